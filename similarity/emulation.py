"""Emulated footage: experiments whose silhouettes are simulated from a known material (the ground truth)."""
from __future__ import annotations

from typing import Sequence

import numpy as np

from mpm.experiment import Experiment
from mpm.forward import Forward, ForwardModel, blank_experiment
from mpm.params import DEFAULT_DENSITY_KG_M3, DEFAULT_DEPTH_MM, WORKING_SIZE, Material, Setup
from similarity.presets import get_preset
from similarity.space import denormalize, normalize


def _default_camera():
    from mpm.camera import Camera

    return Camera.default()


def emulate(material: Material, setups: Sequence[Setup], *, density: float = DEFAULT_DENSITY_KG_M3, camera=None,
            depth_mm: float = DEFAULT_DEPTH_MM, preset="demo", forward: Forward | None = None,
            image_size=WORKING_SIZE, on_result=None) -> list[Experiment]:
    """Footage of ``material`` in each setup, simulated at the preset's final discretisation.

    Returns one :class:`mpm.experiment.Experiment` per setup (``path`` None, named ``emulated_<W>x<H>``).
    ``camera``: a Camera (e.g. ``mpm.experiment.load(dir).camera``) or None for ``Camera.default()``;
    ``forward``: the store and executor that simulate (None: no store, in this process); ``on_result`` as in
    :meth:`mpm.forward.Forward.evaluate`.
    """
    preset = get_preset(preset)
    forward = forward if forward is not None else Forward()
    camera = camera if camera is not None else _default_camera()
    shells = [blank_experiment(s, density=density, camera=camera, depth_mm=depth_mm, image_size=image_size,
                               name=f"emulated_{Setup(s.width_mm, s.height_mm)}") for s in setups]
    for e, r in zip(shells, forward.results(material, shells, preset.final, on_result)):
        if not r.ok or r.silhouettes is None:
            raise RuntimeError(f"ground-truth simulation of {e.name} failed: {r.error}")
        e.frames = r.silhouettes
    return shells


def film(material: Material, setup: Setup, folder, *, preset, forward: Forward, density: float = DEFAULT_DENSITY_KG_M3
         ) -> Experiment:
    """Footage of ``material`` in ``setup`` (:func:`emulate`) written as the experiment folder
    ``folder/footage_<W>x<H>`` and read back from it, as real footage is read."""
    from pathlib import Path

    from mpm.experiment import load, write

    shot = emulate(material, [setup], density=density, preset=preset, forward=forward)[0]
    path = Path(folder) / f"footage_{setup}"
    write(path, shot.frames, width_mm=setup.width_mm, height_mm=setup.height_mm, camera=shot.camera, density=density)
    return load(path)


def simulated_frames(material: Material, experiments, *, preset="footage", forward: Forward | None = None) -> list:
    """Silhouettes of ``material`` in each experiment's setup at the preset's final discretisation (None where
    the simulation failed).  For an estimate's material these come straight from the store.
    """
    forward = forward if forward is not None else Forward()
    return forward.silhouettes(material, experiments, get_preset(preset).final)


def probe_pairs(pairs: Sequence[tuple], offsets) -> list[tuple]:
    """``(material, experiment)`` for each pair's material moved by each of ``offsets`` (normalised material space),
    pair by pair."""
    out = []
    for m, e in pairs:
        u0 = normalize(m.as_array())
        out += [(Material.from_array(denormalize(u0 + du)), e) for du in offsets]
    return out


def probe_losses(pairs: Sequence[tuple], offsets, model: ForwardModel, forward: Forward,
                 on_result=None) -> np.ndarray:
    """Losses (len(pairs), len(offsets)) of the :func:`probe_pairs` of ``(material, experiment)`` pairs, simulated with
    ``model`` and scored against each experiment's footage, all in one batch.  ``on_result`` as in
    :meth:`mpm.forward.Forward.pair_losses`."""
    return forward.pair_losses(probe_pairs(pairs, offsets), model, on_result).reshape(len(pairs), len(offsets))
