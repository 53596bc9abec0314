"""What both MPM engines share above their kernels: the interface of a run (``EngineRun``: Taichi's
``mpm.solver._Run`` and the native ``mpm.native_engine.NativeRun``), the time-step schedule, the frame record and the
run's statistics.  No Taichi here.

The native engine runs the same schedule in C++ (``substeps`` in mpm/native/types.h, which ``Engine::run`` calls);
tests/test_solver_paths.py compares the two bit for bit, and the engine-agreement tests and bench compare the step
counts of the two engines run for run.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Callable, Protocol

import numpy as np


class EngineRun(Protocol):
    """One dam-break simulation on an engine, made by ``start(scene, eta, n, sigma_y, yue, slip_m,
    density_correction, body)`` (:func:`mpm.solver.runner`)."""

    def execute(self, progress: Callable[[int, int], None] | None = None) -> tuple[list, np.ndarray, dict]:
        """(visible particle positions per frame, the front per frame in m, :class:`RunStats` as a dict)."""


def substeps(t: float, t_target: float, vmax: float, scene, cfl: float) -> tuple[int, float]:
    """(steps, dt) that take the run from ``t`` to ``t_target`` under the CFL condition: the elastic wave speed plus
    the fastest particle's speed, with room for a chunk of free fall, dt <= cfl dx / (c + |v|max + g (t_target - t))."""
    dt_cfl = cfl * scene.cell_m / (scene.wave_speed + vmax + scene.gravity * (t_target - t))
    m = max(1, math.ceil((t_target - t) / dt_cfl - 1e-9))
    return m, (t_target - t) / m


def frame_record(scene, x: np.ndarray, hidden: np.ndarray, frozen: np.ndarray) -> tuple[np.ndarray, int, float]:
    """(the visible particles' positions, how many are visible, the front: the largest x of a moving particle, 0
    when none moves) of one frame."""
    moving = ~frozen
    return scene.visible_positions(x, hidden), int((~hidden).sum()), float(x[moving, 0].max()) if moving.any() else 0.0


@dataclass
class RunStats:
    """What a run reports besides its frames (``Simulation.stats``), on either engine."""

    n_particles: int
    steps: int
    dt_min: float
    dt_max: float
    max_speed: float
    plastic_count: int
    mean_J: list
    mass_kg: float
    grid_mass_rel_err: float
    n_visible: list
    wave_speed: float
    spacing_m: float
    grid_capacity: int
    frozen_count: int

    def to_dict(self) -> dict:
        return asdict(self)
