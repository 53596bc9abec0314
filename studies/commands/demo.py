"""``virheo demo``: emulated two-setup ViRheometry run on a default material (demo preset)

Simulates footage of a known material (the ground truth), estimates it back with Algorithm 1 (setup 1, then the
proposed setup 2) and writes a small report. Re-running resumes from the store.
"""
from __future__ import annotations

import argparse
import sys

from mpm.params import DEFAULT_DENSITY_KG_M3
from studies.commands.context import (add_command, add_preset_option, add_run_options, check_run_options, open_run,
                                      real, seed)

# The embedded default specimen (SI) and its first setup (mm); see docs/performance.md (estimate).
DEFAULT_TRUTH = "3.0,0.5,15.0"
DEFAULT_FIRST_SETUP = "40x50"
DEFAULT_SEED = 0  # demo preset seeds 0..3 measured: docs/validation.md


def register(subparsers) -> None:
    p = add_command(subparsers, __doc__)
    p.add_argument("--material", default=DEFAULT_TRUTH, metavar="ETA,N,SIGMA_Y",
                   help=f"ground truth: eta [Pa s^n], n [-], sigma_y [Pa] (default {DEFAULT_TRUTH})")
    p.add_argument("--setup", default=DEFAULT_FIRST_SETUP, metavar="WxH",
                   help=f"first setup, width x height in mm (default {DEFAULT_FIRST_SETUP})")
    p.add_argument("--density", type=real, default=DEFAULT_DENSITY_KG_M3, metavar="KG_M3",
                   help=f"density of the material in kg/m^3 (default {DEFAULT_DENSITY_KG_M3:g})")
    p.add_argument("--seed", type=seed, default=DEFAULT_SEED, help=f"CMA-ES seed (default {DEFAULT_SEED})")
    add_preset_option(p, default="demo")
    add_run_options(p, default_out="./virheo-demo")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from mpm.ranges import check_density
    from similarity import estimate as E
    from similarity.progress import Message
    from mpm.params import Material, Setup
    from studies.report import write_estimate_report

    truth = Material.parse(args.material).check_in_space()
    first = Setup.parse(args.setup).check_in_space()
    density = check_density(args.density, "--density")
    check_run_options(args)
    with open_run(args) as run:
        run.progress(Message(f"ground truth: eta={truth.eta:g} Pa s^n, n={truth.n:g}, "
                      f"sigma_y={truth.sigma_y:g} Pa; first setup {first} mm"))
        est, filmed = E.emulate_virheometry(truth, first, n_setups=2, preset=args.preset, seed=args.seed,
                                            density=density, forward=run.forward,
                                            generations=args.generations, progress=run.progress)
        frames = E.simulated_frames(est.material, filmed, preset=args.preset, forward=run.forward)
        result = write_estimate_report(run.out, est, filmed, frames=frames, truth=truth,
                                       extra={"simulator": run.forward.simulator, **run.counts()})
    for note in result["notes"]:
        sys.stderr.write(f"virheo demo: note: {note}\n")
    m = est.material
    print(f"truth:    eta = {truth.eta:.4g} Pa s^n, n = {truth.n:.4g}, sigma_y = {truth.sigma_y:.4g} Pa")
    print(f"estimate: eta = {m.eta:.4g} Pa s^n, n = {m.n:.4g}, sigma_y = {m.sigma_y:.4g} Pa")
    print(f"E_rel = {result['e_rel']:.4f} (eq. 44) after setups {' + '.join(est.setups)} mm; "
          f"{run.cost_line(est.simulations)}")
    print(f"report: {run.out / 'result.json'}")
    print(run.report_hint())
    return 0
