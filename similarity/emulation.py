"""Emulated footage: experiments whose silhouettes are simulated from a known material (the ground truth)."""
from __future__ import annotations

from typing import Sequence

import numpy as np

from mpm import batch
from mpm.experiment import Experiment
from mpm.params import DEFAULT_DENSITY_KG_M3, DEFAULT_DEPTH_MM, WORKING_SIZE, Material, Setup
from mpm.store import Store
from similarity.presets import get_preset, simulation_request
from similarity.space import denormalize, normalize


def _default_camera():
    from mpm.camera import Camera

    return Camera.default()


def emulate(material: Material, setups: Sequence[Setup], *, density: float = DEFAULT_DENSITY_KG_M3, camera=None,
            depth_mm: float = DEFAULT_DEPTH_MM, preset="demo", store: Store | None = None, executor=None,
            simulator: str = batch.DEFAULT_SIMULATOR, image_size=WORKING_SIZE) -> list[Experiment]:
    """Footage of ``material`` in each setup, simulated at the preset's final discretisation.

    Returns one :class:`mpm.experiment.Experiment` per setup (``path`` None, named ``emulated_<W>x<H>``).
    ``camera``: a Camera (e.g. ``mpm.experiment.load(dir).camera``) or None for ``Camera.default()``.
    """
    preset = get_preset(preset)
    camera = camera if camera is not None else _default_camera()
    shells = [Experiment(name=f"emulated_{Setup(s.width_mm, s.height_mm)}", path=None, width_mm=float(s.width_mm),
                         height_mm=float(s.height_mm), depth_mm=float(depth_mm), density=float(density), camera=camera,
                         frames=np.zeros((0, 0, 0), bool)) for s in setups]
    reqs = [simulation_request(material, e, preset.final, simulator, image_size) for e in shells]
    results = batch.evaluate(reqs, store=store, executor=executor)
    for e, r in zip(shells, results):
        if not r.ok or r.silhouettes is None:
            raise RuntimeError(f"ground-truth simulation of {e.name} failed: {r.error}")
        e.frames = r.silhouettes
    return shells


def simulated_frames(material: Material, experiments, *, preset="footage", store: Store | None = None, executor=None,
                     simulator: str = batch.DEFAULT_SIMULATOR) -> list:
    """Silhouettes of ``material`` in each experiment's setup at the preset's final discretisation (None where
    the simulation failed).  For an estimate's material these come straight from the store.
    """
    model = get_preset(preset).final
    reqs = [simulation_request(material, e, model, simulator) for e in experiments]
    ex = executor if executor is not None else batch.InlineExecutor()
    return [r.silhouettes if r.ok else None for r in batch.evaluate(reqs, store=store, executor=ex)]


def probe_jobs(material: Material, experiment: Experiment, offsets, model,
               simulator: str = batch.DEFAULT_SIMULATOR) -> list:
    """:func:`mpm.batch.evaluate_losses` jobs: ``material`` moved by each of ``offsets`` (normalised material space),
    simulated in ``experiment``'s setup at ``model`` and scored against its footage."""
    eid = batch.experiment_id(experiment.frames, experiment.name)
    u0 = normalize(material.as_array())
    return [(simulation_request(Material.from_array(denormalize(u0 + du)), experiment, model, simulator), eid,
             experiment.frames) for du in offsets]
