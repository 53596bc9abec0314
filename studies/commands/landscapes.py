"""``virheo study landscapes`` and ``virheo study conditioning``: MPM loss landscapes (section 5.1),
finite-difference loss normals and condition numbers (section 5.2, Fig. 9)."""
from __future__ import annotations

import argparse
from contextlib import contextmanager
from pathlib import Path


def _common(p) -> None:
    p.add_argument("--fd-step", type=float, default=0.05, metavar="H",
                   help="finite-difference step in the normalised material space (default 0.05, see docs/landscapes.md)")
    p.add_argument("--preset", default="demo", choices=("demo", "footage", "paper"), help="forward model resolution (default demo: 5 mm cells)")
    p.add_argument("--workers", type=int, default=None, metavar="K", help="local worker processes (default: one per core)")
    p.add_argument("--scheduler", default=None, metavar="ADDR", help="dask.distributed scheduler address")
    p.add_argument("--store", default=None, metavar="PATH", help="simulation store (default OUT/store)")
    p.add_argument("--quiet", action="store_true")
    p.add_argument("--simulator", default=None, help=argparse.SUPPRESS)


def register(study_subparsers) -> None:
    """Add ``landscapes`` and ``conditioning`` to the ``study`` sub-command's parsers."""
    p = study_subparsers.add_parser(
        "landscapes", help="MPM loss landscapes, FD loss normals and Poiseuille matching (section 5)",
        description="Materials by Poisson-disk sampling in the normalised material space, setups from the 1 mm grid; "
        "per (M, S) the emulated MPM loss on a GRID^3 block around M and the finite-difference Hessian, matched to "
        "the plane-Poiseuille loss normal by eq. 43. Resumes from its store; 'virheo theta fit OUT' fits Theta to it.")
    p.add_argument("--materials", type=int, default=10, help="Poisson-disk materials (default 10)")
    p.add_argument("--setups", type=int, default=3, help="random setups per material (default 3)")
    p.add_argument("--grid", type=int, default=3, help="landscape points per axis (default 3; the paper: 8)")
    p.add_argument("--half-width", type=float, default=0.05, metavar="A",
                   help="half-width of the landscape block, normalised (default 0.05)")
    p.add_argument("--plots", type=int, default=3, metavar="N", help="Fig. 6-style PNGs of the first N pairs (default 3)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="./virheo-landscapes", metavar="OUT")
    _common(p)
    p.set_defaults(func=run_landscapes)

    c = study_subparsers.add_parser(
        "conditioning", help="condition number of the FD Hessian over a coarse setup grid (Fig. 9)",
        description="For one material, the finite-difference Hessian of the MPM loss at each setup of a "
        "STEPS x STEPS grid over 20..70 mm; writes conditioning.json and conditioning.png.")
    c.add_argument("--material", required=True, metavar="ETA,N,SIGMA_Y", help="material in SI, e.g. 3.14,0.74,1.24")
    c.add_argument("--steps", type=int, default=3, help="setups per axis over 20..70 mm (default 3)")
    c.add_argument("--out", default="./virheo-conditioning", metavar="OUT")
    _common(c)
    c.set_defaults(func=run_conditioning)


@contextmanager
def run_context(args):
    """(out folder, store, executor): ``--out``, ``--store`` (default OUT/store), ``--scheduler`` or ``--workers``."""
    from mpm import batch
    from mpm.store import Store

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    store = Store(args.store or out / "store")
    executor = batch.connect(args.scheduler) if args.scheduler else batch.local_executor(args.workers)
    try:
        yield out, store, executor
    finally:
        batch.shutdown(executor)


def _check(args) -> None:
    if args.workers is not None and args.workers < 0:
        raise ValueError(f"--workers {args.workers} must be >= 0")


def run_landscapes(args: argparse.Namespace) -> int:
    from mpm import batch
    from studies import landscapes as LS
    
    from studies.report import progress_bars

    _check(args)
    config = LS.StudyConfig(materials=args.materials, setups_per_material=args.setups, grid=args.grid,
                            half_width=args.half_width, fd_step=args.fd_step, preset=args.preset, seed=args.seed).check()
    if args.plots < 0:
        raise ValueError(f"--plots {args.plots} must be >= 0")
    with run_context(args) as (out, store, executor), progress_bars(not args.quiet) as progress:
        res = LS.run(out, config, store=store, executor=executor, progress=progress, plots=args.plots,
                     simulator=args.simulator or batch.DEFAULT_SIMULATOR)
    import numpy as np

    angles = [p["match"]["angle_fd_deg"] for p in res["pairs"] if p["match"] and "angle_fd_deg" in p["match"]]
    print(f"{len(res['pairs'])} landscapes, {res['simulations']} simulations, {res['wall_seconds']:.0f} s; "
          f"median angle FD normal vs matched Poiseuille normal: "
          f"{np.median(angles) if angles else float('nan'):.1f} deg; results in {out / LS.RESULT_FILE}")
    return 0


def run_conditioning(args: argparse.Namespace) -> int:
    from mpm import batch
    from similarity.space import Material
    from studies import landscapes as LS
    
    from studies.report import progress_bars

    _check(args)
    material = Material.parse(args.material).check_in_space()
    if args.steps < 2:
        raise ValueError(f"--steps {args.steps}: the setup grid needs at least 2 points per axis")
    with run_context(args) as (out, store, executor), progress_bars(not args.quiet) as progress:
        res = LS.conditioning(out, material, steps=args.steps, fd_step=args.fd_step, preset=args.preset,
                               store=store, executor=executor, progress=progress,
                               simulator=args.simulator or batch.DEFAULT_SIMULATOR)
    print(f"condition numbers over {args.steps}x{args.steps} setups: min {res['min']:.3g}, median {res['median']:.3g}, "
          f"max {res['max']:.3g}; {res['simulations']} simulations, {res['wall_seconds']:.0f} s; plot {out / 'conditioning.png'}")
    return 0
