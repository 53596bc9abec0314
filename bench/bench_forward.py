"""Forward-model benchmark: one evaluation = simulation to 1/3 s + 8 silhouettes.

Prints, for 30 x 20 mm and 70 x 70 mm setups at the paper's cell width (1.26 mm) and at our default:
wall time, CPU time (all threads; robust to other load on a shared machine), particles, steps and
particle-steps per second; then the silhouette convergence (IoU of the default against a 2x finer cell
width) on shared experiments at their paper Table-1 parameters, and the loss of the Worcestershire
setup-2 footage at the experimenters' setup-1 estimate (the reference implementation's pipeline gives 0.0040).

    python bench/bench_forward.py                 # everything but the 70 x 70 mm run at 1.26 mm
    python bench/bench_forward.py --paper-70      # also that one (~900k particles, tens of minutes)
    python bench/bench_forward.py --experiments 4 # convergence on the first 4 (small) shared experiments only
    python bench/bench_forward.py --skip-timing --skip-loss --min-area-mm2 1000 --max-area-mm2 5000  # the large ones
    python bench/bench_forward.py --skip-timing --skip-convergence   # just the Worcestershire loss
"""
import argparse
import os
import sys
import time
from pathlib import Path
from types import SimpleNamespace as NS

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import mpm  # noqa: E402
from mpm import runtime, solver  # noqa: E402
from mpm.camera import Camera  # noqa: E402
from mpm.params import DEFAULT_DENSITY_KG_M3, DEFAULT_DEPTH_MM  # noqa: E402
from measured import how_measured  # noqa: E402  (bench/ is this script's folder)

REFERENCE_S = 570.0 + 8 * 24.0  # the reference implementation: 4500 steps in 570 s + 8 frames skinned at 19-32 s each
PAPER = ("paper", 1.26, 2)  # the reference's discretisation: 1.26 mm cells, 2 particles per cell per axis


def load() -> str:
    return "load %.1f/%.1f" % os.getloadavg()[:2]


def evaluate(material, setup, *, density=DEFAULT_DENSITY_KG_M3, cell_mm=None, camera=None, depth_mm=DEFAULT_DEPTH_MM,
             ppc=None):
    """One evaluation (simulation to 1/3 s + 8 silhouettes)."""
    return mpm.simulate(material, setup, density=density, cell_mm=cell_mm, camera=camera or Camera.default(),
                        depth_mm=depth_mm, ppc=ppc)


def timing(paper_70: bool) -> None:
    mat = NS(eta=1.0, n=0.8, sigma_y=5.0)  # a mid-range material, flowing but not runny
    default = ("default", solver.DEFAULT_CELL_MM, solver.PARTICLES_PER_CELL)
    print(f"# timing, material eta=1 Pa s^n, n=0.8, sigma_y=5 Pa, rho=1000; threads {runtime.threads()}")
    evaluate(mat, NS(width_mm=30, height_mm=20), cell_mm=4.0)  # compile / load kernels first
    print(f"{'setup':>8} {'run':>8} {'cell':>5} {'ppc':>3} {'particles':>9} {'steps':>5} {'wall_s':>7} {'sim_s':>7} "
          f"{'render_s':>8} {'cpu_s':>7} {'Mpstep/s':>8} {'Mpstep/cpu-s':>12} {'vs ref':>6}  load")
    for w, h in ((30, 20), (70, 70)):
        for name, cell, ppc in (PAPER, default):
            if (w, h, name) == (70, 70, "paper") and not paper_70:
                print(f"{w}x{h:<5} {name:>8} {cell:5.2f} {ppc:3d}  (skipped: pass --paper-70)")
                continue
            sim = evaluate(mat, NS(width_mm=w, height_mm=h), cell_mm=cell, ppc=ppc)
            st = sim.stats
            ps = st["n_particles"] * st["steps"]
            print(f"{w}x{h:<5} {name:>8} {cell:5.2f} {ppc:3d} {st['n_particles']:9d} {st['steps']:5d} {st['wall_s']:7.1f} {st['sim_s']:7.1f} "
                  f"{st['render_s']:8.2f} {st['cpu_s']:7.1f} {ps / st['sim_s'] / 1e6:8.2f} {ps / st['cpu_s'] / 1e6:12.2f} "
                  f"{REFERENCE_S / st['wall_s'] if (w, h) == (30, 20) else float('nan'):6.1f}  {load()}", flush=True)


def _table1():
    from mpm.datasets import manifest

    return {r["folder"]: NS(eta=float(r["paper_eta_Pa_s_n"]), n=float(r["paper_n"]),
                            sigma_y=float(r["paper_sigma_y_Pa"])) for r in manifest()}


def convergence(count: int | None, max_area: float, min_area: float = 0.0) -> None:
    from mpm.experiment import iter_shared, load as load_experiment
    from mpm.loss import iou

    table = _table1()
    folders = []
    for p in iter_shared():
        if p.name in table:
            e = load_experiment(p, frames=False)
            if min_area < e.width_mm * e.height_mm <= max_area:
                folders.append(p)
    folders = folders[:count]
    fine = solver.DEFAULT_CELL_MM / 2
    print(f"# silhouette convergence: IoU of cell {solver.DEFAULT_CELL_MM} mm vs {fine} mm, Table-1 parameters")
    print(f"{'experiment':<52} {'mean IoU':>8} {'min IoU':>8} {'t_default':>9} {'t_fine':>7}  load")
    means = []
    for folder in folders:
        exp = load_experiment(folder, frames=False)
        setup = NS(width_mm=exp.width_mm, height_mm=exp.height_mm)
        kw = dict(density=exp.density, camera=exp.camera, depth_mm=exp.depth_mm)
        try:
            a = evaluate(table[folder.name], setup, cell_mm=None, **kw)
            b = evaluate(table[folder.name], setup, cell_mm=fine, **kw)
        except solver.SimulationError as e:
            print(f"{folder.name:<52} failed: {e}")
            continue
        ious = np.array([iou(x, y) for x, y in zip(a.silhouettes, b.silhouettes)])
        means.append(ious.mean())
        print(f"{folder.name:<52} {ious.mean():8.4f} {ious.min():8.4f} {a.stats['wall_s']:9.1f} {b.stats['wall_s']:7.1f}"
              f"  {load()}", flush=True)
    if means:
        print(f"all: mean IoU {np.mean(means):.4f}, worst experiment {np.min(means):.4f}")


def worcestershire() -> None:
    from mpm.datasets import first_estimates, real_world_dir
    from mpm.experiment import load as load_experiment
    from mpm.loss import video_loss

    row = next(r for r in first_estimates() if "Worcestershire" in r["material"])
    mat = NS(eta=float(row["estimate_after_setup1_eta_Pa_s_n"]), n=float(row["estimate_after_setup1_n"]),
             sigma_y=float(row["estimate_after_setup1_sigma_y_Pa"]))
    exp = load_experiment(real_world_dir() / "ref_JapaneseThickenedWorcestershireSauce_2.0_3.0_2")
    print("# Worcestershire setup 2 at the setup-1 estimate (reference pipeline 0.0040, target <= 0.006)")
    for name, cell, ppc in (("default", solver.DEFAULT_CELL_MM, solver.PARTICLES_PER_CELL), PAPER):
        sim = evaluate(mat, NS(width_mm=exp.width_mm, height_mm=exp.height_mm), density=exp.density, cell_mm=cell,
                       camera=exp.camera, depth_mm=exp.depth_mm, ppc=ppc)
        print(f"{name:>8} cell {cell:4.2f} mm, {ppc} ppc: loss {video_loss(sim.silhouettes, exp.frames):.4f}  wall {sim.stats['wall_s']:.1f} s"
              f"  {load()}", flush=True)


def _count_or_all(text: str):
    """None for "all", else a whole number >= 1."""
    if text == "all":
        return None
    if not text.isdigit() or int(text) < 1:
        raise argparse.ArgumentTypeError(f"give a number of experiments >= 1, or all; got {text!r}")
    return int(text)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paper-70", action="store_true", help="also time 70 x 70 mm at 1.26 mm cells (slow)")
    ap.add_argument("--experiments", default="all", type=_count_or_all,
                    help="number of shared experiments for the IoU study, or all")
    ap.add_argument("--max-area-mm2", type=float, default=1000.0,
                    help="IoU study only on setups with W*H up to this (the 2x finer run costs 16x)")
    ap.add_argument("--min-area-mm2", type=float, default=0.0,
                    help="IoU study only on setups with W*H above this (with --max-area-mm2: split the study)")
    ap.add_argument("--skip-timing", action="store_true")
    ap.add_argument("--skip-convergence", action="store_true")
    ap.add_argument("--skip-loss", action="store_true")
    a = ap.parse_args(argv)
    print(f"# measured: {how_measured()}", flush=True)
    t0 = time.time()
    if not a.skip_timing:
        timing(a.paper_70)
    if not a.skip_convergence:
        convergence(a.experiments, a.max_area_mm2, a.min_area_mm2)
    if not a.skip_loss:
        worcestershire()
    print(f"# total {time.time() - t0:.0f} s")


if __name__ == "__main__":
    main()
