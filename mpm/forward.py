"""The seam between the inverse problem and the forward model.

* :class:`ForwardModel` (a value): how a material is simulated apart from the experiment, i.e. the
  discretisation (cell width, particles per cell), the walls (Navier slip length), the density correction,
  the flow rule and the engine.  Density, depth, camera and image size stay with each experiment.
* :class:`Forward` (a service): the simulation store and the executor that runs what the store lacks.  It
  gives the inverse problem what it needs: video losses of (materials x experiments) under a model,
  simulated results and silhouettes, and the materials the store already holds for a model and experiments.

Everything above ``mpm`` simulates through this module: the store requests (:class:`mpm.store.SimRequest`)
are built here, and only here, from a material, an experiment and a model.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from pathlib import Path
from typing import Callable, Iterable, Sequence

import numpy as np

from mpm import batch, runtime
from mpm.experiment import Experiment
from mpm.params import DEFAULT_DEPTH_MM, WORKING_SIZE, check_flow_rule
from mpm.ranges import check_cell_mm, check_modulus, check_ppc
from mpm.scene import KAPPA_PA, MU_PA
from mpm.store import SimRequest, SimResult, Store

OnResult = Callable[[SimRequest, SimResult | None, bool], None]  # (request, result, served from the store)


@dataclass(frozen=True)
class ForwardModel:
    """The forward model of a simulation: MPM cell width in mm, particles per cell per axis, the walls' Navier
    slip length in metres, the solver's density correction, the flow rule, the engine and the elastic moduli in Pa.
    None: the solver's default (the validated discretisation, sticking walls, the paper's kappa = 1e4 Pa and mu =
    1e3 Pa); ``engine`` None: the one ``$VIRHEO_ARCH`` chooses (:func:`mpm.runtime.engine_for`), else one of
    :data:`mpm.runtime.ENGINES`."""

    cell_mm: float | None = None
    ppc: int | None = None
    slip_length_m: float | None = None
    density_correction: bool = False
    flow_rule: str = "paper"
    engine: str | None = None
    kappa_pa: float | None = None
    mu_pa: float | None = None

    def __post_init__(self):
        """Every bound the scene enforces, checked here once, so that a bad model never reaches a worker."""
        if self.cell_mm is not None:
            check_cell_mm(self.cell_mm)
        if self.ppc is not None:
            check_ppc(self.ppc)
        if self.slip_length_m is not None and not 0.0 <= self.slip_length_m <= 1.0:  # also refuses nan
            raise ValueError(f"slip_length_m={self.slip_length_m!r} must be within 0..1 m (0: sticking walls)")
        for name in ("kappa_pa", "mu_pa"):
            if getattr(self, name) is not None:
                check_modulus(getattr(self, name), name)
        if self.engine is not None and self.engine not in runtime.ENGINES:
            raise ValueError(f"unknown engine {self.engine!r}: expected one of {', '.join(runtime.ENGINES)}")
        check_flow_rule(self.flow_rule)

    def resolved(self) -> "ForwardModel":
        """The same with the solver's defaults filled in (the engine stays as it is: None leaves it to
        ``mpm.runtime`` when a request is made)."""
        from mpm.solver import DEFAULT_CELL_MM, PARTICLES_PER_CELL, SLIP_LENGTH_M

        return ForwardModel(float(DEFAULT_CELL_MM if self.cell_mm is None else self.cell_mm),
                            int(PARTICLES_PER_CELL if self.ppc is None else self.ppc),
                            float(SLIP_LENGTH_M if self.slip_length_m is None else self.slip_length_m),
                            bool(self.density_correction), self.flow_rule, self.engine, self.kappa_pa, self.mu_pa)

    def to_dict(self) -> dict:
        """The model as a dict; the paper's moduli (None) are left out, as in records written before the model
        carried them."""
        return {k: v for k, v in asdict(self).items() if not (k in ("kappa_pa", "mu_pa") and v is None)}

    @classmethod
    def from_dict(cls, d: dict) -> "ForwardModel":
        """The model of ``to_dict()``; also reads the four-key dicts that result files held before the model had
        a flow rule and an engine.  One-line ValueError for other keys."""
        names = {f.name for f in fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"not a forward model: unknown key(s) {', '.join(sorted(unknown))}")
        return cls(**d)

    @classmethod
    def of_record(cls, record: dict) -> "ForwardModel":
        """The model a result.json or a stage of its history was computed with: its nested ``model``, else the
        ``discretisation`` of result files written before the model was one value, else a stage's loose
        ``cell_mm``/``ppc``/``slip_length_m``/``density_correction`` fields (missing ones: the defaults)."""
        for key in ("model", "discretisation"):
            if isinstance(record.get(key), dict):
                return cls.from_dict(record[key])
        return cls.from_dict({k: record[k] for k in ("cell_mm", "ppc", "slip_length_m", "density_correction")
                              if k in record})


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

    def with_simulator(self, simulator: str | None) -> "Forward":
        """The same store and executor with another simulating function (closing it closes nothing)."""
        return Forward(self.store, executor=self.executor, simulator=simulator)

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
        model = model.resolved()
        frames = np.asarray(experiment.frames)
        return batch.request_for(
            material, experiment, density=float(experiment.density), depth_mm=float(experiment.depth_mm),
            camera=experiment.camera, cell_mm=model.cell_mm, ppc=model.ppc,
            slip_length_m=model.slip_length_m or None,  # sticking walls keep the key they always had
            density_correction=model.density_correction, flow_rule=model.flow_rule,
            image_size=(int(frames.shape[-1]), int(frames.shape[-2])), simulator=self.simulator, engine=model.engine,
            kappa_pa=None if model.kappa_pa in (None, KAPPA_PA) else model.kappa_pa,  # the paper's: the keys they had
            mu_pa=None if model.mu_pa in (None, MU_PA) else model.mu_pa,
        )

    @staticmethod
    def experiment_id(experiment) -> str:
        """Content id of an experiment's footage (its losses are stored under it)."""
        return batch.experiment_id(experiment.frames, experiment.name)

    # -- simulations ----------------------------------------------------------------------------
    def evaluate(self, requests: Sequence[SimRequest], on_result: OnResult | None = None) -> list[SimResult]:
        """Results of ``requests`` in order: from the store where present, else simulated and stored."""
        return batch.evaluate(requests, store=self.store, executor=self.executor, on_result=on_result)

    def results(self, material, experiments, model: ForwardModel, on_result: OnResult | None = None) -> list[SimResult]:
        """Simulated results of ``material`` in each of ``experiments`` with ``model``."""
        return self.evaluate([self.request(material, e, model) for e in experiments], on_result)

    def silhouettes(self, material, experiments, model: ForwardModel) -> list:
        """Simulated silhouettes (F, H, W) of ``material`` in each of ``experiments``, None where it failed."""
        return [r.silhouettes if r.ok else None for r in self.results(material, experiments, model)]

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
        return batch.evaluate_losses(jobs, store=self.store, executor=self.executor, on_result=on_result)

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
