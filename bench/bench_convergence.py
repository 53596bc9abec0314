"""Convergence under refinement and agreement with the footage, with and without wall slip.

For each shared experiment at its Table-1 parameters and each slip length: the mean (and min) silhouette IoU
of the default cell width against a 2x finer one (8 frames through the experiment's camera), and the video
loss of both against the footage. One simulation per process, ``--workers`` at a time (one Taichi thread each).

    python bench/bench_convergence.py                                    # the 4 thin-film-prone ones below
    python bench/bench_convergence.py --experiments all --slip-m 0 0.002  # all 14 (hours on 2 cores)
    python bench/bench_convergence.py --experiments ref_Lotion_2.5_5.1_1 --cell-mm 1.5 --fine-mm 0.75
    python bench/bench_convergence.py --experiments EXP --slip-m 0.001 --cell-mm 2 --ppc 2  # two particles per axis
    python bench/bench_convergence.py --experiments all --slip-m 0 --density-correction  # with the density correction
"""
import argparse
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from types import SimpleNamespace as NS

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402
from measured import how_measured  # noqa: E402  (bench/ is this script's folder)

DEFAULT_EXPERIMENTS = ("ref_JapaneseThickenedWorcestershireSauce_2.0_3.0_2", "ref_Lotion_2.5_5.1_1",
                       "ref_Cobb_2.0_2.9_2", "ref_Carbonara_2.0_2.5_2")


def _one(job):
    folder, cell, slip, ppc, corrected = job
    from mpm import solver
    from mpm.datasets import manifest, real_world_dir
    from mpm.experiment import load
    from mpm.loss import video_loss

    row = next(r for r in manifest() if r["folder"] == folder)
    mat = NS(eta=float(row["paper_eta_Pa_s_n"]), n=float(row["paper_n"]), sigma_y=float(row["paper_sigma_y_Pa"]))
    exp = load(real_world_dir() / folder)
    t = time.perf_counter()
    try:
        sim = solver.simulate(mat, NS(width_mm=exp.width_mm, height_mm=exp.height_mm), density=exp.density,
                              cell_mm=cell, camera=exp.camera, depth_mm=exp.depth_mm, slip_length_m=slip,
                              ppc=ppc, density_correction=corrected)
    except (ValueError, solver.SimulationError) as exc:  # too many particles, or the run blew up
        return f"{cell:g} mm: {exc}"
    return sim.silhouettes, float(video_loss(sim.silhouettes, exp.frames)), sim.front_m[-1] * 1e3, \
        time.perf_counter() - t


def _init():
    os.environ["VIRHEO_THREADS"] = "1"
    os.nice(int(os.environ.get("BENCH_NICE", "0")))


def main(argv=None) -> int:
    from mpm.datasets import manifest
    from mpm.loss import iou
    from mpm.solver import DEFAULT_CELL_MM

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--experiments", nargs="+", default=list(DEFAULT_EXPERIMENTS), help="folders, or all")
    ap.add_argument("--slip-m", type=float, nargs="+", default=[0.0, 0.002], help="slip lengths in metres")
    ap.add_argument("--cell-mm", type=float, default=DEFAULT_CELL_MM)
    ap.add_argument("--fine-mm", type=float, default=None, help="default: cell / 2")
    ap.add_argument("--ppc", type=int, default=1, help="particles per cell per axis, both runs")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--density-correction", action="store_true", help="the solver's density correction, both runs")
    a = ap.parse_args(argv)
    if a.ppc < 1:
        ap.error(f"--ppc {a.ppc}: give a whole number >= 1")
    known = [r["folder"] for r in manifest()]
    folders = known if a.experiments == ["all"] else [Path(f).name for f in a.experiments]
    unknown = [f for f in folders if f not in known]
    if unknown:
        ap.error(f"--experiments {unknown[0]}: not a shared experiment (one of {', '.join(known)}, or all)")
    fine = a.fine_mm or a.cell_mm / 2
    jobs = [(f, c, b, a.ppc, a.density_correction) for f in folders for b in a.slip_m for c in (a.cell_mm, fine)]
    print(f"# measured: {how_measured()}", flush=True)
    print(f"# IoU of cell {a.cell_mm:g} mm vs {fine:g} mm ({a.ppc} particle(s) per cell per axis), Table-1 parameters; "
          f"loss = video loss against the footage{'; density-corrected' if a.density_correction else ''}")
    print(f"{'experiment':<52} {'slip mm':>7} {'mean IoU':>8} {'min IoU':>8} {'loss':>7} {'loss fine':>9} "
          f"{'front':>6} {'fine':>6} {'s':>5} {'s fine':>6}")
    rows = {}
    with ProcessPoolExecutor(a.workers, initializer=_init) as pool:
        results = pool.map(_one, jobs)  # in job order: each row prints as soon as its pair is done
        for (f, _, b, _, _), ra, rb in zip(jobs[::2], results, results):
            failed = [r for r in (ra, rb) if isinstance(r, str)]
            if failed:
                print(f"{f:<52} {b * 1e3:7.2f} failed: {'; '.join(failed)}", flush=True)
                continue
            (sa, la, fa, ta), (sb, lb, fb, tb) = ra, rb
            ious = np.array([iou(x, y) for x, y in zip(sa, sb)])
            rows.setdefault(b, []).append((ious.mean(), la))
            print(f"{f:<52} {b * 1e3:7.2f} {ious.mean():8.4f} {ious.min():8.4f} {la:7.4f} {lb:9.4f} {fa:6.1f} "
                  f"{fb:6.1f} {ta:5.0f} {tb:6.0f}", flush=True)
    for b, r in rows.items():
        r = np.array(r)
        print(f"# slip {b * 1e3:g} mm: mean IoU {r[:, 0].mean():.4f}, worst {r[:, 0].min():.4f}; "
              f"mean loss {r[:, 1].mean():.4f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
