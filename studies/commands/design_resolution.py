"""``virheo study design-resolution``: the information criterion's log det gains at several models, against the finest

For fixed materials (modelled on Table 1) and setups (setup 1, the corners and the middle of 20-70 mm and three
more), the log det gain of each candidate after setup 1 from FD loss Hessians on footage emulated at each model; per
material the argmax, the trace ratio 70x70/20x20 and Spearman against the finest model; names the cheapest model
that matches the finest. Runs with other --models or --materials add to one --out. Writes design_resolution.json and
.md. Resumes from its store and finished cases.
"""
from __future__ import annotations

import argparse

from studies.commands.context import add_command, add_run_options, check_run_options, integer, open_run, simulator


def register(study_subparsers) -> None:
    """Add ``design-resolution`` to the ``study`` sub-command's parsers."""
    from studies.design_resolution import DEFAULT_MODELS, MATERIALS, model_label

    p = add_command(study_subparsers, __doc__)
    p.add_argument("--models", nargs="+", default=[f"{m.cell_mm:g}:{m.ppc}" for m in DEFAULT_MODELS],
                   metavar="CELL_MM:PPC", help="forward models, sticking walls (default: "
                   + " ".join(model_label(m) for m in DEFAULT_MODELS) + ")")
    p.add_argument("--materials", type=integer, default=len(MATERIALS), metavar="N",
                   help=f"the first N of the materials {', '.join(m.slug for m in MATERIALS)} (default all)")
    add_run_options(p, default_out="./virheo-design-resolution", generations=False)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from studies.design_resolution import parse_model, run_study

    models = [parse_model(m) for m in args.models]  # before any folder is made
    check_run_options(args)
    with open_run(args) as run:
        result = run_study(run.out, models=models, materials=args.materials, simulator=simulator(),
                           forward=run.forward, progress=run.progress)
        simulated = run.forward.simulations_run
    print((run.out / "design_resolution.md").read_text())
    s = result["summary"]
    verdict = (f"cheapest model matching {s['finest']}: {s['cheapest_matching'] or 'none'}" if not s["pending"] else
               f"no verdict yet against {s['finest']}: {', '.join(s['pending'])} lack candidates there")
    print(f"{verdict}; {simulated} simulations run "
          f"(the rest from the store), {result['wall_seconds']:.0f} s; report in {run.out}")
    return 0
