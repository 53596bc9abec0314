"""``virheo study design-information``: each second-setup criterion's pick scored by the information it realises."""
from __future__ import annotations

import argparse

from studies.commands.context import add_preset_option, add_run_options, check_run_options, integer, open_run, real, seed

DESCRIPTION = (
    "Materials by a Sobol design, a random first setup each; a short stage-1 CMA-ES estimate on emulated footage; "
    "each criterion (EIG, perpendicularity with the fitted and the published Theta map; baselines random and the "
    "largest box) picks a second setup from that estimate; a seeded set of candidates plus the picks are scored by "
    "the information they realise at the true material (log det gain of PSD-projected FD Hessians at one step). "
    "The last --held-out materials are reported apart. Writes design_information.json/.md, "
    "predicted_vs_realised.png, maps.png and design_validation.json. Resumes from its store and its finished parts.")

# option, type, default, metavar, help (each a keyword of studies.design_information.run_study)
OPTIONS = (
    ("--materials", integer, 30, "N", "materials (default 30)"),
    ("--held-out", integer, 10, "K", "the last K materials, kept from the choice of a recommended criterion (default 10)"),
    ("--candidates", integer, 8, "C", "seeded random candidate setups per material, besides the picks (default 8)"),
    ("--fd-step", real, 0.05, "H", "finite-difference step in the normalised material space (default 0.05)"),
    ("--maps", integer, 2, "M", "materials with a map of realised information over a grid of setups (default 2)"),
    ("--map-steps", integer, 6, "S", "map grid points per axis (default 6)"),
    ("--posterior-check", integer, 3, "P",
     "materials whose candidates' emcee posterior volumes are compared to the gains (default 3)"),
    ("--seed", seed, 0, "SEED", "seed of the design, candidates and CMA-ES (default 0)"),
)


def register(study_subparsers) -> None:
    """Add ``design-information`` to the ``study`` sub-command's parsers."""
    p = study_subparsers.add_parser("design-information", description=DESCRIPTION,
                                    help="does the design pay off? criteria's second setups scored by realised information")
    for flag, kind, default, metavar, text in OPTIONS:
        p.add_argument(flag, type=kind, default=default, metavar=metavar, help=text)
    add_preset_option(p, default="demo")
    add_run_options(p, default_out="./virheo-design-information")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from studies.design_information import check_options, run_study

    options = {flag[2:].replace("-", "_"): getattr(args, flag[2:].replace("-", "_")) for flag, *_ in OPTIONS}
    options.update(preset=args.preset, generations=args.generations or 20)
    check_options(**options)  # before any folder is made
    check_run_options(args)
    with open_run(args) as run:
        result = run_study(run.out, forward=run.forward, progress=run.progress, **options)
        simulated = run.forward.simulations_run
    print((run.out / "design_information.md").read_text())
    for key in ("verdict_default", "verdict_recommended"):
        v = result["summary"].get(key)
        if v:
            print(f"{key.split('_')[1]} criterion {v['criterion']} on the held-out materials: beats the candidate mean "
                  f"in {v['beats_mean']} (sign test p = {v['sign_test_p']:.3g}), median normalised score "
                  f"{v['median_score']:.2f}, median Spearman {v['median_spearman']:.2f}")
    print(f"{simulated} simulations run (the rest from the store), {result['wall_seconds']:.0f} s; "
          f"report in {run.out}")
    return 0
