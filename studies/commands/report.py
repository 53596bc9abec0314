"""``virheo report RUN``: uncertainty report of an estimate: posterior, flow-curve band, ellipsoids, next setups (HTML)

For a folder written by `virheo estimate` or `virheo demo`: estimates the noise of the footage, trains an emulator
of the loss near the estimate (the store's simulations plus a space-filling batch of new ones), samples the
posterior over (eta [Pa s^n], n, sigma_y [Pa]) with emcee and writes RUN/posterior.json and an HTML page with
figures (RUN/report/index.html). Re-running resumes (store and emcee backend).
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from studies.commands.context import (add_command, add_laws_option, add_posterior_options, check_engine,
                                      check_posterior_options, seed)


def register(subparsers) -> None:
    p = add_command(subparsers, __doc__)
    p.add_argument("run", metavar="RUN", help="run folder holding result.json (and its store)")
    p.add_argument("--rheometer", default=None, metavar="CSV", help="rheometer flow-curve export to draw over the band")
    p.add_argument("--out", default=None, metavar="DIR", help="report folder (default RUN/report)")
    p.add_argument("--store", default=None, metavar="PATH", help="simulation store (default RUN/store)")
    add_posterior_options(p)
    p.add_argument("--seed", type=seed, default=0, help="seed of the space-filling batch and of emcee (default 0)")
    p.add_argument("--workers", type=int, default=None, metavar="K", help="local worker processes (default: one per core)")
    p.add_argument("--no-discretisation", action="store_true",
                   help="skip the half-cell simulation of the estimate that measures the discretisation error")
    add_laws_option(p)
    p.add_argument("--quiet", action="store_true", help="no progress messages")
    p.set_defaults(func=run)


def _read_rheometer(path):
    from surrogate.rheometer import read_flow_curve

    try:
        return read_flow_curve(path)
    except (UnicodeDecodeError, OSError) as exc:
        raise ValueError(f"{path}: unreadable rheometer file ({exc})") from None


def run(args: argparse.Namespace) -> int:
    from mpm.forward import Forward
    from similarity.posterior import analyse, read_result
    from studies.html_report import write_report

    folder = Path(args.run)
    from similarity.evidence import parse_laws

    laws = [law.name for law in parse_laws(args.laws)]  # an unknown law stops here
    read_result(folder)  # a folder without an estimate stops here
    check_posterior_options(args)
    curve = _read_rheometer(args.rheometer) if args.rheometer else None  # bad files stop here, before any work
    from similarity.progress import Message

    progress = None if args.quiet else (lambda ev: print(ev.text) if isinstance(ev, Message) else None)
    check_engine()
    with Forward(Path(args.store) if args.store else folder / "store", workers=args.workers) as forward:
        analysis = analyse(folder, forward=forward, new_simulations=args.new_simulations,
                           half_width=args.half_width, seed=args.seed, min_ess=args.min_ess, max_steps=args.max_steps,
                           discretisation=not args.no_discretisation, noise_count=args.noise_count,
                           laws=laws, progress=progress)
    page = write_report(Path(args.out) if args.out else folder / "report", analysis, rheometer=curve)
    summary = analysis.summary
    post = summary.posterior
    q5, q95 = post.quantiles["5"], post.quantiles["95"]
    print("posterior 90 % intervals: " + ", ".join(
        f"{k} {getattr(q5, k):.4g}..{getattr(q95, k):.4g}" for k in ("eta", "n", "sigma_y")) + " (Pa s^n, -, Pa)")
    print(f"effective samples {post.ess:.0f}, {'converged' if post.converged else 'NOT converged'}")
    check = summary.emulator.check
    if check is not None:
        print(f"emulator checked on {check.draws} simulated posterior draws ({check.rounds} fits): "
              f"{check.optimism_nats:+.2f} nats optimistic, {'trusted' if check.passed else 'NOT trusted'}")
    from studies.design_validation import reliability_line, validation

    nxt = summary.next_setups_eig
    if nxt:
        print(f"next setup by expected information gain: {nxt[0]['setup']} mm ({nxt[0]['eig_nats']:.3f} nats)")
        print("  " + reliability_line(validation("eig", "reference")))
    info = summary.next_setup_information or {}
    if info.get("setup"):
        from similarity.posterior_summary import information_gain

        gain, unit = information_gain(info)
        weighted = ", each setup weighted by its own noise" if unit == "nats" else ""
        print(f"next setup by simulated information: {info['setup']} mm ({gain:.3f} {unit}; {info['preset']} preset's "
              f"model{weighted}{summary.again})")
        if info.get("check"):
            c = info["check"]
            print(f"  calibration: the setups done carry {c['hessian_nats']:.2f} nats by their simulated Hessians, "
                  f"{c['posterior_nats']:.2f} nats in the posterior"
                  + (f"; Fisher information scaled by {c['scale']:.3g}" if c.get("scale") is not None else ""))
        for t in info.get("top", []):
            flags = "; ".join(t["flags"] or [])
            print(f"  {t['setup']:>6} mm: gain {t['score']:.3f}, {t['volume_ml']:.0f} ml, {t['cost_cpu_min']:.1f} CPU min "
                  f"per estimation stage, runout {t['runout_mm']:.0f} mm" + (f" (flag: {flags})" if flags else ""))
        print("  " + reliability_line(validation("information", "reference")))
    elif info.get("error"):
        print(f"next setup by simulated information: not available ({info['error']})")
    print("90 % flow-curve band, 95th over 5th percentile stress: " + ", ".join(
        f"{summary.band_width(r):.2f} at {r:g}" for r in (1.0, 10.0, 100.0)) + " 1/s")
    if summary.rheometer_band_coverage is not None:
        print(f"rheometer points (1-100 1/s) inside the 90 % band: {100 * summary.rheometer_band_coverage:.0f} %")
    if summary.best_fit is not None and summary.best_fit.better:
        print(summary.best_fit.text)
    print_verdicts(summary.evidence, analysis.run.preset.name)
    print(f"report: {page}")
    return 0


def print_verdicts(evidence, preset: str | None) -> None:
    """The laws' verdicts and log Bayes factors against Herschel-Bulkley, one line each, and how the verdicts fared
    at the run's preset (:func:`studies.law_validation.calibration_line`)."""
    from studies.law_validation import calibration_line

    if evidence is None:
        print("laws: no evidence computed")
        return
    for v in evidence.verdicts:
        print(v.text)
    ref = evidence.of("herschel-bulkley")
    print("laws, ln BF against Herschel-Bulkley (probability at equal prior odds): " + ", ".join(
        f"{e.law} {e.log_z - ref.log_z:+.1f} ± {np.hypot(e.log_z_err, ref.log_z_err):.1f} "
        f"({evidence.probabilities[e.law]:.2f})" for e in evidence.laws if e.law != ref.law))
    print("  " + calibration_line(preset))
