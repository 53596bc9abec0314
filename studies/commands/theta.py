"""``virheo theta fit STUDY --out theta.json``: fit the conversion map Theta (section 5.5) to a landscape study."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from studies.commands.context import add_command_group, seed


def register(subparsers) -> None:
    sub = add_command_group(subparsers, "theta", help="fit the conversion map Theta to a landscape study (section 5.5)",
                            description="Conversion maps Theta(M, S) -> (P, L).", dest="theta_command", metavar="ACTION")
    f = sub.add_parser("fit", help="fit Theta to the matched landscapes of a study",
                       description="Match every landscape of STUDY (a folder written by 'virheo study landscapes') to "
                       "its best plane-Poiseuille setup (eq. 43, 1D search over P L), fit the reciprocal degree-2 "
                       "polynomial with cross-validated ridge regularisation and save it in the published JSON layout "
                       "(usable as 'virheo design --theta FILE'). Whole materials are held out for testing.")
    f.add_argument("study", metavar="STUDY", nargs="+",
                   help="landscape study folder(s); studies with the same grid, half-width and FD step "
                   "are fitted together")
    f.add_argument("--out", required=True, metavar="theta.json", help="where to write the fitted map")
    f.add_argument("--test-fraction", type=float, default=0.3, metavar="F",
                   help="fraction of the study's materials held out of the fit (default 0.3)")
    f.add_argument("--seed", type=seed, default=0, help="seed of the held-out split")
    f.add_argument("--name", default="fitted", help="name stored in the map")
    f.add_argument("--prior", default=None, metavar="MAP",
                   help="fit a correction to this map ('reference', 'fitted' or a JSON file) instead of a map of "
                   "our own: the regularisation shrinks towards it (default: none)")
    f.add_argument("--compare", type=int, default=50, metavar="N",
                   help="random materials on which the second setups of the fitted and published maps are compared (default 50)")
    f.set_defaults(func=run_fit)


def run_fit(args: argparse.Namespace) -> int:
    from studies import landscapes as LS
    from studies import theta_study as TS
    from studies.report import write_json

    studies = [LS.load(s) for s in args.study]
    out = Path(args.out)
    if not out.parent.resolve().is_dir():
        raise FileNotFoundError(f"--out: folder {out.parent} does not exist")
    theta, report = TS.fit_theta(studies, test_fraction=args.test_fraction, seed=args.seed, name=args.name,
                                 prior=args.prior)
    theta.save(out)
    from surrogate.theta import load

    report["design"] = TS.compare_designs(theta, load("reference"), count=args.compare, seed=args.seed)
    report_path = out.with_name(out.stem + "_report.json")
    write_json(report_path, report)
    s = report["fit"]
    print(f"Theta fitted to {s['samples']} landscapes of {s['materials']} materials: ridge alpha {s['alpha']:.3g}, "
          f"leave-one-material-out RMS error of C = P L {s['cv_rms_C_Pa']:.3g} Pa (spread of the targets "
          f"{s['target_rms_C_Pa']:.3g} Pa)")
    for label in ("train", "test"):
        m = report.get(f"median_angle_{label}")
        if m:
            fmt = lambda v: "n/a" if v is None else f"{v:.1f}"
            print(f"  median angle to the FD loss normal on {m['landscapes']} {label} landscapes: "
                  f"matched {fmt(m['matched'])} deg, "
                  f"fitted map {fmt(m['fitted'])} deg, published map {fmt(m['reference'])} deg")
    d = report["design"]
    if d["records"]:
        print(f"  experimenters' second setups reproduced: fitted map {d['records_reproduced_ours']}/{len(d['records'])}, "
              f"published map {d['records_reproduced_reference']}/{len(d['records'])}")
    r = d["random"]
    print(f"  {r['materials']} random materials: same second setup {r['same_setup']}/{r['both_valid']}, "
          f"within 5 mm {r['within_5mm']}/{r['both_valid']}")
    print(f"map written to {out}; report {report_path}")
    return 0
