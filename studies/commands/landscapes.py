"""``virheo study landscapes`` and ``virheo study conditioning``: MPM loss landscapes (section 5.1),
finite-difference loss normals and condition numbers (section 5.2, Fig. 9)."""
from __future__ import annotations

import argparse

from studies.commands.context import add_preset_option, add_run_options, check_run_options, integer, open_run, real, seed


def _common(p, default_out: str) -> None:
    p.add_argument("--fd-step", type=real, default=0.05, metavar="H",
                   help="finite-difference step in the normalised material space (default 0.05, see docs/landscapes.md)")
    add_preset_option(p, default="demo")
    add_run_options(p, default_out=default_out, generations=False)


def region(text: str) -> tuple:
    """argparse ``type`` for ``--region``: three ranges lo:hi (eta, n, sigma_y)."""
    parts = text.split(",")
    try:
        box = tuple(tuple(float(v) for v in part.split(":")) for part in parts)
    except ValueError:
        box = ()
    if len(box) != 3 or any(len(r) != 2 for r in box):
        raise argparse.ArgumentTypeError(f"'{text}' is not three ranges lo:hi for eta, n, sigma_y "
                                         "(e.g. 0:8,0.3:1,0:20)")
    return box


def register(study_subparsers) -> None:
    """Add ``landscapes`` and ``conditioning`` to the ``study`` sub-command's parsers."""
    p = study_subparsers.add_parser(
        "landscapes", help="MPM loss landscapes, FD loss normals and Poiseuille matching (section 5)",
        description="Materials by Poisson-disk sampling in the normalised material space, setups from the 1 mm grid; "
        "per (M, S) the emulated MPM loss on a GRID^3 block around M and the finite-difference Hessian, matched to "
        "the plane-Poiseuille loss normal by eq. 43. Resumes from its store; 'virheo theta fit OUT' fits Theta to it.")
    p.add_argument("--materials", type=integer, default=10, help="Poisson-disk materials (default 10)")
    p.add_argument("--setups", type=integer, default=3, help="random setups per material (default 3)")
    p.add_argument("--grid", type=integer, default=3, help="landscape points per axis (default 3; the paper: 8)")
    p.add_argument("--half-width", type=real, default=0.05, metavar="A",
                   help="half-width of the landscape block, normalised (default 0.05)")
    p.add_argument("--plots", type=integer, default=3, metavar="N", help="Fig. 6-style PNGs of the first N pairs (default 3)")
    p.add_argument("--seed", type=seed, default=0, help="seed of the materials and setups (default 0)")
    p.add_argument("--region", type=region, default=None, metavar="ETA_LO:ETA_HI,N_LO:N_HI,SY_LO:SY_HI",
                   help="draw the materials from this box only (SI: Pa s^n, -, Pa), e.g. 0:8,0.3:1,0:20 for thin, "
                   "weakly yielding materials (default: the whole material space)")
    _common(p, "./virheo-landscapes")
    p.set_defaults(func=run_landscapes)

    c = study_subparsers.add_parser(
        "conditioning", help="condition number of the FD Hessian over a coarse setup grid (Fig. 9)",
        description="For one material, the finite-difference Hessian of the MPM loss at each setup of a "
        "STEPS x STEPS grid over 20..70 mm; writes conditioning.json and conditioning.png.")
    c.add_argument("--material", required=True, metavar="ETA,N,SIGMA_Y", help="material in SI, e.g. 3.14,0.74,1.24")
    c.add_argument("--steps", type=integer, default=3, help="setups per axis over 20..70 mm (default 3)")
    _common(c, "./virheo-conditioning")
    c.set_defaults(func=run_conditioning)


def run_landscapes(args: argparse.Namespace) -> int:
    from studies import landscapes as LS

    check_run_options(args)
    config = LS.StudyConfig(materials=args.materials, setups_per_material=args.setups, grid=args.grid,
                            half_width=args.half_width, fd_step=args.fd_step, preset=args.preset, seed=args.seed,
                            region=args.region).check()
    if args.plots < 0:
        raise ValueError(f"--plots {args.plots} must be >= 0")
    with open_run(args) as run:
        out = run.out
        res = LS.run(out, config, forward=run.forward, progress=run.progress, plots=args.plots)
    import numpy as np

    angles = [p["match"]["angle_fd_deg"] for p in res["pairs"] if p["match"] and "angle_fd_deg" in p["match"]]
    print(f"{len(res['pairs'])} landscapes, {res['simulations']} simulations, {res['wall_seconds']:.0f} s; "
          f"median angle FD normal vs matched Poiseuille normal: "
          f"{np.median(angles) if angles else float('nan'):.1f} deg; results in {out / LS.RESULT_FILE}")
    return 0


def run_conditioning(args: argparse.Namespace) -> int:
    from mpm.params import Material
    from studies import landscapes as LS

    check_run_options(args)
    material = Material.parse(args.material).check_in_space()
    if args.steps < 2:
        raise ValueError(f"--steps {args.steps}: the setup grid needs at least 2 points per axis")
    with open_run(args) as run:
        out = run.out
        res = LS.conditioning(out, material, steps=args.steps, fd_step=args.fd_step, preset=args.preset,
                              forward=run.forward, progress=run.progress)
    print(f"condition numbers over {args.steps}x{args.steps} setups: min {res['min']:.3g}, median {res['median']:.3g}, "
          f"max {res['max']:.3g}; {res['simulations']} simulations, {res['wall_seconds']:.0f} s; plot {out / 'conditioning.png'}")
    return 0
