"""``virheo study emulation``: the section 7.1 emulation study (one setup vs two setups)."""
from __future__ import annotations

import argparse

from similarity.presets import PRESETS


def register(subparsers) -> None:
    p = subparsers.add_parser("study", help="long studies (emulation: section 7.1)",
                              description="Long-running studies; each resumes from its simulation store.")
    sub = p.add_subparsers(dest="study", metavar="STUDY")
    e = sub.add_parser("emulation", help="one setup vs two setups on emulated footage (section 7.1, Fig. 10)",
                       description="Materials by Poisson-disk sampling, several runs each from random first setups; "
                       "two-setup ViRheometry vs one setup at equal simulation count.")
    e.add_argument("--materials", type=int, default=6, help="number of materials (default 6)")
    e.add_argument("--runs", type=int, default=3, help="runs per material from random first setups (default 3)")
    e.add_argument("--preset", default="demo", choices=tuple(PRESETS), help="estimation preset (default demo)")
    e.add_argument("--generations", type=int, default=None, metavar="N", help="generations per stage (default: preset)")
    e.add_argument("--workers", type=int, default=None, metavar="K")
    e.add_argument("--scheduler", default=None, metavar="ADDR", help="dask.distributed scheduler address")
    e.add_argument("--seed", type=int, default=0)
    e.add_argument("--store", default=None, metavar="PATH", help="simulation store (default OUT/store)")
    e.add_argument("--out", default="./virheo-emulation", metavar="OUT")
    e.add_argument("--quiet", action="store_true")
    e.add_argument("--simulator", default=None, help=argparse.SUPPRESS)
    e.set_defaults(func=run_emulation)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])


def run_emulation(args: argparse.Namespace) -> int:
    from mpm import batch
    from studies.commands.estimate import check_args, run_context
    from studies.emulation import timed_study
    from studies.report import progress_bars

    for name in ("materials", "runs"):
        if getattr(args, name) < 1:
            raise ValueError(f"--{name} {getattr(args, name)} must be >= 1")
    check_args(args)
    with run_context(args) as (out, store, executor), progress_bars(not args.quiet) as progress:
        result = timed_study(out, materials=args.materials, runs=args.runs, preset=args.preset,
                             generations=args.generations, seed=args.seed, store=store, executor=executor,
                             progress=progress, simulator=args.simulator or batch.DEFAULT_SIMULATOR)
    s = result["summary"]
    print((out / "emulation.md").read_text())
    print(f"good: one setup {s['good_single']}/{s['cases']}, two setups {s['good_two_setups']}/{s['cases']}; "
          f"{result['wall_seconds']:.0f} s; report in {out}")
    return 0
