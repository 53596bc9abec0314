"""The walls' slip length against real footage: eq.-3 loss of reference materials per slip length.

    python bench/bench_slip_footage.py [--slips-mm 0,0.5,1,2] [--cell-mm 2] [--ppc 2] [--density-correction]
                                       [--only lotion milk] [--score ETA,N,SIGMA_Y ...] [--store DIR] [--workers 2]

For each of the four shared materials with rheometer curves, the mean eq.-3 loss over its two setups at the
solver's validated discretisation (1.5 mm, one particle per cell per axis) for two reference materials: the
Herschel-Bulkley fit of its rheometer curve over 1-100 1/s, and the paper's estimate (Table 1). A wall law
under which both fit the footage better is closer to the flows filmed. 4 simulations per slip length and
material (64 for the defaults); about 10 minutes on 2 cores (lotion's 70 x 70 mm setup is half of it).
``--cell-mm`` and ``--ppc`` score on other cells (``--ppc 2``: two particles per cell per axis, 6 times the
cost at 1.5 mm, twice at 2 mm); ``--score`` adds more materials (e.g. an estimate) to every row. Prints a
markdown table (per setup in brackets).
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402

from bench_real_estimates import SLUGS, parse_materials, rheometer_curves  # noqa: E402  (bench/ is this script's folder)
from measured import how_measured  # noqa: E402


def main(argv=None) -> int:
    from mpm import experiment as xp
    from mpm.datasets import manifest, real_world_dir, table1
    from mpm.forward import Forward
    from similarity.presets import VALIDATED
    from surrogate.rheometer import fit_herschel_bulkley

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--slips-mm", default="0,0.5,1,2", help="slip lengths in mm, comma-separated")
    p.add_argument("--only", nargs="*", default=None, choices=list(SLUGS.values()), help="materials (slugs)")
    p.add_argument("--store", default=str(Path.home() / ".cache/virheometry/slip_footage"))
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--cell-mm", type=float, default=None, help="cell width in mm (default: the solver's)")
    p.add_argument("--ppc", type=int, default=None, help="particles per cell per axis (default: the solver's)")
    p.add_argument("--density-correction", action="store_true", help="the solver's density correction")
    p.add_argument("--score", nargs="*", default=[], metavar="ETA,N,SIGMA_Y", help="more materials to score")
    args = p.parse_args(argv)
    others = parse_materials(p, args.score)
    if args.ppc is not None and args.ppc < 1:
        p.error(f"--ppc {args.ppc}: give a whole number >= 1")
    if args.cell_mm is not None and not args.cell_mm > 0:
        p.error(f"--cell-mm {args.cell_mm}: give a cell width > 0 in mm")
    slips = [float(v) * 1e-3 for v in args.slips_mm.split(",")]
    curves = rheometer_curves()
    rows = manifest()
    extra = "".join(f" {m.eta:g}, {m.n:g}, {m.sigma_y:g} |" for m in others)
    print(f"# measured: {how_measured()}", flush=True)
    print(f"| material | slip mm | cell mm | particles per cell per axis | rheometer fit | Table 1 |{extra}")
    print("|---|---:|---:|---:|---|---|" + "---|" * len(others))
    with Forward(args.store, workers=args.workers) as forward:
        for name, slug in SLUGS.items():
            if args.only and slug not in args.only:
                continue
            mine = sorted((r for r in rows if r["material"].lower() == name.lower()), key=lambda r: r["setup_index"])
            exps = [xp.load(str(Path(real_world_dir()) / r["folder"])) for r in mine]
            paper = table1(mine[0])
            refs = [fit_herschel_bulkley(curves[name]).material, paper, *others]
            for b in slips:
                model = dataclasses.replace(VALIDATED, slip_length_m=b, cell_mm=args.cell_mm, ppc=args.ppc,
                                            density_correction=args.density_correction).resolved()
                losses = forward.losses(refs, exps, model)
                cells = [f"{np.mean(row):.5f} ({', '.join(f'{v:.4f}' for v in row)})" for row in losses]
                print(f"| {name} | {b * 1e3:g} | {model.cell_mm:g} | {model.ppc} | {' | '.join(cells)} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
