"""``virheo estimate DIR [DIR ...]``: Herschel-Bulkley parameters from dam-break footage (Algorithm 1)."""
from __future__ import annotations

import argparse
import sys
from contextlib import contextmanager
from pathlib import Path

from similarity.presets import PRESETS


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "estimate", help="estimate eta, n, sigma_y from experiment folders (CMA-ES, Algorithm 1)",
        description="Fit the Herschel-Bulkley parameters to one or more experiment folders (setup 1 first). "
        "Stage k fits the first k folders. Re-running the same command after an interruption resumes it.",
    )
    p.add_argument("dirs", nargs="+", metavar="DIR", help="experiment folders (settings.xml, camera_params.xml, config_01..08.png)")
    p.add_argument("--preset", default="footage", choices=tuple(PRESETS),
                   help="accuracy/time trade-off (default footage: coarse search, finished at the validated discretisation)")
    p.add_argument("--generations", type=int, default=None, metavar="N", help="CMA-ES generations per stage (default: the preset's)")
    p.add_argument("--workers", type=int, default=None, metavar="K", help="local worker processes (default: one per core; 0: in-process)")
    p.add_argument("--scheduler", default=None, metavar="ADDR", help="dask.distributed scheduler address, e.g. tcp://host:8786")
    p.add_argument("--seed", type=int, default=0, help="CMA-ES seed (default 0)")
    p.add_argument("--store", default=None, metavar="PATH", help="simulation store (default: OUT/store)")
    p.add_argument("--out", required=True, metavar="OUT", help="output folder for result.json, flow_curve.png, overlays")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(func=run)


def check_args(args) -> None:
    if args.generations is not None and args.generations < 1:
        raise ValueError(f"--generations {args.generations} must be >= 1")
    if args.workers is not None and args.workers < 0:
        raise ValueError(f"--workers {args.workers} must be >= 0")


@contextmanager
def run_context(args):
    """(out folder, store, executor) of a long run: ``--out``, ``--store`` (default OUT/store), and
    ``--scheduler`` (dask) or ``--workers`` local processes; the executor is shut down afterwards."""
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


def run(args: argparse.Namespace) -> int:
    from mpm.experiment import load
    from similarity import estimate as E
    from studies.report import progress_bars, write_estimate_report

    check_args(args)
    experiments = [load(d) for d in args.dirs]  # malformed folders stop here, before any work
    for e in experiments:
        if len(e.frames) != 8:
            raise ValueError(f"{e.name}: expected 8 frames config_01..08.png, found {len(e.frames)}")
        for w in e.warnings:
            sys.stderr.write(f"virheo estimate: warning: {e.name}: {w}\n")
    with run_context(args) as (out, store, executor), progress_bars(not args.quiet) as progress:
        est = E.estimate(experiments, preset=args.preset, seed=args.seed, executor=executor, store=store,
                         generations=args.generations, progress=progress)
        frames = E.simulated_frames(est.material, experiments, preset=args.preset, store=store, executor=executor)
    write_estimate_report(out, est, experiments, frames=frames,
                          extra={"folders": [str(Path(d).resolve()) for d in args.dirs]})
    m = est.material
    print(f"estimate: eta = {m.eta:.4g} Pa s^n, n = {m.n:.4g}, sigma_y = {m.sigma_y:.4g} Pa "
          f"(loss {est.loss:.5f}, {est.simulations} simulations, {est.wall_seconds:.0f} s)")
    if est.next_setup is not None:
        print(f"next setup: {est.next_setup} mm (width x height)")
    print(f"report: {out / 'result.json'}")
    print(f"uncertainty (posterior, credible intervals, next setup by information gain, HTML page): virheo report {out}")
    return 0
