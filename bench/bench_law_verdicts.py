"""Does the shared footage resolve a yield stress?  The laws' verdicts for the 7 real materials (docs/uncertainty.md).

    python bench/bench_law_verdicts.py [--root DIR] [--preset survey] [--workers 2] [--only milk lotion]

For each material: ``virheo estimate SETUP1 SETUP2 --preset PRESET --out ROOT/<slug>`` (skipped when
ROOT/<slug>/result.json holds a run of that preset), then ``virheo report ROOT/<slug>`` (skipped when its
posterior.json holds the laws' evidence of that estimate; a killed run resumes from its store).  A material whose
estimate or report fails is recorded with its error and the others go on (exit status 1 at the end).  Prints the
command, then per material the verdicts (yield stress: Herschel-Bulkley over the power law; shear thinning: over
Bingham), the log Bayes factors with their Monte Carlo errors, the most probable laws, whether the emulator passed
its checks, beside Table 1's estimate and, for the 4 materials with a rheometer curve, the rheometer fits of the
four laws (Herschel-Bulkley's yield stress and n, the best law by BIC and the power law's BIC above it).  Merges
into ROOT/law_verdicts.json (a run with ``--only`` keeps the other materials' entries).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from measured import how_measured, real_materials  # noqa: E402  (bench/ is this script's folder)
from studies.law_validation import NAMES  # noqa: E402

SLUGS = {"Japanese thickened Worcestershire sauce": "worcestershire", "moisturizing milk": "milk",
         "Japanese cabbage pancake sauce": "okonomiyaki", "lotion": "lotion", "thousand island dressing": "island",
         "Cobb salad dressing": "cobb", "carbonara sauce": "carbonara"}


def rheometer_fits() -> dict:
    """Material name -> {law: HerschelBulkleyFit} of the shared rheometer curves (1-100 1/s)."""
    from mpm.datasets import require_data_dir
    from mpm.laws import LAWS
    from surrogate.rheometer import fit_herschel_bulkley, read_flow_curve

    out = {}
    for f in sorted((require_data_dir() / "rheometer").glob("*.csv")):
        curve = read_flow_curve(f)
        out[curve.material_name] = {law: fit_herschel_bulkley(curve, law=law) for law in LAWS}
    return out


def _reported(out: Path) -> bool:
    """ROOT/<slug>/posterior.json holds the laws' evidence of the estimate in its result.json."""
    from similarity.posterior_summary import read_posterior

    try:
        s = read_posterior(out)
        result = json.loads((out / "result.json").read_text())
    except (ValueError, OSError):
        return False
    return s.evidence is not None and s.estimate.to_dict() == result.get("estimate")


def _run(argv: list) -> str | None:
    """``virheo ARGV``; None when it succeeded, else why not (one line)."""
    from studies.cli import main as virheo

    try:
        code = virheo(argv)
    except Exception as exc:  # noqa: BLE001  (one material's failure is recorded, the others go on)
        return f"{argv[0]}: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
    return None if code == 0 else f"{argv[0]} exited with status {code} (its one-line error is above)"


def _entry(name: str, out: Path, mine, fits: dict, wall: dict) -> dict:
    from mpm.datasets import table1
    from similarity.posterior_summary import read_posterior

    s = read_posterior(out)
    ev = s.evidence
    checks = {"posterior": s.emulator.check, "laws": s.emulator.laws_check}
    entry = {"material": name, "setups": s.setups, "estimate": s.estimate.to_dict(), "table1": table1(mine[0]).to_dict(),
             "verdicts": [v.to_dict() for v in ev.verdicts], "probabilities": ev.probabilities,
             "most_probable": ev.most_probable, "checks": {k: None if c is None else c.passed for k, c in checks.items()},
             "wall": wall}
    if name in fits:
        f = fits[name]
        best = min(f.values(), key=lambda x: x.bic)
        entry["rheometer"] = {"sigma_y": f["herschel-bulkley"].material.sigma_y, "n": f["herschel-bulkley"].material.n,
                              "best_by_bic": best.law, "bic": {law: fit.bic for law, fit in f.items()},
                              "aic": {law: fit.aic for law, fit in f.items()}}
    return entry


def _row(e: dict) -> str:
    if "failed" in e:
        return f"| {e['material']} | failed: {e['failed']} | | | | | | |"
    cells = []
    for v in e["verdicts"]:
        word = ("not resolved" if not v["resolved"] else
                ("resolved, holds" if v["holds"] else "resolved, does not hold") + f" ({v['strength']})")
        cells.append(f"{v['log_bf']:+.2f} ± {v['log_bf_err']:.2f}: {word}")
    probs = sorted(e["probabilities"].items(), key=lambda kv: -kv[1])
    laws = "; ".join(f"{NAMES[law]} {100 * p:.0f} %" for law, p in probs if p >= 0.2 or law == probs[0][0])
    checks = ", ".join(f"{k} {'passed' if ok else 'FAILED'}" for k, ok in e["checks"].items() if ok is not None)
    rh = e.get("rheometer")
    rh_cell = "no curve"
    if rh:
        above = rh["bic"]["power-law"] - rh["bic"][rh["best_by_bic"]]
        rh_cell = (f"{rh['sigma_y']:.2f} Pa, {rh['n']:.2f}; {NAMES[rh['best_by_bic']]}"
                   + (f" (power law +{above:.0f} in BIC)" if rh["best_by_bic"] != "power-law" else ""))
    return (f"| {e['material']} | {' + '.join(e['setups'])} | {cells[0]} | {cells[1]} | {laws} | {checks} | "
            f"{e['table1']['sigma_y']:.2f} Pa, {e['table1']['n']:.2f} | {rh_cell} |")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--root", default=os.path.expanduser("~/.cache/virheometry/law_verdicts"))
    p.add_argument("--preset", default="survey")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--new-simulations", type=int, default=12)
    p.add_argument("--only", nargs="*", default=None, choices=sorted(SLUGS.values()), metavar="SLUG",
                   help=f"slugs: {', '.join(SLUGS.values())}")
    args = p.parse_args(argv)
    root = Path(args.root)
    fits = rheometer_fits()
    file = root / "law_verdicts.json"
    results = json.loads(file.read_text()) if file.is_file() else {}
    print(f"measured: {how_measured()}")
    print(f"command: python bench/bench_law_verdicts.py {' '.join(sys.argv[1:] if argv is None else argv)} "
          f"(preset {args.preset}, --new-simulations {args.new_simulations}, {args.workers} workers)")
    failed = 0
    for name, slug, mine, folders in real_materials(SLUGS, args.only):
        out = root / slug
        wall = {}
        done = (out / "result.json").exists() and json.loads((out / "result.json").read_text()).get("preset") == args.preset
        why = None
        if not done:
            t0 = time.perf_counter()
            why = _run(["estimate", *folders, "--out", str(out), "--preset", args.preset, "--workers",
                              str(args.workers), "--quiet"])
            wall["estimate_s"] = time.perf_counter() - t0
        if why is None and not _reported(out):
            t0 = time.perf_counter()
            why = _run(["report", str(out), "--workers", str(args.workers), "--new-simulations",
                              str(args.new_simulations), "--quiet"])
            wall["report_s"] = time.perf_counter() - t0
        if why is not None:
            failed += 1
            results[slug] = {"material": name, "failed": why}
        else:
            results[slug] = _entry(name, out, mine, fits, wall)
        root.mkdir(parents=True, exist_ok=True)
        file.write_text(json.dumps(results, indent=1))
    print("| material | setups [mm] | yield stress: ln BF (HB over power law) | shear thinning: ln BF (HB over "
          "Bingham) | most probable laws | emulator checks | Table 1 sigma_y, n | rheometer HB sigma_y, n; best law by "
          "BIC |")
    print("|---|---|---|---|---|---|---|---|")
    for slug in SLUGS.values():
        if slug in results:
            print(_row(results[slug]))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
