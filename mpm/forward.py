"""The seam between the inverse problem and the forward model.

* :class:`ForwardModel` (a value, :mod:`mpm.model`): how a material is simulated apart from the experiment, i.e.
  the discretisation (cell width, particles per cell), the walls (Navier slip length), the density correction,
  the flow rule, the elastic moduli and the engine.  Density, depth, camera and image size stay with each
  experiment.  It travels whole, inside the store request, to the worker that simulates it.
* :class:`Forward` (a service): the simulation store and the executor that runs what the store lacks.  It
  gives the inverse problem what it needs: video losses of (materials x experiments) under a model,
  simulated results and silhouettes, and the materials the store already holds for a model and experiments.

Everything above ``mpm`` simulates through this module: the store requests (:class:`mpm.store.SimRequest`)
are built here, and only here, from a material, an experiment and a model.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterable, Sequence

import numpy as np

from mpm import batch
from mpm.experiment import Experiment
from mpm.model import ForwardModel  # noqa: F401 (the seam's value, re-exported)
from mpm.params import DEFAULT_DEPTH_MM, WORKING_SIZE
from mpm.store import SimRequest, SimResult, Store

OnResult = Callable[[SimRequest, SimResult | None, bool], None]  # (request, result, served from the store)


def blank_experiment(setup, *, density: float, camera, depth_mm: float = DEFAULT_DEPTH_MM, image_size=WORKING_SIZE,
                     name: str = "") -> Experiment:
    """An experiment without footage (no frames, ``path`` None) in ``setup`` (``.width_mm .height_mm``) seen by
    ``camera`` at ``image_size`` (width, height): what the forward model needs to simulate it."""
    return Experiment(name=name, path=None, width_mm=float(setup.width_mm), height_mm=float(setup.height_mm),
                      depth_mm=float(depth_mm), density=float(density), camera=camera,
                      frames=np.zeros((0, int(image_size[1]), int(image_size[0])), bool))


class Forward:
    """Simulations through a store and an executor (the forward model as a service).

    ``store``: a :class:`mpm.store.Store`, a folder to open one in, or None (nothing kept).  The executor:
    ``executor`` (any ``concurrent.futures.Executor`` or a dask Client), else a dask.distributed ``scheduler``
    address, else ``workers`` local processes (None: one per CPU core; 0: in this process).  ``simulator``
    names the simulating function as ``"module:function"`` (None: the MPM solver; tests use a fake one).
    What this object opens (a store from a folder, an executor) it closes in :meth:`close`.
    """

    def __init__(self, store=None, *, workers: int | None = 0, executor=None, scheduler: str | None = None,
                 simulator: str | None = None):
        self._own_store = store is not None and not isinstance(store, Store)
        self.store: Store | None = Store(Path(store)) if self._own_store else store
        self._own_executor = executor is None and (scheduler is not None or workers != 0)
        try:
            if executor is not None:
                self.executor = executor
            elif scheduler is not None:
                self.executor = batch.connect(scheduler)
            else:
                self.executor = batch.local_executor(workers)
        except BaseException:
            if self._own_store:
                self.store.close()
            raise
        self.simulator = simulator or batch.DEFAULT_SIMULATOR
        self._ran = [0]  # simulations run (not served from the store), shared with with_simulator's copies

    @property
    def simulations_run(self) -> int:
        """How many simulations this object (and its :meth:`with_simulator` copies) ran, not counting those the
        store served."""
        return self._ran[0]

    def with_simulator(self, simulator: str | None) -> "Forward":
        """The same store and executor with another simulating function (closing it closes nothing)."""
        other = Forward(self.store, executor=self.executor, simulator=simulator)
        other._ran = self._ran
        return other

    def _counting(self, on_result: OnResult | None) -> OnResult:
        def seen(request: SimRequest, result: SimResult | None, cached: bool) -> None:
            if not cached:
                self._ran[0] += 1
            if on_result:
                on_result(request, result, cached)
        return seen

    def close(self) -> None:
        """Shut down the executor and close the store, where this object opened them."""
        if self._own_executor:
            batch.shutdown(self.executor)
            self._own_executor = False
        if self._own_store:
            self.store.close()
            self._own_store = False

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # -- requests -------------------------------------------------------------------------------
    def request(self, material, experiment, model: ForwardModel) -> SimRequest:
        """The store request that simulates ``material`` (``.eta .n .sigma_y``) in ``experiment``'s setup, density,
        depth, camera and image size with ``model``, its solver defaults filled in (so every request names its
        discretisation) and its engine resolved by ``mpm.runtime`` where the model leaves it open."""
        size = np.shape(experiment.frames)
        return batch.request_for(material, experiment, density=float(experiment.density), model=model,
                                 depth_mm=float(experiment.depth_mm), camera=experiment.camera,
                                 image_size=(int(size[-1]), int(size[-2])), simulator=self.simulator)

    @staticmethod
    def experiment_id(experiment) -> str:
        """Content id of an experiment's footage (its losses are stored under it)."""
        return batch.experiment_id(experiment.frames, experiment.name)

    # -- simulations ----------------------------------------------------------------------------
    def evaluate(self, requests: Sequence[SimRequest], on_result: OnResult | None = None) -> list[SimResult]:
        """Results of ``requests`` in order: from the store where present, else simulated and stored."""
        return batch.evaluate(requests, store=self.store, executor=self.executor, on_result=self._counting(on_result))

    def results(self, material, experiments, model: ForwardModel, on_result: OnResult | None = None) -> list[SimResult]:
        """Simulated results of ``material`` in each of ``experiments`` with ``model``."""
        return self.evaluate([self.request(material, e, model) for e in experiments], on_result)

    def silhouettes(self, material, experiments, model: ForwardModel) -> list:
        """Simulated silhouettes (F, H, W) of ``material`` in each of ``experiments``, None where it failed."""
        return [r.silhouettes if r.ok else None for r in self.results(material, experiments, model)]

    def simulate(self, material, experiment, model: ForwardModel, *, dim: int = 3, progress=None):
        """One simulation of ``material`` in ``experiment`` with ``model``, run in this process and returned whole
        (:class:`mpm.solver.Simulation`: the particles of every frame beside the silhouettes), for a user who
        watches one run (``virheo simulate``); not stored.  ``dim`` 2: plane strain.  ``progress(frames_done, 8)``
        after each frame."""
        from mpm import solver

        request = self.request(material, experiment, model)
        sim = solver.simulate(material, experiment, model=request.model, density=request.density,
                              camera=experiment.camera, depth_mm=request.depth_mm,
                              image_size=tuple(request.image_size), dim=dim, progress=progress)
        self._ran[0] += 1
        return sim

    # -- losses ---------------------------------------------------------------------------------
    def pair_losses(self, pairs: Iterable[tuple], model: ForwardModel, on_result: OnResult | None = None) -> np.ndarray:
        """Video losses (eq. 3) of ``(material, experiment)`` pairs against each experiment's footage, in one batch;
        NaN where the simulation failed.  ``on_result(request, result, cached)`` once per distinct request."""
        pairs = list(pairs)
        ids: dict[int, str] = {}
        for _, e in pairs:
            if id(e) not in ids:
                ids[id(e)] = self.experiment_id(e)
        jobs = [(self.request(m, e, model), ids[id(e)], e.frames) for m, e in pairs]
        return batch.evaluate_losses(jobs, store=self.store, executor=self.executor,
                                     on_result=self._counting(on_result))

    def losses(self, materials: Sequence, experiments: Sequence, model: ForwardModel,
               on_result: OnResult | None = None) -> np.ndarray:
        """Video losses (len(materials), len(experiments)) of every material in every experiment (NaN: failed)."""
        materials, experiments = list(materials), list(experiments)
        flat = self.pair_losses([(m, e) for m in materials for e in experiments], model, on_result)
        return flat.reshape(len(materials), len(experiments))

    # -- what the store holds -------------------------------------------------------------------
    def simulated(self, experiments: Sequence, model: ForwardModel) -> np.ndarray:
        """Materials (k, 3) as (eta, n, sigma_y) that the store holds simulated (successfully or not) in every one
        of ``experiments`` with ``model`` by this simulator and engine, in the order they were first simulated."""
        if self.store is None:
            return np.zeros((0, 3))
        probe = _Probe()
        settings = [self.request(probe, e, model).setting_key for e in experiments]
        return np.asarray(self.store.materials(settings), float).reshape(-1, 3)


@dataclass(frozen=True)
class _Probe:
    """A stand-in material for requests whose material is left out (their ``setting_key``)."""

    eta: float = 1.0
    n: float = 1.0
    sigma_y: float = 0.0
