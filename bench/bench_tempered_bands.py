"""The real-footage flow-curve bands had N_eff of eq. (1) been k times the count, from the posteriors as run
(docs/uncertainty.md).

    python bench/bench_tempered_bands.py --root DIR [--k 1 2 3 4 6 8]

DIR holds the folders of ``python bench/bench_real_estimates.py --root DIR``, each after ``virheo report
DIR/<slug> --rheometer CSV`` (its ``posterior_samples.npy`` and ``posterior_log_prob.npy``).  Counting k residuals
where one was counted raises the likelihood to the power k; under the uniform prior the posterior's samples
become the tempered posterior's with weights p^(k-1) (``studies.credible.tempering_weights``).  For each material
and k the bench prints the weighted 90 % band's width at 1, 10 and 100 1/s, the share of the rheometer points over
1-100 1/s inside it, and the weights' Kish effective sample size as a share of the samples.  An approximation: the
emulator's box and checks stay as they ran at k = 1.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from bench_real_estimates import SLUGS, rheometer_curves  # noqa: E402  (bench/ is this script's folder)
from measured import how_measured  # noqa: E402
from similarity.flow_band import band_coverage, band_width, flow_band  # noqa: E402
from similarity.space import denormalize  # noqa: E402
from studies.credible import TEMPERING, kish_fraction, tempering_weights  # noqa: E402

RATES = (1.0, 10.0, 100.0)  # 1/s, where the band's width is printed


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--root", type=Path, required=True, help="the root of bench_real_estimates.py's folders")
    p.add_argument("--k", type=float, nargs="+", default=list(TEMPERING), help="N_eff multipliers")
    args = p.parse_args(argv)
    curves = rheometer_curves()
    print(f"# measured: {how_measured()}")
    print("| material | k | band width at 1 / 10 / 100 1/s | rheometer points in band | Kish ESS |")
    print("|---|---:|---|---:|---:|")
    found = 0
    for name, slug in SLUGS.items():
        folder = args.root / slug
        samples, log_prob = folder / "posterior_samples.npy", folder / "posterior_log_prob.npy"
        if not (samples.is_file() and log_prob.is_file()):
            continue
        found += 1
        si, lp = denormalize(np.load(samples)), np.load(log_prob)
        for k in args.k:
            w = tempering_weights(lp, k)
            band = flow_band(si, None if k == 1 else w)  # k = 1: the report's own band
            widths = " / ".join(f"{band_width(band, r):.2f}" for r in RATES)
            print(f"| {name} | {k:g} | {widths} | {100 * band_coverage(band, curves[name]):.0f} % | {100 * kish_fraction(w):.0f} % |")
    if not found:
        print(f"bench_tempered_bands: no reported posterior under {args.root} (run `virheo report` on its folders)",
              file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
