"""Does a finer model tell the truth from a two-setup estimate of `virheo study design`?

For every finished case and each criterion asked for, the truth and the criterion's two-setup estimate are
simulated in both setups of that run at the study's preset (5 mm cells for ``demo``) and at a finer cell width, and
the mean video loss (eq. 3) between the two is printed.  A loss that stays near zero at the finer cell width means the
two materials give the same silhouettes there too: the estimate sits in the similarity valley (section 5), not in a
discretisation artefact.

    python bench/bench_design_resolution.py design --store STORE [--cell-mm 2.5] [--criteria perpendicularity,random]
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from mpm.forward import Forward  # noqa: E402
from mpm.loss import video_loss  # noqa: E402
from mpm.params import Setup  # noqa: E402
from similarity.emulation import emulate  # noqa: E402
from similarity.presets import get_preset  # noqa: E402
from measured import how_measured  # noqa: E402  (bench/ is this script's folder)
from studies.design_study import records  # noqa: E402


def pair_loss(truth, estimate, setups, preset, forward) -> float:
    a = emulate(truth, setups, preset=preset, forward=forward)
    b = emulate(estimate, setups, preset=preset, forward=forward)
    return float(np.mean([video_loss(x.frames, y.frames) for x, y in zip(a, b)]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("study", help="a `virheo study design` output folder")
    ap.add_argument("--store", required=True, help="the study's simulation store")
    ap.add_argument("--cell-mm", type=float, default=2.5, help="the finer cell width (default 2.5)")
    ap.add_argument("--criteria", default="perpendicularity,random")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--cases", type=int, default=None, metavar="N", help="the first N cases only (default all)")
    args = ap.parse_args()
    if args.cases is not None and args.cases < 1:
        ap.error(f"--cases {args.cases}: must be >= 1")
    try:
        recs = records(args.study)[:args.cases]
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(2)
    unknown = set(args.criteria.split(",")) - set(recs[0].config["criteria"])
    if unknown:
        print(f"error: --criteria {', '.join(sorted(unknown))}: not in the study "
              f"({', '.join(recs[0].config['criteria'])})", file=sys.stderr)
        sys.exit(2)
    coarse = get_preset(recs[0].config["preset"])
    fine = dataclasses.replace(coarse, cell_mm=args.cell_mm)
    forward = Forward(args.store, workers=args.workers)
    rows = []
    print(f"# measured: {how_measured()}", flush=True)
    print(f"case criterion E_rel loss@{coarse.final.resolved().cell_mm:g}mm loss@{args.cell_mm:g}mm")
    try:
        for r in recs:
            for crit in args.criteria.split(","):
                c = r.criteria[crit]
                setups = [Setup(*map(float, s.split("x"))) for s in (r.first_setup, c.second_setup)]
                row = [c.e_rel] + [pair_loss(r.truth, c.estimate, setups, p, forward) for p in (coarse, fine)]
                rows.append(row)
                print(f"{r.case:4d} {crit:16s} {row[0]:.3f} {row[1]:.2e} {row[2]:.2e}", flush=True)
    finally:
        forward.close()
    a = np.array(rows)
    far = a[:, 0] > 0.1
    print(f"median loss: {np.median(a[:, 1]):.2e} coarse, {np.median(a[:, 2]):.2e} fine "
          f"(fine/coarse median {np.median(a[:, 2] / np.maximum(a[:, 1], 1e-12)):.2f}); "
          f"estimates with E_rel > 0.1: {int(far.sum())}/{len(a)}, their median fine loss "
          f"{np.median(a[far, 2]) if far.any() else float('nan'):.2e}")


if __name__ == "__main__":
    main()
