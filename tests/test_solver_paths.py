"""The Taichi solver's three CPU code paths (VIRHEO_ARCH=taichi-cpu) simulate the same flow: one thread (a quarter
frame per kernel launch), several threads (a grid copy per thread, summed in the grid update) and atomic adds into
one grid (the CUDA path, forced on the CPU with VIRHEO_MPM_ATOMIC=1). Taichi fixes its thread count per process, so
each path runs in its own."""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parent.parent
SCRIPT = """
import json
from types import SimpleNamespace as NS
from mpm import solver
s = solver.simulate(NS(eta=1.0, n=0.8, sigma_y=5.0), NS(width_mm=30, height_mm=20), density=1000.0, cell_mm=3.0)
print(json.dumps({"front": s.front_m.tolist(), "tasks": s.stats["tasks"], "last": s.frames[-1].tolist()}))
"""


def run_path(**env) -> dict:
    proc = subprocess.run([sys.executable, "-c", SCRIPT], capture_output=True, text=True, cwd=REPO, timeout=300,
                          env={**os.environ, "VIRHEO_ARCH": "taichi-cpu", "VIRHEO_MPM_ATOMIC": "0", **env})
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def paths():
    return {"serial": run_path(VIRHEO_THREADS="1"), "threads": run_path(VIRHEO_THREADS="2"),
            "atomic": run_path(VIRHEO_THREADS="1", VIRHEO_MPM_ATOMIC="1")}


def test_each_path_is_the_one_asked_for(paths):
    assert paths["serial"]["tasks"] == 1
    assert paths["threads"]["tasks"] == 2
    assert paths["atomic"]["tasks"] == 1  # one grid, atomics


@pytest.mark.parametrize("other", ["threads", "atomic"])
def test_paths_agree_on_the_flow(paths, other):
    ref, alt = paths["serial"], paths[other]
    # only the order of float sums differs (measured: 2e-8 m in the runouts, 2e-7 m in any particle at t = 7/24 s)
    assert np.allclose(ref["front"], alt["front"], rtol=0, atol=1e-5)
    a, b = np.array(ref["last"]), np.array(alt["last"])
    assert a.shape == b.shape
    assert np.abs(a - b).max() < 1e-4


BOUNDS_SCRIPT = """
import taichi as ti
from types import SimpleNamespace as NS
from mpm import solver
init = ti.init
ti.init = lambda *a, **k: init(*a, **{**k, "debug": True, "check_out_of_bound": True, "offline_cache": False})
class FirstFrame(Exception):
    pass
def stop(done, total):
    raise FirstFrame
try:
    solver.simulate(NS(eta=0.55, n=0.81, sigma_y=1.95), NS(width_mm=21, height_mm=40), density=1200.0, dim=2,
                    cell_mm=0.75, ppc=4, slip_length_m=0.0, progress=stop)
except FirstFrame:
    print("first frame inside the grid")
"""


def test_every_stencil_lies_inside_the_grid_window():
    """Under Taichi's bounds checks, a lattice whose particles sit where x / dx - l_p / dx is an integer (here
    0.75 mm cells with 4 particles per axis) scatters into and gathers from the grid window only. Should the
    window's bounding box and the transfers round that expression differently, a transfer writes one node row
    in front of the grid (a segmentation fault, or silently corrupted memory)."""
    proc = subprocess.run([sys.executable, "-c", BOUNDS_SCRIPT], capture_output=True, text=True, cwd=REPO,
                          timeout=600, env={**os.environ, "VIRHEO_ARCH": "taichi-cpu", "VIRHEO_THREADS": "1"})
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "first frame inside the grid" in proc.stdout


def test_native_engine_threads_agree_with_one(monkeypatch):
    """The native engine's threads (VIRHEO_THREADS, read at each simulation) simulate the serial flow; only the
    order of float sums may differ."""
    from types import SimpleNamespace as NS

    import engines
    from mpm import solver

    monkeypatch.setenv("VIRHEO_ARCH", engines.require("native"))
    sims = {}
    for threads in ("1", "2"):
        monkeypatch.setenv("VIRHEO_THREADS", threads)
        sims[threads] = solver.simulate(NS(eta=1.0, n=0.8, sigma_y=5.0), NS(width_mm=30, height_mm=20),
                                        density=1000.0, cell_mm=3.0)
    assert [s.stats["tasks"] for s in sims.values()] == [1, 2]
    assert np.allclose(sims["1"].front_m, sims["2"].front_m, rtol=0, atol=1e-5)
    a, b = sims["1"].frames[-1], sims["2"].frames[-1]
    assert a.shape == b.shape and np.abs(a - b).max() < 1e-4


def test_native_instruction_sets_agree(monkeypatch):
    """Every instruction set this CPU runs (VIRHEO_NATIVE_ISA: AVX-512, AVX2 with its 32-byte registers, generic)
    simulates the same flow, 2D and 3D. They differ in the last bits of float operations, which the free surface
    amplifies in a few particles (measured, AVX2 against generic: runouts within 4e-6 m; 99.9 % of the particles
    within 9e-5 m after 1/3 s, the farthest 0.7 mm, a quarter of the 3 mm cell)."""
    from types import SimpleNamespace as NS

    import engines
    from mpm import native_engine, solver

    monkeypatch.setenv("VIRHEO_ARCH", engines.require("native"))
    runs = native_engine._native.isas()
    for dim, setup, cell in ((3, NS(width_mm=30, height_mm=20), 3.0), (2, NS(width_mm=21, height_mm=40), 2.0)):
        sims = {}
        for isa in runs:
            monkeypatch.setenv("VIRHEO_NATIVE_ISA", isa)
            sims[isa] = solver.simulate(NS(eta=0.55, n=0.81, sigma_y=1.95), setup, density=1200.0, cell_mm=cell,
                                        ppc=2, dim=dim)
            assert sims[isa].stats["isa"] == isa
        ref = sims[runs[0]]
        for isa, sim in sims.items():
            assert np.allclose(ref.front_m, sim.front_m, rtol=0, atol=1e-5), (dim, isa)
            assert ref.frames[-1].shape == sim.frames[-1].shape
            moved = np.linalg.norm(ref.frames[-1] - sim.frames[-1], axis=1)
            assert np.quantile(moved, 0.999) < 2e-4 and moved.max() < cell * 1e-3, (dim, isa)  # within a cell


FLUSH_SCRIPT = """
import numpy as np
from types import SimpleNamespace as NS
from mpm import solver
def keeps():  # 1e-39 is subnormal in float32: flush-to-zero makes it 0
    return bool(np.float32(1e-39) * np.float32(1.0) != 0)
before, seen = keeps(), []
solver.simulate(NS(eta=1.0, n=0.8, sigma_y=5.0), NS(width_mm=30, height_mm=20), density=1000.0, cell_mm=6.0,
                progress=lambda k, n: seen.append(keeps()))
print(before, len(seen), all(seen), keeps())
"""


def test_native_engine_flushes_subnormals_only_while_it_simulates():
    """The native engine flushes subnormal floats to zero in its own arithmetic (as Taichi does once initialised);
    the caller's floating-point mode is untouched, after the run and inside its progress callback (where Python
    runs). In a fresh interpreter: Taichi's own init would turn flushing on for the whole process."""
    import engines

    engines.require("native")
    proc = subprocess.run([sys.executable, "-c", FLUSH_SCRIPT], capture_output=True, text=True, cwd=REPO, timeout=300,
                          env={**os.environ, "VIRHEO_ARCH": "native"})
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip().splitlines()[-1] == "True 8 True True"


def test_native_constants_are_the_python_ones():
    """The flag bits and error codes are defined once, in mpm.solver_constants; the C++ engine's constexpr copies
    carry the same values, and the Taichi engine imports them."""
    import re

    from mpm import kernels, solver_constants as C

    native = Path(__file__).resolve().parent.parent / "mpm" / "native"
    cpp = {name: int(value) for name, value in re.findall(r"\b([A-Z_]+) = (\d+)\b", (native / "types.h").read_text())}
    text = (native / "kernel.h").read_text() + (native / "engine.cpp").read_text()
    for name in ("HIDDEN", "PLASTIC", "FROZEN", "ERR_NAN", "ERR_LEFT_REACH", "ERR_SPEED", "ERR_INTERRUPTED"):
        assert cpp[name] == getattr(C, name), name
    assert (kernels.HIDDEN, kernels.PLASTIC, kernels.FROZEN, kernels.ERRORS) == (C.HIDDEN, C.PLASTIC, C.FROZEN, C.ERRORS)
    # the C++ sources use the named codes, not bare numbers
    assert not re.search(r"(res\.error = |return )[1-4];", text)


def test_native_time_step_schedule_is_the_python_one():
    """The CFL schedule is written once per language: the C++ ``substeps`` (types.h, which the engine's run loop
    calls) gives the Python ``mpm.engine_run.substeps``'s steps and step bit for bit, over times, speeds, cells and
    wave speeds from a crawl to the speed limit (the cell width as the engine holds it, in float32)."""
    from types import SimpleNamespace as NS

    from mpm import native_engine
    from mpm.engine_run import substeps
    from mpm.params import N_FRAMES, frame_times

    if not native_engine.available():
        pytest.skip(native_engine.why_unavailable())
    from mpm import _native

    rng = np.random.default_rng(0)
    ends = frame_times()
    checked = 0
    for _ in range(400):
        k = int(rng.integers(N_FRAMES))
        t = float(rng.uniform(0.0, ends[k]))
        scene = NS(cell_m=float(np.float32(rng.uniform(0.2e-3, 10e-3))), wave_speed=float(rng.uniform(0.5, 60.0)),
                   gravity=9.81)
        for vmax in (0.0, float(rng.uniform(0, 2)), float(rng.uniform(2, 60))):
            cfl = float(rng.choice([0.5, 0.3, 0.65]))
            want = substeps(t, float(ends[k]), vmax, scene, cfl)
            got = _native.substeps(t, float(ends[k]), vmax, scene.cell_m, scene.wave_speed, scene.gravity, cfl)
            assert got == want, (t, vmax, scene, cfl)
            checked += want[0] > 1
    assert checked > 300  # most cases take several steps, so the rounding of m is exercised
    # the engine's run loop calls it, rather than writing the schedule again
    kernel = (Path(__file__).resolve().parent.parent / "mpm" / "native" / "kernel.h").read_text()
    assert "substeps(t, t_target, vm," in kernel and "std::ceil" not in kernel.split("Result run(")[1].split("Result finish")[0]
