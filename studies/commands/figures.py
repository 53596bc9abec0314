"""``virheo figures``: the paper's figures and Table 1 from our code (``paper_figures``)."""
from __future__ import annotations

import argparse
import importlib
import inspect
import sys
import time
from pathlib import Path

from studies.commands.context import check_engine, simulator


def register(subparsers) -> None:
    from paper_figures import FIGURES

    p = subparsers.add_parser(
        "figures", help="reproduce the paper's figures and Table 1 (PNG and markdown)",
        description="Make the paper's figures from our code: " + ", ".join(FIGURES) + ". Every simulation goes "
        "through the store, so a second run is fast. A figure whose input data are missing (e.g. a study not run "
        "yet) is reported in one line naming the command that makes them.",
    )
    p.add_argument("--only", default=None, metavar="LIST", help="comma-separated figures, e.g. fig05,fig13 (default: all)")
    p.add_argument("--quick", action="store_true", help="small settings (coarse model, tiny budgets): minutes, not days")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder for the PNGs (and table1.md)")
    p.add_argument("--store", default=None, metavar="PATH", help="simulation store (default: DIR/store)")
    p.add_argument("--workers", type=int, default=None, metavar="K", help="local worker processes (default: one per core)")
    p.add_argument("--landscapes", default=None, metavar="DIR",
                   help="output folder of `virheo study landscapes` (Figs. 6, 7; Fig. 9 reads conditioning.json there "
                   "or in DIR/conditioning); with --quick and no DIR a tiny study is run into OUT/landscape-study")
    p.add_argument("--estimates", nargs="+", default=None, metavar="DIR",
                   help="Fig. 13: folders written by `python bench/bench_real_estimates.py --root DIR`, one per seed "
                   "(default: that bench's default root)")
    p.set_defaults(func=run)


def selected(only: str | None) -> list[str]:
    from paper_figures import FIGURES

    if not only:
        return list(FIGURES)
    names = [s.strip().lower() for s in only.split(",") if s.strip()]
    names = [f"fig{int(s[3:]):02d}" if s.startswith("fig") and s[3:].isdigit() else s for s in names]
    unknown = [s for s in names if s not in FIGURES]
    if unknown or not names:
        raise ValueError(f"--only: unknown figure(s) {', '.join(unknown) or only!r}; choose from {', '.join(FIGURES)}")
    return list(dict.fromkeys(names))


def run(args: argparse.Namespace) -> int:
    from mpm.forward import Forward
    from paper_figures import FIGURES, SIMULATION_FREE
    from paper_figures._plot import Context, MissingData

    names = selected(args.only)
    if args.workers is not None and args.workers < 0:
        raise ValueError(f"--workers {args.workers} must be >= 0")
    simulating = any(n not in SIMULATION_FREE for n in names)
    if simulating:
        check_engine()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    forward = Forward(args.store or out / "store", workers=args.workers if simulating else 0)
    context = Context(forward=forward, landscapes=args.landscapes, estimates=args.estimates,
                      simulator=simulator())
    made = missing = 0
    t_all = time.perf_counter()
    try:
        for name in names:
            module = importlib.import_module(FIGURES[name])
            t0 = time.perf_counter()
            kwargs = {"context": context} if "context" in inspect.signature(module.make).parameters else {}
            try:
                paths = module.make(out, quick=args.quick, **kwargs)
            except MissingData as exc:
                missing += 1
                print(f"{name}: not made: {exc}", flush=True)
                continue
            made += 1
            print(f"{name}: {', '.join(str(p) for p in paths)} ({time.perf_counter() - t0:.0f} s)", flush=True)
    finally:
        forward.close()
    print(f"{made} figure(s) made, {missing} without data, {time.perf_counter() - t_all:.0f} s in all", file=sys.stderr)
    return 0
