"""The native CPU engine (``mpm._native``, C++ in mpm/native/): a whole dam-break in one call.

It runs the physics of the Taichi step (``mpm.kernels``): the same scene, constants, flow rules, walls, density
correction and time-step schedule, in float32, vectorised for the CPU it runs on (AVX-512, AVX2 or a generic
path, chosen at run time; ``$VIRHEO_NATIVE_ISA`` forces one, for testing). Its agreement with the Taichi engine
is measured by bench/bench_engine_agreement.py (docs/performance.md). Neither importing this module nor simulating
imports Taichi: the constants it shares with the Taichi engine live in ``mpm.solver_constants``.
``mpm.runtime`` decides which engine runs.
"""
from __future__ import annotations

import os
import sys

import numpy as np

from mpm.engine_run import RunStats, frame_record
from mpm.params import FPS, N_FRAMES, frame_times
from mpm.solver_constants import (ERR_SPEED, ERRORS, FROZEN, HIDDEN, NEWTON_ITERATIONS, NEWTON_TOL, NO_WARM_START, PLASTIC,
                                  SimulationError, get_flow_rule)

try:
    from mpm import _native
    _IMPORT_ERROR = None
except ImportError as exc:  # not built: no compiler at install time
    _native = None
    _IMPORT_ERROR = exc

_SAID = {"isa": False}
INTERFACE = 4  # the calling convention this module speaks (engine.cpp's INTERFACE): a build that differs is stale


def available() -> bool:
    """True when the compiled extension is importable and built from sources of this calling convention."""
    return _native is not None and getattr(_native, "INTERFACE", 1) == INTERFACE


def why_unavailable() -> str:
    """One line: why the native engine cannot run ('' when it can)."""
    if _native is None:
        return f"mpm._native does not import ({_IMPORT_ERROR}); reinstall with a C++ compiler: pip install -e ."
    if not available():
        return (f"mpm._native was built from older sources (interface {getattr(_native, 'INTERFACE', 1)}, this "
                f"checkout needs {INTERFACE}): rebuild it with pip install -e .")
    return ""


def isa() -> str:
    """The SIMD path this CPU runs: ``$VIRHEO_NATIVE_ISA`` if set, else the best one it supports."""
    if not available():
        raise ValueError(why_unavailable())
    runs = _native.isas()
    want = os.environ.get("VIRHEO_NATIVE_ISA", "").strip().lower()
    if want:
        if want not in _native.compiled():
            raise ValueError(f"VIRHEO_NATIVE_ISA must be one of {', '.join(_native.compiled())}, got {want!r}")
        if want not in runs:
            raise ValueError(f"VIRHEO_NATIVE_ISA={want}: this CPU runs only {', '.join(runs)}")
        return want
    best = runs[0]
    compiled = _native.compiled()
    if best != compiled[0] and not _SAID["isa"]:
        _SAID["isa"] = True
        print(f"virheometry: this CPU lacks the {compiled[0]} instructions the native engine was built for; "
              f"running its {best} path", file=sys.stderr)
    return best


class NativeRun:
    """One simulation on the native engine (an :class:`mpm.engine_run.EngineRun`)."""

    def __init__(self, scene, eta, n, sigma_y, yue: bool, slip_m: float = 0.0, density_correction: bool = False,
                 body=None, threads: int = 1, *, cfl: float, substeps: int):
        if not available():
            raise ValueError(why_unavailable())
        self.scene = scene
        self.eta, self.n, self.sigma_y, self.yue = float(eta), float(n), float(sigma_y), bool(yue)
        self.slip_m = float(slip_m)
        self.density_correction = bool(density_correction)
        self.body = (0.0, -scene.gravity, 0.0) if body is None else tuple(float(b) for b in body) + (0.0,) * 3
        self.threads = max(1, int(threads))
        self.cfl, self.substeps = float(cfl), int(substeps)  # the time-step schedule, as mpm.solver sets it
        self.isa = isa()

    def params(self, count: int) -> dict:
        """The run's parameters by name, as the C++ engine reads them into its ``Params`` (mpm/native/types.h)."""
        s = self.scene
        rule = get_flow_rule("yue2015" if self.yue else "paper")
        return dict(
            dim=s.dim, density_correction=self.density_correction, slipping=self.slip_m > 0, threads=self.threads,
            substeps=self.substeps, n_particles=count, n_frames=N_FRAMES, newton_iterations=NEWTON_ITERATIONS,
            alpha=rule.alpha, beta=rule.beta, flow_c=rule.c,
            dx=s.cell_m, particle_mass=s.particle_mass, particle_volume=s.particle_volume, kappa=s.kappa, mu=s.mu,
            eta=self.eta, n=self.n, sigma_y=self.sigma_y, body_x=self.body[0], body_y=self.body[1], body_z=self.body[2],
            plane_z=s.plane_z_m, half_length_cells=s.half_length_m / s.cell_m, slip=self.slip_m,
            newton_tol=NEWTON_TOL, no_warm_start=NO_WARM_START,
            cfl=self.cfl, wave_speed=s.wave_speed, gravity=s.gravity, speed_limit=s.speed_limit, fps=FPS,
        )

    def execute(self, progress=None):
        s = self.scene
        d = s.dim
        pos = np.ascontiguousarray(s.particles(), np.float64)
        count = len(pos)
        _, hidden0 = s.frozen_and_hidden(pos)
        flags0 = np.where(hidden0, HIDDEN, 0).astype(np.int32)
        lo, hi = s.reach()
        lim = np.zeros(6, np.int32)
        lim[:d] = np.floor(lo / s.cell_m) - 1
        lim[3:3 + d] = np.ceil(hi / s.cell_m) + 1
        times = np.ascontiguousarray(frame_times(), np.float64)
        out_x = np.empty((N_FRAMES, count, d), np.float32)
        out_flags = np.empty((N_FRAMES, count), np.uint8)
        out_j = np.zeros(N_FRAMES)
        out_mass = np.zeros(N_FRAMES)
        callback = None if progress is None else (lambda k: progress(k, N_FRAMES))
        error, value, steps, dt_min, dt_max, vmax_seen, sorts, refills = _native.simulate(
            pos, flags0, self.params(count),
            np.ascontiguousarray(s.boxes(), np.float64), lim, times, out_x, out_flags, out_j, out_mass, callback,
            self.isa)
        if error == ERR_SPEED:
            raise SimulationError(f"simulation blew up: speed {value:.3g} m/s exceeds {s.speed_limit:.3g} m/s")
        if error:
            raise SimulationError(f"simulation blew up: {ERRORS.get(error, 'unknown error')}")
        m_total = count * s.particle_mass
        frames3, front, visible = [], [], []
        for k in range(N_FRAMES):
            x = out_x[k].astype(np.float64)
            positions, n_visible, x_front = frame_record(s, x, (out_flags[k] & HIDDEN) != 0, (out_flags[k] & FROZEN) != 0)
            frames3.append(positions)
            visible.append(n_visible)
            front.append(x_front)
        final = out_flags[-1]
        stats = RunStats(
            n_particles=count, steps=int(steps), dt_min=float(dt_min), dt_max=float(dt_max),
            max_speed=float(vmax_seen), plastic_count=int(((final & PLASTIC) != 0).sum()), mean_J=out_j.tolist(),
            mass_kg=m_total, grid_mass_rel_err=float(np.max(np.abs(out_mass - m_total)) / m_total),
            n_visible=visible, wave_speed=s.wave_speed, spacing_m=s.spacing_m, grid_capacity=0,
            frozen_count=int(((final & FROZEN) != 0).sum()),
        )
        return frames3, np.array(front), stats.to_dict() | dict(isa=self.isa, sorts=int(sorts), window_refills=int(refills))


def return_mapping(be_trial, be_old, mu, eta, n, sigma_y, dt, *, flow_rule: str = "paper", log_e0=None):
    """The native engine's return mapping over a batch: the contract of
    ``mpm.constitutive.return_mapping_taichi`` (float32). Returns (new b_e as float64, plastic flags, log of the
    excess stress where plastic, else NaN)."""
    log_e0 = NO_WARM_START if log_e0 is None else log_e0

    if not available():
        raise ValueError(why_unavailable())
    rule = get_flow_rule(flow_rule)
    be = np.ascontiguousarray(np.asarray(be_trial, np.float32).reshape(-1, 3, 3))
    batch = np.shape(be_trial)[:-2]
    old = np.ascontiguousarray(np.broadcast_to(np.asarray(be_old), np.shape(be_trial)).reshape(-1, 3, 3), np.float32)
    par = np.stack([np.broadcast_to(np.asarray(v, dtype=float), batch).reshape(-1)
                    for v in (mu, eta, n, sigma_y, dt, log_e0)], axis=1).astype(np.float32)
    out = np.zeros_like(be)
    plastic = np.zeros(len(be), np.int32)
    log_e = np.zeros(len(be), np.float32)
    _native.return_mapping(be, old, np.ascontiguousarray(par), rule.alpha, rule.beta, rule.c, NEWTON_ITERATIONS,
                           NEWTON_TOL, NO_WARM_START, out, plastic, log_e, isa())
    flags = plastic.astype(bool)
    return (out.astype(np.float64).reshape(np.shape(be_trial)), flags.reshape(batch),
            np.where(flags, log_e.astype(np.float64), np.nan).reshape(batch))


