"""``virheo study design-outcome``: does the recommended second setup give a better estimate? arms at equal budget

Materials drawn half runny, half thick pastes, a random first setup each; footage emulated with a finer model; stage
1 shared; each arm (information, perpendicularity, eig, largest, random x2, repeat) picks a second setup, and stage
2 on both setups gets the same simulation work, the criterion's own simulations included. Outcome: the flow-curve error
over 1-100 1/s (and E_rel); each arm against random and perpendicularity by a paired Wilcoxon test and a bootstrap
interval. Pre-registered in docs/uncertainty.md. Writes design_outcome.json and .md. Resumes from its store and
finished cases.
"""
from __future__ import annotations

import argparse

from studies.commands.context import (PRESET_NAMES, add_command, add_preset_option, add_run_options, check_run_options,
                                      integer, open_run, real, seed, simulator)


def register(study_subparsers) -> None:
    """Add ``design-outcome`` to the ``study`` sub-command's parsers."""
    p = add_command(study_subparsers, __doc__)
    p.add_argument("--materials", type=integer, default=8, metavar="N", help="materials, half runny (default 8)")
    p.add_argument("--seeds", type=integer, default=2, metavar="K", help="CMA-ES seeds per material (default 2)")
    p.add_argument("--seed", type=seed, default=62, help="seed of the materials and random setups (default 62)")
    add_preset_option(p, default="survey")
    p.add_argument("--footage-model", default="1.26:2", metavar="CELL_MM:PPC",
                   help="the model that films the footage (default 1.26:2, sticking walls)")
    p.add_argument("--criterion-preset", default=None, choices=PRESET_NAMES, metavar="NAME",
                   help="the information criterion's model (default: its own, demo)")
    p.add_argument("--stage-1-generations", type=integer, default=12, metavar="G", help="stage 1's generations (12)")
    p.add_argument("--budget-particle-steps", type=real, default=None, metavar="W",
                   help="each arm's simulation work after stage 1 in particles x time steps, the criterion's simulations "
                        "and stage 2's warm start included (default: the pre-registered 6e9)")
    p.add_argument("--posteriors", type=integer, default=4, metavar="P",
                   help="materials (half runny, half pastes) whose arms get the posterior outcome (the Herschel-Bulkley "
                        "posterior of `virheo report --laws herschel-bulkley`), seed 0 (default 4)")
    add_run_options(p, default_out="./virheo-design-outcome", generations=False)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from studies.design_outcome import run_study
    from studies.design_resolution import parse_model

    footage = parse_model(args.footage_model)
    check_run_options(args)
    with open_run(args) as run:
        result = run_study(run.out, materials=args.materials, seeds=args.seeds, seed=args.seed, preset=args.preset,
                           footage_model=footage, criterion_preset=args.criterion_preset,
                           stage_1_generations=args.stage_1_generations, budget_particle_steps=args.budget_particle_steps,
                           posteriors=args.posteriors,
                           simulator=simulator(), forward=run.forward, progress=run.progress)
        simulated = run.forward.simulations_run
    print((run.out / "design_outcome.md").read_text())
    print(f"{simulated} simulations run (the rest from the store), {result['wall_seconds']:.0f} s; report in {run.out}")
    return 0
