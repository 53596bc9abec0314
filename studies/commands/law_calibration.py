"""``virheo study laws``: calibration of the laws' verdicts: yield stress, shear thinning (emulated footage)

18 materials (4 power law, 4 Bingham, 2 Newtonian, 8 Herschel-Bulkley, some near the faces); footage at 1.26 mm with
two particles per axis, a one-setup estimate at the preset's model (default survey: 2.5 mm, two particles per axis),
the second setup `virheo design` proposes, the two-setup estimate and `virheo report`'s evidence. Scores the
verdicts against the truth. Writes laws.json, laws.md and laws.png. Resumes from its store and its finished cases.
--quick: 2 materials on coarse models, a test of the machinery.
"""
from __future__ import annotations

import argparse

from studies.commands.context import (add_command, add_preset_option, add_run_options, check_run_options, integer,
                                      open_run, seed)


def register(study_subparsers) -> None:
    """Add ``laws`` to the ``study`` sub-command's parsers."""
    p = add_command(study_subparsers, __doc__)
    p.add_argument("--quick", action="store_true", help="2 materials, footage at 2.5 mm, the demo preset")
    p.add_argument("--new-simulations", type=integer, default=12, metavar="N",
                   help="space-filling candidates per emulator box of the posterior (default 12)")
    p.add_argument("--min-ess", type=integer, default=1000, metavar="N", help="posterior samples' ESS (default 1000)")
    p.add_argument("--seed", type=seed, default=0, help="seed of the materials, setups, CMA-ES and emcee (default 0)")
    add_preset_option(p, default=None)  # None: survey (demo with --quick)
    add_run_options(p, default_out="./virheo-laws")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from studies.law_calibration import run_study

    check_run_options(args)
    if args.new_simulations < 1 or args.min_ess < 1:
        raise ValueError("--new-simulations and --min-ess must be >= 1")
    with open_run(args) as run_:
        result = run_study(run_.out, quick=args.quick, preset=args.preset, generations=args.generations,
                           new_simulations=args.new_simulations, seed=args.seed, min_ess=args.min_ess,
                           forward=run_.forward, progress=run_.progress)
    print((run_.out / "laws.md").read_text())
    for q in result["summary"]["questions"]:
        share = "none resolved" if q["right_share"] is None else f"{q['right']}/{q['resolved']} right"
        print(f"{q['question']}: {share}, {q['decisively_wrong']} decisively wrong: "
              f"{'target met' if q['passed'] else 'target NOT met'}")
    print(f"report in {run_.out} (laws.json, laws.md, laws.png)")
    return 0
