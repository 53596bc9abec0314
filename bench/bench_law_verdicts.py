"""Does the shared footage resolve a yield stress?  The laws' verdicts for the 7 real materials (docs/uncertainty.md).

    python bench/bench_law_verdicts.py [--root DIR] [--preset survey] [--workers 2] [--only milk lotion]

For each material: ``virheo estimate SETUP1 SETUP2 --preset PRESET --out ROOT/<slug>`` (skipped when
ROOT/<slug>/result.json holds a run of that preset), then ``virheo report ROOT/<slug>`` (skipped when its
posterior.json holds the laws' evidence; a killed run resumes from its store).  Prints, per material, the verdicts
(yield stress: Herschel-Bulkley over the power law; shear thinning: over Bingham), the log Bayes factors with their
Monte Carlo errors and the most probable law, beside Table 1's estimate and, for the 4 materials with a rheometer
curve, the rheometer fits of the four laws (yield stress, and the best law by BIC).  Writes ROOT/law_verdicts.json.
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


def main(argv=None) -> int:
    from mpm.datasets import table1
    from similarity.posterior_summary import read_posterior
    from studies.cli import main as virheo

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--root", default=os.path.expanduser("~/.cache/virheometry/law_verdicts"))
    p.add_argument("--preset", default="survey")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--new-simulations", type=int, default=12)
    p.add_argument("--only", nargs="*", default=None, help=f"slugs: {', '.join(SLUGS.values())}")
    args = p.parse_args(argv)
    root = Path(args.root)
    fits, results = rheometer_fits(), {}
    print(f"measured: {how_measured()}")
    for name, slug, mine, folders in real_materials(SLUGS, args.only):
        out = root / slug
        wall = {}
        done = (out / "result.json").exists() and json.loads((out / "result.json").read_text()).get("preset") == args.preset
        if not done:
            t0 = time.perf_counter()
            code = virheo(["estimate", *folders, "--out", str(out), "--preset", args.preset, "--workers",
                           str(args.workers), "--quiet"])
            if code:
                return code
            wall["estimate_s"] = time.perf_counter() - t0
        try:
            reported = read_posterior(out).evidence is not None
        except ValueError:
            reported = False
        if not reported:
            t0 = time.perf_counter()
            code = virheo(["report", str(out), "--workers", str(args.workers), "--new-simulations",
                           str(args.new_simulations), "--quiet"])
            if code:
                return code
            wall["report_s"] = time.perf_counter() - t0
        s = read_posterior(out)
        ev = s.evidence
        paper = table1(mine[0])
        entry = {"material": name, "setups": s.setups, "estimate": s.estimate.to_dict(), "table1": paper.to_dict(),
                 "verdicts": [v.to_dict() for v in ev.verdicts], "probabilities": ev.probabilities,
                 "most_probable": ev.most_probable, "wall": wall}
        if name in fits:
            f = fits[name]
            best = min(f.values(), key=lambda x: x.bic)
            entry["rheometer"] = {"sigma_y": f["herschel-bulkley"].material.sigma_y,
                                  "n": f["herschel-bulkley"].material.n, "best_by_bic": best.law,
                                  "bic": {law: fit.bic for law, fit in f.items()}}
        results[slug] = entry
        (root / "law_verdicts.json").write_text(json.dumps(results, indent=1))
    print("| material | setups [mm] | yield stress: ln BF (HB over power law) | shear thinning: ln BF (HB over "
          "Bingham) | most probable law | Table 1 sigma_y, n | rheometer HB sigma_y, n; best law by BIC |")
    print("|---|---|---|---|---|---|---|")
    for slug, e in results.items():
        cells = [f"{v['log_bf']:+.2f} ± {v['log_bf_err']:.2f}: "
                 f"{v['text'].split(': ', 1)[1].split(' (')[0]}" for v in e["verdicts"]]
        rh = e.get("rheometer")
        rh_cell = f"{rh['sigma_y']:.2f} Pa, {rh['n']:.2f}; {rh['best_by_bic']}" if rh else "no curve"
        print(f"| {e['material']} | {' + '.join(e['setups'])} | {cells[0]} | {cells[1]} | {e['most_probable']} "
              f"({100 * e['probabilities'][e['most_probable']]:.0f} %) | {e['table1']['sigma_y']:.2f} Pa, "
              f"{e['table1']['n']:.2f} | {rh_cell} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
