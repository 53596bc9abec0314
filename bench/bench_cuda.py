"""Taichi's CUDA path against a CPU engine: silhouettes, loss and throughput of the solver on one GPU.

    VIRHEO_DATA=... python bench/bench_cuda.py [--experiment FOLDER] [--models 1.5:1 1.26:2 0.75:2]
                                               [--cpu-models 1.5:1 1.26:2] [--cpu-engine native] [--cpu-threads 2]
                                               [--population 16] [--workers 1 4 8] [--cpu-workers 2]

For one shared experiment at its Table-1 parameters, walls slipping by the footage model's slip length:

1. each ``--models`` discretisation (cell mm : particles per cell per axis) on CUDA: particles, steps, simulation
   seconds, particle-steps per second and the eq.-3 loss against the footage;
2. each ``--cpu-models`` one on the CPU engine ``--cpu-engine`` (``native``, the default, or ``taichi-cpu``; one
   process, ``--cpu-threads`` threads, default 1) and, for those, how far CUDA is from the CPU: mean and min
   silhouette IoU over the 8 frames, the loss of each, the runout difference and the speed ratio;
3. a population of ``--population`` materials around Table 1 (log-normal, as a CMA-ES generation) at the
   default discretisation, simulated by 1, 4, 8 ... worker processes sharing the GPU, and by ``--cpu-workers``
   one-thread processes of the CPU engine (0: skip): simulations per second.

The first simulation of each process compiles the kernels (or loads them from Taichi's offline cache); it is
run at 6 mm and reported apart. Needs a CUDA device (``VIRHEO_ARCH=cuda`` is set for the CUDA workers).
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from contextlib import contextmanager
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402
from bench_engine_speed import parse_model  # noqa: E402  (bench/ is this script's folder)
from measured import how_measured  # noqa: E402


@contextmanager
def arch_env(arch: str, threads: int, cores: int = 0):
    """Worker processes spawned inside inherit this engine ($VIRHEO_ARCH), thread count and, with ``cores`` > 0,
    the first ``cores`` processors of this one."""
    old = {k: os.environ.get(k) for k in ("VIRHEO_ARCH", "VIRHEO_THREADS")}
    os.environ.update(VIRHEO_ARCH=arch, VIRHEO_THREADS=str(threads))
    affinity = os.sched_getaffinity(0) if cores > 0 and hasattr(os, "sched_setaffinity") else None
    if affinity is not None:
        os.sched_setaffinity(0, sorted(affinity)[:cores])
    try:
        yield
    finally:
        if affinity is not None:
            os.sched_setaffinity(0, affinity)
        for k, v in old.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def run(requests, workers: int):
    """Results of ``requests`` on ``workers`` fresh processes (none stored), and the wall time of all."""
    from mpm.forward import Forward

    t = time.perf_counter()
    with Forward(workers=workers) as forward:
        out = forward.evaluate(requests)
    return out, time.perf_counter() - t


def main(argv=None) -> int:
    from dataclasses import replace

    from mpm import experiment as xp
    from mpm.datasets import manifest, real_world_dir, table1
    from mpm.loss import iou, video_loss
    from mpm.forward import Forward
    from mpm.params import Material
    from similarity.presets import FOOTAGE_SLIP_LENGTH_M, VALIDATED

    request = Forward().request  # requests only: each run() below has its own executor

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--experiment", default="ref_JapaneseThickenedWorcestershireSauce_4.0_2.1_1")
    ap.add_argument("--models", nargs="*", default=["1.5:1", "1.26:2"], help="CUDA discretisations CELL_MM:PPC")
    ap.add_argument("--cpu-models", nargs="*", default=["1.5:1"], help="also on the CPU, compared with CUDA")
    ap.add_argument("--cpu-engine", choices=("native", "taichi-cpu"), default="native", help="the CPU engine")
    ap.add_argument("--cpu-threads", type=int, default=1, help="threads of the CPU process")
    ap.add_argument("--cpu-workers", type=int, default=0, help="CPU processes for the population (0: skip)")
    ap.add_argument("--cpu-cores", type=int, default=0,
                    help="run the CPU engine on this many cores of the machine (0: all), e.g. 2 for a laptop")
    ap.add_argument("--population", type=int, default=16, help="materials in the population (0: skip)")
    ap.add_argument("--workers", type=int, nargs="*", default=[1, 4, 8], help="CUDA processes for the population")
    ap.add_argument("--slip-m", type=float, default=FOOTAGE_SLIP_LENGTH_M, help="walls' slip length in metres")
    a = ap.parse_args(argv)
    try:
        models = [replace(parse_model(m), slip_length_m=a.slip_m) for m in a.models]
        cpu_models = [replace(parse_model(m), slip_length_m=a.slip_m) for m in a.cpu_models]
    except ValueError as exc:
        raise SystemExit(f"bench_cuda: {exc}") from None
    row = next((r for r in manifest() if r["folder"] == a.experiment), None)
    if row is None:
        raise SystemExit(f"bench_cuda: no shared experiment {a.experiment!r}")
    exp = xp.load(str(Path(real_world_dir()) / a.experiment))
    mat = table1(row)
    cores = os.cpu_count() or 1
    warm = replace(VALIDATED, cell_mm=6.0, slip_length_m=a.slip_m)
    print(f"# measured: {how_measured()}", flush=True)
    print(f"# {a.experiment} at Table 1 ({mat.eta:g} Pa s^n, {mat.n:g}, {mat.sigma_y:g} Pa), slip {a.slip_m * 1e3:g} mm;"
          f" {cores} CPU cores", flush=True)

    results = {}
    print("| arch | cell mm | ppc | particles | steps | sim s | wall s | Mpstep/s | loss |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for arch, threads, todo in (("cuda", 1, models), (a.cpu_engine, max(1, a.cpu_threads), cpu_models)):
        if not todo:
            continue
        with arch_env(arch, threads, 0 if arch == "cuda" else a.cpu_cores):
            reqs = [request(mat, exp, warm)] + [request(mat, exp, m) for m in todo]
            out, _ = run(reqs, 1)
        print(f"# {arch}: first simulation (6 mm, kernels compiled or loaded) {out[0].wall_seconds:.1f} s", flush=True)
        for m, res in zip(todo, out[1:]):
            if not res.ok:
                print(f"| {arch} | {m.cell_mm:g} | {m.ppc} | failed: {res.error} |")
                continue
            s = res.stats
            loss = video_loss(res.silhouettes, exp.frames)
            results[arch, m.cell_mm, m.ppc] = res
            print(f"| {s['arch']} | {m.cell_mm:g} | {m.ppc} | {s['n_particles']} | {s['steps']} | {s['sim_s']:.2f} | "
                  f"{res.wall_seconds:.2f} | {s['particle_steps_per_s'] / 1e6:.1f} | {loss:.5f} |", flush=True)
    for m in cpu_models:
        g, c = results.get(("cuda", m.cell_mm, m.ppc)), results.get((a.cpu_engine, m.cell_mm, m.ppc))
        if g is None or c is None:
            continue
        ious = [iou(x, y) for x, y in zip(g.silhouettes, c.silhouettes)]
        print(f"# {m.cell_mm:g} mm, {m.ppc} ppc: CUDA vs {a.cpu_engine} silhouette IoU mean {np.mean(ious):.4f} min "
              f"{np.min(ious):.4f}; loss {video_loss(g.silhouettes, exp.frames):.5f} vs "
              f"{video_loss(c.silhouettes, exp.frames):.5f}; runout differs by "
              f"{abs(g.front_m[-1] - c.front_m[-1]) * 1e3:.2f} mm; speed {g.stats['particle_steps_per_s'] / c.stats['particle_steps_per_s']:.1f}x "
              f"{a.cpu_engine} ({a.cpu_threads} threads, {a.cpu_cores or cores} cores)", flush=True)

    if a.population > 0 and a.workers:
        rng = np.random.default_rng(0)
        jitter = np.exp(0.15 * rng.standard_normal((a.population, 3)))
        pop = [Material(mat.eta * j[0], min(mat.n * j[1], 1.5), mat.sigma_y * j[2]) for j in jitter]
        model = replace(VALIDATED, slip_length_m=a.slip_m)
        reqs = [request(p, exp, model) for p in pop]
        base = None
        for k in a.workers:
            with arch_env("cuda", 1):
                run([request(mat, exp, warm)], 1)  # offline cache filled before the pool starts
                out, wall = run(reqs, k)
            ok = sum(r.ok for r in out)
            rate = ok / wall
            base = base or rate
            sim_s = np.median([r.stats["sim_s"] for r in out if r.ok])
            print(f"# population of {a.population} at {model.resolved().cell_mm:g} mm: {k} CUDA processes "
                  f"{wall:.1f} s wall ({ok} ok), {rate:.2f} simulations/s ({rate / base:.2f}x one process), "
                  f"median {sim_s:.2f} s simulating each", flush=True)
        if a.cpu_workers > 0:
            with arch_env(a.cpu_engine, 1, a.cpu_cores):  # requests name the engine they were made for
                run([request(mat, exp, warm)], 1)
                out, wall = run([request(p, exp, model) for p in pop], a.cpu_workers)
            ok = sum(r.ok for r in out)
            sim_s = np.median([r.stats["sim_s"] for r in out if r.ok])
            print(f"# the same population on {a.cpu_workers} {a.cpu_engine} processes (one thread each): "
                  f"{wall:.1f} s wall ({ok} ok), {ok / wall:.2f} simulations/s ({ok / wall / base:.2f}x one CUDA "
                  f"process), median {sim_s:.2f} s simulating each", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
