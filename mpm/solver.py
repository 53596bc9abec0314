"""Driver of the MPM dam-break: ``simulate`` builds the scene, runs the time loop on the engine that
``mpm.runtime`` chooses (the compiled Taichi step kernel of ``mpm.kernels``, or ``mpm.native_engine``) and renders
silhouettes; ``Simulation`` holds the result.

Default discretisation: one particle per cell per axis on 1.5 mm cells (the paper's: ``cell_mm=1.26,
ppc=2``); time step from the CFL condition of the elastic wave speed plus the particle speed. ``dim=2`` is
plane strain at mid-depth, its frames extruded over the depth. One simulation at a time per process.
"""
import contextlib
import functools
import math
import os
import sys
import threading
import time
from dataclasses import dataclass, field

import numpy as np
import taichi as ti

from mpm import kernels as kn
from mpm.engine import Engine, engine
from mpm.engine_run import RunStats, frame_record, substeps
from mpm import runtime
from mpm.model import DEFAULT_CELL_MM, PARTICLES_PER_CELL, SLIP_LENGTH_M, ForwardModel  # noqa: F401 (re-exported)
from mpm.solver_constants import NO_WARM_START, SimulationError
from mpm import scene as sc
from mpm.params import (DEFAULT_DEPTH_MM, FLOW_RULES, FPS, N_FRAMES, WORKING_SIZE, Material,
                        frame_times)

CFL = 0.5  # dt = CFL * dx / (c + |v|max); 0.6-0.65 still stable, 0.8 blows up (docs/method/forward-model.md)
SUBSTEPS_PER_FRAME = 4  # the time step is re-evaluated this often per frame interval

__all__ = ["simulate", "Simulation", "SimulationError", "DEFAULT_CELL_MM", "CFL", "PARTICLES_PER_CELL",
           "SUBSTEPS_PER_FRAME", "FLOW_RULES"]


@dataclass
class Simulation:
    """Result of :func:`simulate`. Positions in metres in the reference frame (see ``mpm.scene``)."""

    times: np.ndarray  # (8,) s, t_k = k/24
    frames: list  # 8 arrays (N_k, 3) of the visible particles' positions
    silhouettes: np.ndarray | None  # (8, H, W) bool, True = material, when a camera was given
    front_m: np.ndarray  # (8,) runout: max x of the moving (non-frozen) material
    stats: dict = field(default_factory=dict)


def _check_options(dim, precision, image_size):
    if dim not in (2, 3):
        raise ValueError(f"dim must be 2 or 3, got {dim!r}")
    runtime.float_type_name(precision)
    from mpm.camera import image_size_of

    return image_size_of(image_size)


COMPILE_NOTICE_S = 2.0  # a first launch still running after this long is compiling: say so on stderr
_NOTICE = {"said": False}


@contextlib.contextmanager
def _compile_notice(eng):
    """Tell the user (one line on stderr) when the first launch of ``eng``'s kernels takes long: that is
    Taichi compiling them (first run on a machine, or after the solver changed; later processes load
    them from Taichi's offline cache)."""
    if eng.warm:
        yield
        return

    def say():
        if not _NOTICE["said"]:
            _NOTICE["said"] = True
            print("virheometry: compiling the simulation kernels (first run with this solver on this machine; "
                  "about ten seconds, cached afterwards)...", file=sys.stderr, flush=True)

    timer = threading.Timer(COMPILE_NOTICE_S, say)
    timer.daemon = True
    timer.start()
    try:
        yield
    finally:
        timer.cancel()


def simulate(material, setup, *, density, model: ForwardModel | None = None, dim=3, camera=None,
             depth_mm=DEFAULT_DEPTH_MM, image_size=WORKING_SIZE, precision="f32", progress=None,
             **model_fields) -> Simulation:
    """Run the dam-break for 1/3 s and return 8 frames (t = k/24 s) of visible particle positions.

    material: any object with .eta (Pa s^n), .n, .sigma_y (Pa); setup: any object with .width_mm,
    .height_mm (20-70 mm); density in kg/m^3; depth_mm: distance between the side walls;
    model: the forward model (:class:`mpm.model.ForwardModel`: cell width, particles per cell per axis, the walls'
    Navier slip length, the density correction, the flow rule, the elastic moduli, the engine), or its fields as
    keywords (``cell_mm=1.26, ppc=2``: the paper's discretisation); unset fields take the solver's defaults;
    camera: a ``mpm.camera.Camera`` to also render silhouettes at image_size = (width, height);
    precision: "f32" or "f64"; progress: optional callable ``progress(frames_done, 8)`` called after each
    simulated frame.
    The engine is ``mpm.runtime.engine_for(precision)`` (``$VIRHEO_ARCH``); ``stats["arch"]`` names it.
    Raises ValueError for bad input (an unknown or unavailable engine too, and a model naming an engine other than
    the one this process runs), SimulationError when the run blows up.
    """
    if model is not None and model_fields:
        raise TypeError(f"simulate() takes a model or its fields, not both ({', '.join(model_fields)})")
    model = (ForwardModel(**model_fields) if model is None else model).resolved()
    mat = Material.of(material)
    size = _check_options(dim, precision, image_size)
    here = runtime.engine_for(precision)
    if model.engine and model.engine != here:
        raise ValueError(f"a simulation requested for the {model.engine} engine would run on {here} in this "
                         f"process (VIRHEO_ARCH={os.environ.get('VIRHEO_ARCH', 'auto')}): give every worker the "
                         f"requester's VIRHEO_ARCH")
    scene = sc.DamBreak.build(setup, density=density, cell_mm=model.cell_mm, depth_mm=depth_mm, dim=dim, ppc=model.ppc,
                              kappa_pa=sc.KAPPA_PA if model.kappa_pa is None else model.kappa_pa,
                              mu_pa=sc.MU_PA if model.mu_pa is None else model.mu_pa)
    t_start, cpu_start = time.perf_counter(), time.process_time()
    start, name, tasks = runner(dim, precision)
    t_ready = time.perf_counter()
    slip = model.slip_length_m
    run = start(scene, mat.eta, mat.n, mat.sigma_y, model.flow_rule == "yue2015", slip, model.density_correction)
    frames3, front, stats = run.execute(progress)
    t_sim = time.perf_counter()
    silhouettes = None
    if camera is not None:
        from mpm.silhouette import render

        silhouettes = np.stack([render(f, camera, image_size=size, spacing_m=scene.spacing_m) for f in frames3])
    t_end = time.perf_counter()
    stats.update(
        setup_s=t_ready - t_start, sim_s=t_sim - t_ready, render_s=t_end - t_sim, wall_s=t_end - t_start,
        cpu_s=time.process_time() - cpu_start,
        cell_mm=scene.cell_m * 1e3, ppc=scene.ppc, slip_length_m=slip, density_correction=model.density_correction,
        dim=dim, precision=precision, flow_rule=model.flow_rule,
        arch=name, tasks=tasks,
    )
    stats["particle_steps_per_s"] = stats["n_particles"] * stats["steps"] / max(stats["sim_s"], 1e-9)
    return Simulation(frame_times(), frames3, silhouettes, front, stats)


def runner(dim: int, precision: str = "f32"):
    """``(start, engine, tasks)`` for the engine that ``mpm.runtime`` chooses for ``precision``: ``start(scene, eta,
    n, sigma_y, yue, slip_m=0.0, density_correction=False, body=None)`` makes an :class:`mpm.engine_run.EngineRun`;
    ``engine`` names it ("native", "taichi-cpu" or "cuda"); ``tasks``: its threads (Taichi: its grid copies).
    ValueError (one line) for an unknown or unavailable engine."""
    name = runtime.engine_for(precision, say=True)
    if name == "native":
        from mpm import native_engine

        tasks = runtime.threads()
        start = functools.partial(native_engine.NativeRun, threads=tasks, cfl=CFL, substeps=SUBSTEPS_PER_FRAME)
        return start, name, tasks
    eng = engine(dim, precision)
    return functools.partial(_Run, eng), name, eng.tasks


class _Run:
    """One simulation on a Taichi engine's buffers (an :class:`mpm.engine_run.EngineRun`)."""

    def __init__(self, eng: Engine, scene: sc.DamBreak, eta, n, sigma_y, yue: bool, slip_m: float = 0.0,
                 density_correction: bool = False, body=None):
        self.eng, self.scene = eng, scene
        self.eta, self.n, self.sigma_y, self.yue = eta, n, sigma_y, yue
        self.slip_m = float(slip_m)
        self.density_correction = bool(density_correction)
        # body force per unit mass (m/s^2): gravity along -y unless given
        body = (0.0, -scene.gravity, 0.0) if body is None else tuple(float(b) for b in body)
        self.body = ti.Vector(list(body[:scene.dim]))
        pos = scene.particles()
        self.count = len(pos)
        eng.ensure_particles(self.count)
        cap, d, dt = eng.cap_p, scene.dim, eng.np_dtype
        _, hidden = scene.frozen_and_hidden(pos)
        x = np.zeros((cap, d), dt)
        x[: self.count] = pos
        be = np.zeros((cap, 3, 3), dt)
        be[:] = np.eye(3)
        flags = np.zeros(cap, np.int32)
        flags[: self.count] = np.where(hidden, kn.HIDDEN, 0)
        eng.x.from_numpy(x)
        eng.zero(eng.v)
        eng.zero(eng.C)
        eng.be.from_numpy(be)
        eng.iso.fill(1)  # b_e = I
        eng.loge.fill(NO_WARM_START)
        eng.flags.from_numpy(flags)
        eng.boxes.from_numpy(scene.boxes().astype(dt))
        lo, hi = scene.reach()
        lim = np.zeros(6, np.int32)
        lim[:d] = np.floor(lo / scene.cell_m) - 1
        lim[3:3 + d] = np.ceil(hi / scene.cell_m) + 1
        eng.lim.from_numpy(lim)
        win = np.zeros(16, np.int32)
        eng.win.from_numpy(win)
        with _compile_notice(eng):
            eng.init_bbox(eng.x, eng.acc, eng.accf, self._params(0.0))
        first = eng.acc.to_numpy()
        span = first[:, 3:3 + d].max(0) + 3 - first[:, :d].min(0)
        eng.ensure_grid(int(np.prod(span)) * 2)
        eng.zero(eng.grid)  # the previous run leaves its last window behind

    def _launch(self, steps: int, dt: float) -> None:
        eng = self.eng
        if not eng.warm:  # the first launch alone, so that the notice times compiling and not stepping
            first = 0 if eng.serial else 1  # a serial launch of 0 steps only compiles
            with _compile_notice(eng):
                self._launch_steps(1, first, dt)
            eng.warm = True
            steps -= first
        if steps > 0:
            launches, per_launch = (1, steps) if eng.serial else (steps, 1)
            self._launch_steps(launches, per_launch, dt)

    def _params(self, dt: float):
        """The step kernel's parameter struct (:func:`mpm.kernels.step_params`) for time step ``dt``."""
        eng, s = self.eng, self.scene
        return eng.params(n=self.count, capg=eng.cap_g, dt=dt, dx=s.cell_m, mp=s.particle_mass, vol=s.particle_volume,
                          kappa=s.kappa, mu=s.mu, eta=self.eta, n_power=self.n, sy=self.sigma_y, body=self.body,
                          zmid=s.plane_z_m, lh=s.half_length_m / s.cell_m, slip=self.slip_m)

    def _launch_steps(self, launches: int, per_launch: int, dt: float) -> None:
        eng = self.eng
        prm = self._params(dt)
        particles, grid = eng.particles(), eng.grid_state()
        for _ in range(launches):
            eng.step(particles, grid, eng.boxes, eng.lim, prm, per_launch, self.yue, self.slip_m > 0,
                     self.density_correction)

    def _advance(self, steps: int, dt: float) -> None:
        """Run ``steps`` steps of size dt, growing the grid whenever the window overflows it."""
        eng = self.eng
        done0 = int(eng.win.to_numpy()[kn.DONE])
        target = done0 + steps
        todo = steps
        while todo > 0:
            self._launch(todo, dt)
            win = eng.win.to_numpy()
            if win[kn.ERROR]:
                raise SimulationError(f"simulation blew up: {kn.ERRORS.get(int(win[kn.ERROR]), 'unknown error')}")
            if win[kn.OVERFLOW]:
                eng.ensure_grid(int(win[kn.NEED]) * 3 // 2)
                win[kn.OVERFLOW] = 0
                win[kn.COUNT] = 0  # the new buffer is zero: nothing to clear
                eng.win.from_numpy(win)
            todo = target - int(win[kn.DONE])

    def execute(self, progress=None):
        eng, scene = self.eng, self.scene
        t = 0.0
        steps = 0
        dts = []
        vmax_seen = 0.0
        frames3, front, mean_j, mass_err, visible = [], [], [], [], []
        m_total = self.count * scene.particle_mass
        for k, t_frame in enumerate(frame_times()):
            t_prev = k / FPS
            for sub in range(SUBSTEPS_PER_FRAME):
                t_target = t_prev + (sub + 1) * (t_frame - t_prev) / SUBSTEPS_PER_FRAME
                vmax = float(eng.accf.to_numpy().max())
                if not math.isfinite(vmax) or vmax > scene.speed_limit:
                    raise SimulationError(f"simulation blew up: speed {vmax:.3g} m/s exceeds "
                                          f"{scene.speed_limit:.3g} m/s")
                vmax_seen = max(vmax_seen, vmax)
                m, dt = substeps(t, t_target, vmax, scene, CFL)
                self._advance(m, dt)
                t = t_target
                steps += m
                dts.append(dt)
            x, hidden, frozen, jm = self._snapshot()
            positions, n_visible, x_front = frame_record(scene, x, hidden, frozen)
            frames3.append(positions)
            visible.append(n_visible)
            front.append(x_front)
            mean_j.append(jm)
            eng.grid_mass(eng.grid, eng.win, eng.out)
            mass_err.append(abs(float(eng.out.to_numpy()[0]) - m_total) / m_total)
            if progress is not None:
                progress(k + 1, N_FRAMES)
        flags = eng.flags.to_numpy()[: self.count]
        stats = RunStats(
            n_particles=self.count, steps=steps, dt_min=float(min(dts)), dt_max=float(max(dts)), max_speed=float(vmax_seen),
            plastic_count=int(((flags & kn.PLASTIC) != 0).sum()), mean_J=mean_j, mass_kg=m_total,
            grid_mass_rel_err=max(mass_err), n_visible=visible, wave_speed=scene.wave_speed,
            spacing_m=scene.spacing_m, grid_capacity=eng.cap_g, frozen_count=int(((flags & kn.FROZEN) != 0).sum()),
        )
        return frames3, np.array(front), stats.to_dict()

    def _snapshot(self):
        eng, n = self.eng, self.count
        x = eng.x.to_numpy()[:n].astype(np.float64)
        flags = eng.flags.to_numpy()[:n]
        be = eng.be.to_numpy()[:n].astype(np.float64)
        frozen = (flags & kn.FROZEN) != 0
        moving = ~frozen
        j = np.sqrt(np.abs(np.linalg.det(be[moving]))) if moving.any() else np.ones(1)
        if not np.all(np.isfinite(x)):
            raise SimulationError("simulation blew up: a particle position became NaN")
        return x, (flags & kn.HIDDEN) != 0, frozen, float(j.mean())
