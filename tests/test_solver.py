"""MPM dam-break (mpm.simulate): physics invariants on small, coarse runs, on each engine (tests/engines.py).

All runs share one process, and on Taichi one compiled kernel per dim (20 x 20 mm, 2.5 mm cells, ~1.5k particles
with the default of one particle per cell per axis).
"""
import functools
import math
import os
from types import SimpleNamespace as NS

import numpy as np
import pytest

import engines
import mpm
from mpm import scene as sc
from mpm import solver

SETUP = NS(width_mm=20, height_mm=20)
RHO = 1000.0
CELL = 2.5


def run(eta, n=1.0, sigma_y=0.0, dim=3, camera=False, engine="taichi-cpu"):
    """The cached run on ``engine`` (skipped, or failed under VIRHEO_REQUIRE_NATIVE=1, where it cannot run)."""
    return _run(eta, n, sigma_y, dim, camera, engines.require(engine))


@functools.lru_cache(maxsize=None)
def _run(eta, n, sigma_y, dim, camera, engine):
    cam = None
    if camera:
        from mpm.camera import Camera

        cam = Camera.default()
    with engines.using(engine):
        sim = mpm.simulate(NS(eta=eta, n=n, sigma_y=sigma_y), SETUP, density=RHO, cell_mm=CELL, dim=dim,
                           camera=cam, image_size=(240, 135))
    assert sim.stats["arch"] == engine
    return sim


def test_frames_times_and_visibility(mpm_engine):
    sim = run(0.3, camera=True, engine=mpm_engine)
    assert np.allclose(sim.times, np.arange(1, 9) / 24)
    assert len(sim.frames) == 8 and sim.front_m.shape == (8,)
    w, d = SETUP.width_mm * 1e-3, 0.04
    for f in sim.frames:
        assert f.ndim == 2 and f.shape[1] == 3 and np.isfinite(f).all()
        box = f[f[:, 0] < w - CELL * 1e-3]  # inside the box: floor and near-wall layers are hidden
        assert (box[:, 1] > 0).all() and (box[:, 2] < d).all()
        assert (f[:, 0] < 0).any() and (f[:, 2] < 0).any()  # back-wall and far-wall coating stay visible
    st = sim.stats
    scene = sc.DamBreak.build(SETUP, density=RHO, cell_mm=CELL, ppc=st["ppc"])
    frozen0 = scene.frozen_and_hidden(scene.particles())[0].sum()
    assert st["n_particles"] == scene.n_particles
    assert frozen0 <= st["frozen_count"] < st["n_particles"] / 2  # sticking walls keep their coating
    # CFL: no step longer than CFL dx / c, and the steps add up to the 1/3 s of the video
    assert st["dt_max"] <= solver.CFL * CELL * 1e-3 / st["wave_speed"] * (1 + 1e-9)
    assert st["steps"] * st["dt_min"] <= 1 / 3 + 1e-9 <= st["steps"] * st["dt_max"] + 2e-9
    assert sim.silhouettes.shape == (8, 135, 240) and sim.silhouettes.dtype == bool
    area = sim.silhouettes.reshape(8, -1).mean(1)
    assert (area > 0.005).all() and area[-1] > area[0]  # the material spreads in the image


def test_mass_is_conserved_and_volume_nearly_so(mpm_engine):
    """Particle mass is fixed; the grid receives exactly that mass (uGIMP weights sum to one); J stays
    within 5 % of 1 with the hydrostatic compression of order rho g H / (2 kappa)."""
    st = run(0.3, engine=mpm_engine).stats
    assert st["mass_kg"] == pytest.approx(st["n_particles"] * RHO * st["spacing_m"] ** 3)
    assert st["grid_mass_rel_err"] < 2e-5  # f32 sums
    expected = RHO * sc.GRAVITY * SETUP.height_mm * 1e-3 / (2 * sc.KAPPA_PA)  # ~1 %
    for j in st["mean_J"]:
        assert abs(j - 1) < 0.05
        assert 0.1 * expected < 1 - j < 3 * expected  # compressed, less as the column spreads
    # at frame 1 the column still stands (sticking walls carry part of its weight)
    assert 0.3 * expected < 1 - st["mean_J"][0] < 3 * expected


def test_stiff_column_never_yields_and_only_sags(mpm_engine):
    """sigma_y = 5 kPa >> rho g H = 0.2 kPa: no particle enters the plastic branch, the front only moves
    by an elastic sag of order rho g H^2 / mu (4 mm), far less than a flowing material's runout."""
    stiff = run(1.0, sigma_y=5000.0, engine=mpm_engine)
    assert stiff.stats["plastic_count"] == 0
    h = SETUP.height_mm * 1e-3
    sag_scale = RHO * sc.GRAVITY * h * h / sc.MU_PA
    w = SETUP.width_mm * 1e-3
    sag = stiff.front_m.max() - w
    scene = sc.DamBreak.build(SETUP, density=RHO, cell_mm=CELL, ppc=stiff.stats["ppc"])
    p = scene.particles()
    first_column = p[~scene.frozen_and_hidden(p)[0], 0].max()
    assert stiff.front_m[-1] > first_column  # it does bulge a little
    flow = run(0.3, engine=mpm_engine).front_m[-1] - w
    assert sag < 1.5 * sag_scale
    assert sag < 0.2 * flow
    assert run(0.3, engine=mpm_engine).stats["plastic_count"] > 0


def test_runout_decreases_with_eta(mpm_engine):
    fronts = [run(eta, engine=mpm_engine).front_m[-1] for eta in (0.3, 3.0, 30.0)]
    assert fronts[0] > fronts[1] > fronts[2]
    assert fronts[0] - fronts[1] > CELL * 1e-3 and fronts[1] - fronts[2] > 0.5 * CELL * 1e-3


def test_runout_decreases_with_yield_stress(mpm_engine):
    fronts = [run(0.3, sigma_y=sy, engine=mpm_engine).front_m[-1] for sy in (0.0, 20.0, 80.0)]
    assert fronts[0] > fronts[1] > fronts[2]
    assert fronts[0] - fronts[2] > CELL * 1e-3


def test_plane_strain_variant_orders_runouts_like_3d(mpm_engine):
    f2 = [run(eta, dim=2, engine=mpm_engine).front_m[-1] for eta in (0.3, 30.0)]
    f3 = [run(eta, engine=mpm_engine).front_m[-1] for eta in (0.3, 30.0)]
    assert f2[0] > f2[1] and f3[0] > f3[1]
    sim2 = run(0.3, dim=2, engine=mpm_engine)
    assert sim2.stats["dim"] == 2 and sim2.stats["grid_mass_rel_err"] < 2e-5
    # extruded over the depth, frames are 3D positions spanning the box
    f = sim2.frames[0]
    assert f.shape[1] == 3 and f[:, 2].min() < 0 < 0.04 - CELL * 1e-3 < f[:, 2].max() <= 0.04
    # without sideways spreading the plane-strain front runs at least as far as the 3D one
    assert f2[0] >= f3[0] - CELL * 1e-3


def test_repeated_calls_reuse_the_engine_and_its_buffers(monkeypatch):
    """Another material, setup, density and cell width run on the same compiled Taichi engine; its particle
    buffers only grow."""
    from mpm import engine

    monkeypatch.setenv("VIRHEO_ARCH", "taichi-cpu")
    run(0.3)
    eng = engine.engine(3, "f32")
    cap = eng.cap_p
    smaller = mpm.simulate(NS(eta=2.0, n=0.5, sigma_y=1.0), NS(width_mm=25, height_mm=22), density=1100.0,
                           cell_mm=3.0)
    assert engine.engine(3, "f32") is eng
    assert smaller.stats["n_particles"] < cap == eng.cap_p


def test_two_particles_per_axis_sample_the_same_mass_and_report_progress(mpm_engine):
    calls = []
    one = run(0.3, engine=mpm_engine)
    two = mpm.simulate(NS(eta=0.3, n=1.0, sigma_y=0.0), SETUP, density=RHO, cell_mm=CELL, ppc=2,
                       progress=lambda k, total: calls.append((k, total)))
    assert calls == [(k, 8) for k in range(1, 9)]
    assert two.stats["ppc"] == 2 and two.stats["spacing_m"] == pytest.approx(one.stats["spacing_m"] / 2)
    assert two.stats["n_particles"] == pytest.approx(8 * one.stats["n_particles"], rel=0.15)
    assert two.stats["mass_kg"] == pytest.approx(one.stats["mass_kg"], rel=0.1)  # same block, finer lattice
    assert two.stats["grid_mass_rel_err"] < 1e-5
    # a runny material flows a comparable distance at either sampling (not the same: see docs/results.md)
    assert two.front_m[-1] == pytest.approx(one.front_m[-1], rel=0.3)


def test_blow_up_raises_simulation_error(mpm_engine, monkeypatch):
    monkeypatch.setattr(solver, "CFL", 4.0)  # far beyond the elastic stability limit
    with pytest.raises(solver.SimulationError) as e:
        mpm.simulate(NS(eta=0.3, n=1.0, sigma_y=0.0), SETUP, density=RHO, cell_mm=CELL)
    assert isinstance(e.value, RuntimeError) and "\n" not in str(e.value)


@pytest.mark.parametrize("kw", [dict(material=NS(eta=-1.0, n=1.0, sigma_y=0.0)), dict(material=NS(eta=1.0, n=0.0, sigma_y=0.0)),
                                dict(material=NS(eta=1.0, n=1.0, sigma_y=-2.0)), dict(density=0.0), dict(density=-5.0),
                                dict(setup=NS(width_mm=10, height_mm=20)), dict(setup=NS(width_mm=30, height_mm=75)),
                                dict(dim=1), dict(flow_rule="bingham"), dict(precision="f16"), dict(cell_mm=-1.0),
                                dict(ppc=0), dict(ppc=5)])
def test_bad_input_is_a_one_line_value_error(kw):
    args = dict(material=NS(eta=1.0, n=1.0, sigma_y=0.0), setup=SETUP, density=RHO)
    args.update(kw)
    with pytest.raises(ValueError) as e:
        mpm.simulate(args.pop("material"), args.pop("setup"), **args)
    assert "\n" not in str(e.value)


def test_importing_mpm_does_not_start_taichi():
    import subprocess
    import sys

    code = ("import mpm, mpm.camera, mpm.scene, mpm.solver, mpm.constitutive, mpm.shear\n"
            "from mpm import runtime\n"
            "assert not runtime.initialised()\n"
            "assert callable(mpm.simulate)\n")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


def test_f64_option_agrees_with_f32(mpm_engine):
    """precision="f64" (its own process: Taichi holds one default float per process) runs on Taichi's CPU path,
    also where the native engine (f32 only) is chosen, which says so in one line on stderr."""
    import json
    import subprocess
    import sys

    code = ("import json; from types import SimpleNamespace as NS; import mpm\n"
            f"s = mpm.simulate(NS(eta=0.3, n=1.0, sigma_y=0.0), NS(width_mm={SETUP.width_mm}, height_mm={SETUP.height_mm}),"
            f" density={RHO}, cell_mm={CELL}, precision='f64')\n"
            "print(json.dumps([list(s.front_m), s.stats['grid_mass_rel_err'], s.stats['precision'], s.stats['arch']]))\n")
    proc = subprocess.run([sys.executable, "-c", code], check=True, timeout=600, capture_output=True, text=True)
    front64, mass_err, precision, arch = json.loads(proc.stdout.strip().splitlines()[-1])
    assert precision == "f64" and mass_err < 1e-12 and arch == "taichi-cpu"
    notices = [line for line in proc.stderr.splitlines() if "the native engine runs f32" in line]
    assert len(notices) == (1 if mpm_engine == "native" else 0)
    assert np.allclose(front64, run(0.3, engine=mpm_engine).front_m, atol=0.5e-3)


def test_a_slow_first_launch_says_it_is_compiling(monkeypatch, capsys):
    """The first launch of an engine's kernels (Taichi compiling them) prints one line on stderr once it takes
    longer than COMPILE_NOTICE_S; a warm engine, or a quick first launch, prints nothing."""
    import time

    monkeypatch.setattr(solver, "COMPILE_NOTICE_S", 0.05)
    monkeypatch.setitem(solver._NOTICE, "said", False)
    with solver._compile_notice(NS(warm=False)):
        pass
    with solver._compile_notice(NS(warm=True)):
        time.sleep(0.2)
    assert capsys.readouterr().err == ""
    with solver._compile_notice(NS(warm=False)):
        time.sleep(0.3)
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "compiling the simulation kernels" in err


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096 / 1e6


@pytest.mark.skipif(not os.path.exists("/proc/self/statm"), reason="needs Linux /proc for the RSS")
def test_repeated_simulations_do_not_grow_the_process(mpm_engine):
    # a worker of a landscape or conditioning study runs tens of thousands of simulations; each one must give back
    # what it took (Taichi's ndarray.fill on vector arrays kept 8 KB a call: 30 KB a simulation, 0.7 GB a worker)
    run = functools.partial(solver.simulate, NS(eta=1.0, n=0.8, sigma_y=5.0), NS(width_mm=20.0, height_mm=20.0),
                            density=1000.0, cell_mm=5.0, ppc=1, dim=2)
    for _ in range(10):
        run()
    before = _rss_mb()
    for _ in range(150):
        run()
    assert _rss_mb() - before < 1.5  # MB over 150 simulations; with the leak above, 3.2 MB
