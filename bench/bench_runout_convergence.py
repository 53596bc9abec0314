"""Does the runout of a runny dam-break converge under refinement? Fronts per frame for a list of
discretisations (cell width, particles per cell per axis, CFL), 2D plane strain by default.

    python bench/bench_runout_convergence.py [--dim 2|3] [--material ETA,N,SIGMA_Y] [--setup WxH]
                                             [--density RHO] [--slip-m B] [--runs CELL,PPC[,CFL] ...]

Defaults: the thickened Worcestershire sauce at Table 1 (0.55, 0.81, 1.95) in its setup 1 (21 x 40 mm,
1200 kg/m^3), the runniest flow of the shared footage. Prints a markdown table (docs/method/forward-model.md records it):
front = max x of the moving material at t = k/24 s, in mm.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

import mpm
from mpm import solver
from mpm.params import Material, Setup
from measured import how_measured  # noqa: E402  (bench/ is this script's folder)

DEFAULT_RUNS = ("3,1", "1.5,1", "1,1", "0.75,1", "0.5,1", "0.375,1", "0.25,1", "1,1,0.25", "1,1,0.125",
                "3,2", "2.5,2", "2,2", "1.5,2", "1.25,2", "1,2", "0.75,2", "0.5,2", "1,2,0.25")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--dim", type=int, default=2)
    p.add_argument("--material", default="0.55,0.81,1.95")
    p.add_argument("--setup", default="21x40")
    p.add_argument("--density", type=float, default=1200.0)
    p.add_argument("--slip-m", type=float, default=0.0, help="Navier slip length of floor and walls, metres")
    p.add_argument("--density-correction", action="store_true", help="the solver's density correction")
    p.add_argument("--runs", nargs="*", default=list(DEFAULT_RUNS), help="CELL_MM,PPC[,CFL] (default CFL: the solver's)")
    args = p.parse_args(argv)
    material = Material.parse(args.material)
    setup = Setup.parse(args.setup)
    default_cfl = solver.CFL
    print(f"# measured: {how_measured()}", flush=True)
    print(f"# {args.dim}D, material {args.material}, setup {args.setup} mm, density {args.density:g} kg/m^3, "
          f"slip length {args.slip_m * 1e3:g} mm{', density-corrected' if args.density_correction else ''}")
    print("\n| cell mm | ppc | spacing mm | CFL | front per frame (mm) | final front mm | steps | wall s |")
    print("|---:|---:|---:|---:|---|---:|---:|---:|")
    for run in args.runs:
        parts = run.split(",")
        cell, ppc = float(parts[0]), int(parts[1])
        solver.CFL = float(parts[2]) if len(parts) > 2 else default_cfl
        t = time.perf_counter()
        sim = mpm.simulate(material, setup, density=args.density, cell_mm=cell, ppc=ppc, dim=args.dim,
                           slip_length_m=args.slip_m, density_correction=args.density_correction)
        front = np.round(sim.front_m * 1e3, 1)
        print(f"| {cell:g} | {ppc} | {cell / ppc:.3g} | {solver.CFL:g} | {' '.join(f'{f:g}' for f in front)} | "
              f"**{front[-1]:g}** | {sim.stats.get('steps', '')} | {time.perf_counter() - t:.1f} |", flush=True)
    solver.CFL = default_cfl
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
