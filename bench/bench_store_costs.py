"""What one simulation costs, by forward model and setup, from the wall times that simulation stores recorded.

    python bench/bench_store_costs.py STORE [STORE ...] [--min-count 2]

Each store (a run's or a study's ``store/`` folder) keeps every simulation's wall time as its worker measured it:
one simulation process, one thread.  Prints, per model (cell width, particles per cell per axis, engine) and setup,
the count and the median, smallest and largest wall time.  The figures are those of the machine that filled the stores, under its load then: a store filled while other work
ran holds slower times (the median is the figure to quote).
"""
from __future__ import annotations

import argparse
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from measured import how_measured  # noqa: E402  (bench/ is this script's folder)


def main(argv=None) -> int:
    from mpm.store import Store

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("stores", nargs="+", metavar="STORE")
    p.add_argument("--min-count", type=int, default=2, help="leave out setups with fewer simulations (default 2)")
    args = p.parse_args(argv)
    walls = defaultdict(list)
    for root in args.stores:
        if not (Path(root) / "index.sqlite").is_file():
            print(f"{root}: not a simulation store (no index.sqlite)", file=sys.stderr)
            return 2
        with Store(root) as store:
            for req, wall in store.timings():
                m = req.model
                walls[(m.cell_mm, m.ppc, m.engine or "-"), (req.width_mm, req.height_mm)].append(wall)
    print(f"reading machine: {how_measured()}")
    print("| cell mm, particles per axis, engine | setup | simulations | median s | min s | max s |")
    print("|---|---|---:|---:|---:|---:|")
    for (model, setup), w in sorted(walls.items(), key=lambda kv: (-kv[0][0][0], kv[0][0][1:], kv[0][1])):
        w = np.asarray(w)
        w = w[np.isfinite(w)]
        if len(w) < args.min_count:
            continue
        cell, ppc, engine = model
        print(f"| {cell:g}, {ppc}, {engine} | {setup[0]:g}x{setup[1]:g} | {len(w)} | {np.median(w):.2f} | "
              f"{w.min():.2f} | {w.max():.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
