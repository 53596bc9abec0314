"""``virheo estimate DIR [DIR ...]``: estimate eta, n, sigma_y from experiment folders (CMA-ES, Algorithm 1)

Fit the Herschel-Bulkley parameters (eta [Pa s^n], n [-], sigma_y [Pa]) to one or more experiment folders (setup 1
first). Stage k fits the first k folders. Re-running the same command after an interruption resumes it.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from studies.commands.context import add_command, add_preset_option, add_run_options, check_run_options, open_run, seed


def register(subparsers) -> None:
    p = add_command(subparsers, __doc__)
    p.add_argument("dirs", nargs="+", metavar="DIR",
                   help="experiment folders (settings.xml, camera_params.xml, config_01..08.png)")
    add_preset_option(p, default="footage")
    p.add_argument("--seed", type=seed, default=0, help="CMA-ES seed (default 0)")
    p.add_argument("--start", default=None, metavar="ETA,N,SIGMA_Y",
                   help="stage 1's starting point in SI (eta [Pa s^n], n [-], sigma_y [Pa]), e.g. a rheometer's fit "
                   "or an earlier estimate (default: the centre of the material space)")
    p.add_argument("--slip-mm", type=float, default=None, metavar="B",
                   help="Navier slip length of the floor and walls in mm, in every stage (default: the preset's; "
                   "footage: sticking throughout; footage-1p: 1 mm in its finishing stage; 0: sticking throughout; measured effect "
                   "in docs/performance.md, Wall slip)")
    p.add_argument("--density-correction", action="store_true",
                   help="the solver's density correction in every stage (one particle per cell then converges in "
                   "2D and ranks materials like the paper's discretisation; measured in docs/decisions.md, "
                   "Density correction)")
    add_run_options(p, default_out=None)
    p.set_defaults(func=run)


def load_experiments(dirs, command: str) -> list:
    """Experiment folders read and checked before any work: malformed folders, setups outside the setup
    space and footage without evidence (no material, no motion, material leaving the image) stop here."""
    from mpm import experiment
    from mpm.params import Setup

    experiments = [experiment.load(d) for d in dirs]
    for e in experiments:
        try:
            Setup(e.width_mm, e.height_mm).check_in_space()
        except ValueError as exc:
            raise ValueError(f"{e.name}: {exc}") from None
        experiment.check_footage(e)
        for w in e.warnings:
            sys.stderr.write(f"virheo {command}: warning: {e.name}: {w}\n")
    return experiments


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from similarity import estimate as E
    from studies.report import write_estimate_report

    check_run_options(args)
    preset = E.get_preset(args.preset)
    if args.slip_mm is not None:
        if not 0.0 <= args.slip_mm <= 1000.0:  # also refuses nan
            raise ValueError(f"--slip-mm {args.slip_mm:g} must be within 0-1000 mm (0: sticking walls)")
        preset = replace(preset, slip_length_m=args.slip_mm * 1e-3)
    if args.density_correction:
        preset = replace(preset, density_correction=True)
    start = None if args.start is None else E.Material.parse(args.start).check_in_space()
    experiments = load_experiments(args.dirs, "estimate")
    with open_run(args) as run:
        est = E.estimate(experiments, preset=preset, seed=args.seed, forward=run.forward,
                         generations=args.generations, progress=run.progress, start=start)
        frames = E.simulated_frames(est.material, experiments, preset=preset, forward=run.forward)
        result = write_estimate_report(run.out, est, experiments, frames=frames,
                                       extra={"folders": [str(Path(d).resolve()) for d in args.dirs], **run.counts()})
    m, model = est.material, est.model
    print(f"estimate: eta = {m.eta:.4g} Pa s^n, n = {m.n:.4g}, sigma_y = {m.sigma_y:.4g} Pa "
          f"(loss {est.loss:.5f} at {model.cell_mm:g} mm cells, {model.ppc} particle(s) per cell per axis"
          f"{', density-corrected' if model.density_correction else ''}"
          f"{f', walls slipping {model.slip_length_m * 1e3:g} mm' if model.slip_length_m else ''}; "
          f"{run.cost_line(est.simulations)})")
    for w in est.warnings:
        sys.stderr.write(f"virheo estimate: warning: {w}\n")
    for note in result["notes"]:
        sys.stderr.write(f"virheo estimate: note: {note}\n")
    done = " ".join(f"--done {e.width_mm:g}x{e.height_mm:g}" for e in experiments)
    design = f"virheo design --material {m.eta:.4g},{m.n:.4g},{m.sigma_y:.4g} {done}"
    if est.next_setup is not None:
        print(f"next setup: {est.next_setup} mm (width x height), by the paper's perpendicularity criterion, which "
              f"proved weak in the simulator's own information; the default criterion: {design}")
    else:
        print(f"next setup: none proposed by the paper's perpendicularity criterion (note above); the simulator's "
              f"own criterion: {design}")
    print(f"report: {run.out / 'result.json'}")
    print(run.report_hint())
    return 0
