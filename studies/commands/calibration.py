"""``virheo study calibration``: does the posterior's 90 % credible region hold the truth? (emulated footage)

Materials by a Sobol design over the material space, one random setup each; footage simulated by the estimating
model ('same') or at half its cell width ('finer'); a one-setup estimate, then the posterior of `virheo report`;
records the credible level of the truth. Writes calibration.json, calibration.md and reliability.png. Resumes from
its store and its finished cases.
"""
from __future__ import annotations

import argparse

from studies.commands.context import (add_command, add_posterior_options, add_preset_option, add_run_options,
                                      check_posterior_options, check_run_options, integer, open_run, seed)


def register(study_subparsers) -> None:
    """Add ``calibration`` to the ``study`` sub-command's parsers."""
    p = add_command(study_subparsers, __doc__)
    p.add_argument("--cases", type=integer, default=20, metavar="N", help="materials (one setup each; default 20)")
    p.add_argument("--setting", choices=("same", "finer", "both"), default="both",
                   help="footage by the estimating model, at half its cell width, or both (default both)")
    add_posterior_options(p)
    p.add_argument("--seed", type=seed, default=0, help="seed of the design, CMA-ES and emcee (default 0)")
    add_preset_option(p, default="demo")
    add_run_options(p, default_out="./virheo-calibration")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from studies import calibration as C

    check_posterior_options(args)
    check_run_options(args)
    settings = C.SETTINGS if args.setting == "both" else (args.setting,)
    with open_run(args) as run:
        result = C.run_study(run.out, cases=args.cases, settings=settings, preset=args.preset,
                             generations=args.generations, new_simulations=args.new_simulations,
                             half_width=args.half_width, seed=args.seed, min_ess=args.min_ess,
                             max_steps=args.max_steps, forward=run.forward, progress=run.progress,
                             noise_count=args.noise_count)
        simulated = run.forward.simulations_run
    print((run.out / "calibration.md").read_text())
    for s, v in result["summary"].items():
        print(f"{s}: truth in the 90 % HPD region in {v['inside_90']['hpd']}/{v['cases']} cases")
    print(f"{simulated} simulations run (the rest from the store), {result['wall_seconds']:.0f} s; "
          f"report in {run.out} (calibration.json, calibration.md, reliability.png)")
    return 0
