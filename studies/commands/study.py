"""``virheo study emulation``: the section 7.1 emulation study (one setup vs two setups)."""
from __future__ import annotations

import argparse

from studies.commands.context import (add_command_group, add_preset_option, add_run_options, check_run_options,
                                      integer, open_run, seed)


def register(subparsers) -> None:
    sub = add_command_group(subparsers, "study", help="long studies (emulation: section 7.1; landscapes; calibration of the posterior; second-setup design; does the design pay off; the laws' verdicts)",
                            description="Long-running studies; each resumes from its simulation store.",
                            dest="study", metavar="STUDY")
    e = sub.add_parser("emulation", help="one setup vs two setups on emulated footage (section 7.1, Fig. 10)",
                       description="Materials by Poisson-disk sampling, several runs each from random first setups; "
                       "two-setup ViRheometry vs one setup at equal simulation count.")
    e.add_argument("--materials", type=integer, default=6, metavar="M", help="number of materials (default 6)")
    e.add_argument("--runs", type=integer, default=3, metavar="R",
                   help="runs per material from random first setups (default 3)")
    add_preset_option(e, default="demo")
    e.add_argument("--seed", type=seed, default=0, help="seed of the materials, setups and CMA-ES (default 0)")
    add_run_options(e, default_out="./virheo-emulation")
    e.set_defaults(func=run_emulation)
    from studies.commands import (calibration, design_information, design_outcome, design_resolution, design_study,
                                  landscapes, law_calibration)

    landscapes.register(sub)
    calibration.register(sub)
    design_study.register(sub)
    design_information.register(sub)
    design_resolution.register(sub)
    design_outcome.register(sub)
    law_calibration.register(sub)


def run_emulation(args: argparse.Namespace) -> int:
    from studies.emulation import run_study

    for name in ("materials", "runs"):
        if getattr(args, name) < 1:
            raise ValueError(f"--{name} {getattr(args, name)} must be >= 1")
    check_run_options(args)
    with open_run(args) as run:
        result = run_study(run.out, materials=args.materials, runs=args.runs, preset=args.preset,
                           generations=args.generations, seed=args.seed, forward=run.forward, progress=run.progress)
    s = result["summary"]
    print((run.out / "emulation.md").read_text())
    print(f"good: one setup {s['good_single']}/{s['cases']}, two setups {s['good_two_setups']}/{s['cases']}; "
          f"{run.simulated} simulations run, {run.from_store} results from the store, "
          f"{result['wall_seconds']:.0f} s; report in {run.out}")
    return 0
