"""Speed of the native engine against the Taichi reference (taichi-cpu), one thread each, 3D.

For each setup and discretisation (cell mm : particles per cell per axis) both engines simulate the same dam-break
``--rounds`` times in this process, alternating which goes first (so that the load of a shared machine hits both
alike), after one warm-up call each (6 mm: Taichi loads or compiles its kernels). Printed per case: M
particle-steps per second of simulation time (particles x steps / ``stats["sim_s"]``, median over the rounds) of
each engine, their ratio, the silhouette IoU of native against taichi through ``Camera.default()`` (min over the
8 frames, last round), the largest runout difference, and the verdict against the targets: native >= 6x
taichi-cpu at two particles per axis, >= 4x at one; stretch: native >= 20 M particle-steps/s.
Material: Japanese thickened Worcestershire sauce at Table 1 (0.55 Pa s^n, 0.81, 1.95 Pa), 1200 kg/m^3.

    python bench/bench_engine_speed.py                                   # 30x20 and 70x70 at 1.5:1 1.5:2 1.26:2
    python bench/bench_engine_speed.py --setups 30x20 --rounds 3         # Taichi at 70x70, 1.26:2: ~15 min a run
    python bench/bench_engine_speed.py --setups 70x70 --models 1.5:1 1.5:2
    python bench/bench_engine_speed.py --callgrind                       # instructions per particle-step instead
    python bench/bench_engine_speed.py --native-only --setups 30x20 --models 2.5:2 --rounds 3   # native alone

``--callgrind`` runs a short simulation (30 x 20 mm, 2.5 mm cells, 2 particles per axis) of each engine under
``valgrind --tool=callgrind`` and prints instructions per particle-step: (Ir of a process that simulates - Ir of
the same process that only builds the scene) / (particles x steps); both processes first make the 6 mm warm-up
call. Valgrind has no AVX-512: native runs its AVX2 path there (``VIRHEO_NATIVE_ISA=avx2``), and Taichi compiles
its kernels for the CPU valgrind presents, into an empty cache (primed once under ``--tool=none``). The Taichi runs
take several minutes.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))
sys.path.insert(0, str(HERE))  # bench/: the agreement measure lives in bench_engine_agreement

import numpy as np  # noqa: E402

from bench_engine_agreement import ENGINES, Agreement, simulate_on  # noqa: E402
from measured import how_measured, load  # noqa: E402

MATERIAL = "0.55,0.81,1.95"  # Japanese thickened Worcestershire sauce, Table 1 (eta Pa s^n, n, sigma_y Pa)
DENSITY = 1200.0  # kg/m^3, the sauce's
SETUPS = ("30x20", "70x70")
MODELS = ("1.5:1", "1.5:2", "1.26:2")
TARGET = {1: 4.0, 2: 6.0}  # native / taichi-cpu at (at least) this many particles per cell per axis
STRETCH = 20.0  # M particle-steps/s of the native engine
WARM_UP = ("30x20", "6:1")
CALLGRIND = ("30x20", "2.5:2")  # a short simulation under valgrind


def parse_model(text: str):
    """'CELL_MM:PPC' -> ForwardModel (mpm.forward); ValueError (one line) otherwise."""
    from mpm.forward import ForwardModel

    cell, _, ppc = text.partition(":")
    try:
        model = ForwardModel(float(cell), int(ppc or 1))
    except ValueError:
        raise ValueError(f"model {text!r}: give CELL_MM:PPC, e.g. 1.5:1") from None
    if not (model.cell_mm > 0 and model.ppc >= 1):
        raise ValueError(f"model {text!r}: a cell width > 0 mm and >= 1 particle per axis")
    return model


def rate(sim) -> float:
    """M particle-steps per second of simulation time."""
    return sim.stats["n_particles"] * sim.stats["steps"] / sim.stats["sim_s"] / 1e6


def timing(a, material, setups, models) -> int:
    from mpm.camera import Camera
    from mpm.params import Setup

    cam = Camera.default()
    engines = ("native",) if a.native_only else ENGINES
    print(f"# {' vs '.join(engines)}, one thread each, 3D; material eta {material.eta:g} Pa s^n, n {material.n:g}, "
          f"sigma_y {material.sigma_y:g} Pa, density {a.density:g} kg/m^3, depth 40 mm, sticking walls; "
          f"{a.rounds} round(s) per case, engines alternating")
    print(f"# measured: {how_measured()}", flush=True)
    w_setup, w_model = Setup.parse(WARM_UP[0]), parse_model(WARM_UP[1])
    for engine in engines:
        s = simulate_on(engine, material, w_setup, density=a.density, cell_mm=w_model.cell_mm, ppc=w_model.ppc)
        print(f"# warm-up {engine} ({w_setup} mm, {w_model.cell_mm:g} mm cells): {s.stats['wall_s']:.1f} s wall",
              flush=True)
    print(f"{'setup':>6} {'model':>7} {'round':>5} {'engine':>10} {'particles':>9} {'steps':>5} {'sim s':>7} "
          f"{'Mpstep/s':>8}  load")
    rows = []
    for setup in setups:
        for text, model in models:
            rates = {e: [] for e in engines}
            last = {}
            for r in range(a.rounds):
                for engine in (engines if r % 2 == 0 else engines[::-1]):
                    sim = simulate_on(engine, material, setup, density=a.density, cell_mm=model.cell_mm,
                                      ppc=model.ppc, camera=cam)
                    rates[engine].append(rate(sim))
                    last[engine] = sim
                    print(f"{str(setup):>6} {text:>7} {r + 1:5d} {engine:>10} {sim.stats['n_particles']:9d} "
                          f"{sim.stats['steps']:5d} {sim.stats['sim_s']:7.2f} {rate(sim):8.3f}  {load()}",
                          flush=True)
            med = {e: float(np.median(v)) for e, v in rates.items()}
            if a.native_only:
                print(f"{str(setup):>6} {text:>7} median {med['native']:.3f} M particle-steps/s (native, isa "
                      f"{last['native'].stats['isa']})", flush=True)
                continue
            rows.append((setup, model, last, med, Agreement.of(last["taichi-cpu"], last["native"])))
    if a.native_only:
        return 0
    print(f"\n| setup | cell mm, particles per axis | particles | steps taichi / native | taichi-cpu M p-steps/s | "
          f"native M p-steps/s | native / taichi | target | IoU min | max \\|Δ front\\| mm | verdict |")
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|")
    for setup, model, last, med, ag in rows:
        ta, na = last["taichi-cpu"].stats, last["native"].stats
        ratio = med["native"] / med["taichi-cpu"]
        target = TARGET[min(model.ppc, 2)]
        verdict = ("met" if ratio >= target else "MISSED") + (", stretch met" if med["native"] >= STRETCH else "")
        print(f"| {setup} mm | {model.cell_mm:g}, {model.ppc} | {na['n_particles']:,} | {ta['steps']} / {na['steps']} | "
              f"{med['taichi-cpu']:.2f} | {med['native']:.2f} | **{ratio:.1f}x** | {target:g}x | "
              f"{ag.ious.min():.4f} | {ag.front_diff_m * 1e3:.3f} | {verdict} |")
    print(f"\n# targets: native >= {TARGET[2]:g}x taichi-cpu at two particles per axis, >= {TARGET[1]:g}x at one; "
          f"stretch >= {STRETCH:g} M particle-steps/s (medians of {a.rounds} round(s), simulation time only); "
          f"done at load {load()}")
    return 0


# ---------------------------------------------------------------------------------------------------- callgrind
def callgrind_child(engine: str, mode: str, a) -> int:
    """Under valgrind: the warm-up call, then build the scene (mode "build") or also simulate it ("simulate");
    prints particles and steps as JSON."""
    from mpm import scene as sc
    from mpm.params import Setup

    setup, model = Setup.parse(CALLGRIND[0]), parse_model(CALLGRIND[1])
    material = parse_material(a.material)
    w_model = parse_model(WARM_UP[1])
    simulate_on(engine, material, Setup.parse(WARM_UP[0]), density=a.density, cell_mm=w_model.cell_mm,
                ppc=w_model.ppc)
    if mode == "build":
        s = sc.DamBreak.build(setup, density=a.density, cell_mm=model.cell_mm, ppc=model.ppc)
        s.frozen_and_hidden(s.particles())
        print(json.dumps({}))
        return 0
    sim = simulate_on(engine, material, setup, density=a.density, cell_mm=model.cell_mm, ppc=model.ppc)
    print(json.dumps(dict(n=sim.stats["n_particles"], steps=sim.stats["steps"], isa=sim.stats.get("isa"))))
    return 0


def total_ir(path: Path) -> int:
    """Instructions executed (Ir), all threads, from a callgrind output file."""
    m = re.search(r"^(?:summary|totals):\s*(\d+)", path.read_text(), re.M)
    if m is None:
        raise ValueError(f"{path}: no summary line (did valgrind fail?)")
    return int(m.group(1))


def callgrind(a) -> int:
    if shutil.which("valgrind") is None:
        raise ValueError("--callgrind needs valgrind on the PATH")
    os.environ["VIRHEO_NATIVE_ISA"] = "avx2"  # the children's path, and how_measured's
    tmp = Path(tempfile.mkdtemp(prefix="virheo-callgrind-"))
    env = dict(os.environ, VIRHEO_THREADS="1", TI_OFFLINE_CACHE_FILE_PATH=str(tmp / "ti"))
    child = [sys.executable, __file__, "--material", a.material, "--density", str(a.density), "--callgrind-child"]
    print(f"# instructions per particle-step under valgrind --tool=callgrind: {CALLGRIND[0]} mm, model "
          f"{CALLGRIND[1]} (cell mm : particles per axis), one thread; material {a.material}, density "
          f"{a.density:g}; native path avx2 (valgrind has no AVX-512)")
    print(f"# measured: {how_measured()}", flush=True)

    def run(tool: list[str], engine: str, mode: str) -> dict:
        p = subprocess.run(["valgrind", "-q", *tool, *child, engine, mode], env=dict(env, VIRHEO_ARCH=engine),
                           capture_output=True, text=True)
        lines = [ln for ln in p.stdout.splitlines() if ln.startswith("{")]
        if p.returncode != 0 or not lines:
            tail = (p.stderr.strip().splitlines() or ["no output"])[-1]
            raise ValueError(f"valgrind {engine} {mode} failed (exit {p.returncode}): {tail}")
        return json.loads(lines[-1])

    rows = {}
    for engine in ("native",) if a.native_only else ENGINES[::-1]:  # native first: it is quick
        if engine == "taichi-cpu":  # compile Taichi's kernels for valgrind's CPU into the empty cache
            run(["--tool=none"], engine, "build")
        ir, info = {}, {}
        for mode in ("build", "simulate"):
            out = tmp / f"callgrind.{engine}.{mode}"
            info.update(run(["--tool=callgrind", f"--callgrind-out-file={out}"], engine, mode))
            ir[mode] = total_ir(out)
        ps = info["n"] * info["steps"]
        rows[engine] = (ir["simulate"] - ir["build"]) / ps
        print(f"# {engine}: {info['n']} particles x {info['steps']} steps; Ir {ir['simulate']:,} simulating, "
              f"{ir['build']:,} building only: {rows[engine]:,.0f} instructions per particle-step"
              + (f" (isa {info['isa']})" if info.get("isa") else "") + f"; load {load()}", flush=True)
    print(f"\n| engine | instructions per particle-step |\n|---|---:|")
    for engine, v in rows.items():
        print(f"| {engine} | {v:,.0f} |")
    if a.native_only:
        shutil.rmtree(tmp, ignore_errors=True)
        return 0
    print(f"\n# native executes {rows['taichi-cpu'] / rows['native']:.1f}x fewer instructions per particle-step than "
          f"taichi-cpu (its AVX2 path; Taichi compiled for valgrind's CPU)")
    shutil.rmtree(tmp, ignore_errors=True)
    return 0


def parse_material(text: str):
    from mpm.params import Material

    return Material.parse(text)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--setups", nargs="+", default=list(SETUPS), help="W x H in mm, e.g. 30x20 70x70")
    ap.add_argument("--models", nargs="+", default=list(MODELS), help="CELL_MM:PPC, e.g. 1.5:1 1.5:2 1.26:2")
    ap.add_argument("--rounds", type=int, default=2, help="runs of each engine per case (alternating order)")
    ap.add_argument("--material", default=MATERIAL, help="ETA,N,SIGMA_Y (Pa s^n, -, Pa)")
    ap.add_argument("--density", type=float, default=DENSITY, help="kg/m^3")
    ap.add_argument("--native-only", action="store_true",
                    help="the native engine alone (its path: $VIRHEO_NATIVE_ISA or the CPU's best; avx2 under "
                    "--callgrind); no ratio to taichi-cpu")
    ap.add_argument("--callgrind", action="store_true", help="instructions per particle-step under valgrind instead")
    ap.add_argument("--callgrind-child", nargs=2, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    try:
        if a.callgrind_child:
            return callgrind_child(*a.callgrind_child, a)
        from mpm import runtime
        from mpm.params import Setup

        material = parse_material(a.material)
        setups = [Setup.parse(s).check_in_space() for s in a.setups]
        models = [(f"{m.cell_mm:g}:{m.ppc}", m) for m in map(parse_model, a.models)]
        if a.rounds < 1:
            raise ValueError(f"--rounds {a.rounds}: give at least 1")
        missing = runtime.native_missing()
        if missing is not None:
            raise ValueError(f"the native engine is not available: {missing}")
        os.environ["VIRHEO_THREADS"] = "1"
        return callgrind(a) if a.callgrind else timing(a, material, setups, models)
    except (ValueError, FileNotFoundError) as exc:
        print(f"bench_engine_speed: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
