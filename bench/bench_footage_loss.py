"""Benchmark: loss of our simulated silhouettes against real footage, per cell width and splat radius.

    python bench/bench_footage_loss.py [--experiment NAME] [--cells 3,2.5,2,1.5] [--radii 0.8,1.0,1.2,1.5,2.0]

Default: the Japanese thickened Worcestershire sauce's setup-2 footage at the experimenters' setup-1
estimate (first_estimates.csv), where the reference implementation's pipeline scores 0.0040; the
target is <= 0.006. For each cell width it runs one simulation and renders the 8 frames with the
default radius and with each radius of ``--radii`` (mm). Slow (minutes at 1.5 mm cells on 2 cores).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from mpm import experiment  # noqa: E402
from mpm.datasets import first_estimates, real_world_dir  # noqa: E402
from mpm.loss import frame_losses  # noqa: E402
from mpm.params import Material  # noqa: E402
from mpm.silhouette import default_radius_m, render_frames  # noqa: E402
from measured import how_measured  # noqa: E402  (bench/ is this script's folder)

WORCESTER_2 = "ref_JapaneseThickenedWorcestershireSauce_2.0_3.0_2"


def setup1_estimate(material_name: str) -> Material:
    for row in first_estimates():
        if row["material"] == material_name:
            return Material(float(row["estimate_after_setup1_eta_Pa_s_n"]), float(row["estimate_after_setup1_n"]),
                             float(row["estimate_after_setup1_sigma_y_Pa"]))
    raise ValueError(f"no setup-1 estimate for {material_name!r}")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--experiment", default=WORCESTER_2)
    ap.add_argument("--cells", default="3,2.5,2,1.5", help="cell widths in mm")
    ap.add_argument("--radii", default="0.8,1.0,1.2,1.5,2.0", help="extra splat radii in mm")
    args = ap.parse_args(argv)

    from mpm.datasets import manifest
    import mpm.solver as solver

    known = {r["folder"]: r["material"] for r in manifest()}
    if Path(args.experiment).name not in known:
        ap.error(f"--experiment {args.experiment}: not a shared experiment (one of {', '.join(known)})")
    exp = experiment.load(real_world_dir() / Path(args.experiment).name)
    material_name = known[exp.name]
    mat = setup1_estimate(material_name)
    print(f"# measured: {how_measured()}", flush=True)
    print(f"{exp.name}: W {exp.width_mm:g} x H {exp.height_mm:g} mm, rho {exp.density:g} kg/m^3, "
          f"material eta {mat.eta:.4g} Pa s^n, n {mat.n:.4g}, sigma_y {mat.sigma_y:.4g} Pa")
    radii = [float(r) * 1e-3 for r in args.radii.split(",") if r]
    for cell in (float(c) for c in args.cells.split(",")):
        t = time.perf_counter()
        sim = solver.simulate(mat, exp, density=exp.density, cell_mm=cell, depth_mm=exp.depth_mm)
        wall = time.perf_counter() - t
        spacing = float(sim.stats["spacing_m"])
        print(f"\ncell {cell:g} mm: {sim.stats['n_particles']} particles, {sim.stats['steps']} steps, "
              f"{wall:.0f} s (noisy: shared machine)")
        for r in [None] + radii:
            t = time.perf_counter()
            masks = render_frames(sim.frames, exp.camera, radius_m=r, spacing_m=spacing)
            dt = time.perf_counter() - t
            fl = frame_losses(masks, exp.frames)
            label = f"default {1e3 * default_radius_m(spacing):.3f}" if r is None else f"{1e3 * r:.3f}"
            print(f"  radius {label:>15} mm: loss {fl.mean():.5f}  frames {np.array2string(fl, precision=4)}"
                  f"  render {dt:.2f} s")


if __name__ == "__main__":
    main()
