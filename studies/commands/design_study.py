"""``virheo study design``: second setup by EIG vs perpendicularity vs random at equal budget (emulated footage)

Materials by a Sobol design over the material space, a random first setup each; two-setup ViRheometry once per
criterion for the second setup (expected information gain under stage 1's belief, the paper's perpendicularity,
random), sharing stage 1. Records E_rel after two setups. Writes design.json, design.md and e_rel.png. Resumes from
its store and its finished cases.
"""
from __future__ import annotations

import argparse

from studies.commands.context import (add_command, add_preset_option, add_run_options, check_run_options, integer,
                                      open_run, seed)


def register(study_subparsers) -> None:
    """Add ``design`` to the ``study`` sub-command's parsers."""
    p = add_command(study_subparsers, __doc__)
    p.add_argument("--cases", type=integer, default=20, metavar="N",
                   help="materials (one first setup each; default 20)")
    p.add_argument("--seed", type=seed, default=0, help="seed of the design, setups and CMA-ES (default 0)")
    add_preset_option(p, default="demo")
    add_run_options(p, default_out="./virheo-design")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from studies import design_study as D

    check_run_options(args)
    with open_run(args) as run:
        result = D.run_study(run.out, cases=args.cases, preset=args.preset, generations=args.generations,
                             seed=args.seed, forward=run.forward, progress=run.progress)
        simulated = run.forward.simulations_run
    s = result["summary"]
    print((run.out / "design.md").read_text())
    print("E_rel <= {:g} after two setups: ".format(s["good_threshold"]) + ", ".join(
        f"{c} {v['good']}/{v['cases']}" for c, v in s["criteria"].items()))
    print(f"{simulated} simulations run (the rest from the store), {result['wall_seconds']:.0f} s; "
          f"report in {run.out} (design.json, design.md, e_rel.png)")
    return 0
