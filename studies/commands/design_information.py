"""``virheo study design-information``: each second-setup criterion's pick scored by the information it realises."""
from __future__ import annotations

import argparse

from studies.commands.context import add_preset_option, add_run_options, check_run_options, integer, open_run, real, seed


def register(study_subparsers) -> None:
    """Add ``design-information`` to the ``study`` sub-command's parsers."""
    p = study_subparsers.add_parser(
        "design-information", help="does the design pay off? criteria's second setups scored by realised information",
        description="Materials by a Sobol design, a random first setup each; a short stage-1 CMA-ES estimate on "
        "emulated footage; each criterion (EIG, perpendicularity with the fitted and the published Theta map, random) "
        "picks a second setup from that estimate; a seeded set of candidates plus the picks are scored by the "
        "information they realise at the true material (log det gain of PSD-projected FD Hessians at one step). "
        "The last --held-out materials are reported apart. Writes design_information.json/.md, "
        "predicted_vs_realised.png and maps.png. Resumes from its store and its finished materials.")
    p.add_argument("--materials", type=integer, default=30, metavar="N", help="materials (default 30)")
    p.add_argument("--held-out", type=integer, default=10, metavar="K",
                   help="the last K materials, kept from the choice of the recommended criterion (default 10)")
    p.add_argument("--candidates", type=integer, default=8, metavar="C",
                   help="seeded random candidate setups per material, besides the picks (default 8)")
    p.add_argument("--fd-step", type=real, default=0.05, metavar="H",
                   help="finite-difference step in the normalised material space (default 0.05)")
    p.add_argument("--maps", type=integer, default=2, metavar="M",
                   help="materials with a map of realised information over the setup grid (default 2)")
    p.add_argument("--map-steps", type=integer, default=6, metavar="S", help="map grid points per axis (default 6)")
    p.add_argument("--posterior-check", type=integer, default=3, metavar="P",
                   help="materials whose candidates' emcee posterior volumes are compared to the gains (default 3)")
    p.add_argument("--seed", type=seed, default=0, help="seed of the design, candidates and CMA-ES (default 0)")
    add_preset_option(p, default="demo")
    add_run_options(p, default_out="./virheo-design-information")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from studies import design_information as D

    check_run_options(args)
    with open_run(args) as run:
        stored = run.forward.store.count()
        result = D.run_study(run.out, materials=args.materials, held_out=args.held_out, candidates=args.candidates,
                             preset=args.preset, generations=args.generations or 20, fd_step=args.fd_step,
                             seed=args.seed, maps=args.maps, map_steps=args.map_steps,
                             posterior_check=args.posterior_check, forward=run.forward, progress=run.progress)
        simulated = run.forward.store.count() - stored
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
