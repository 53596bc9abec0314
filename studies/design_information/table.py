"""design_information.md: the information study's table of picks and scores per material, the scores per measure
and set, and the posterior check."""
from __future__ import annotations

import numpy as np

from similarity import information as I
from studies.design_information import checks
from studies.design_information.records import InformationRecord, InformationSummary
from studies.design_validation import WITHIN

MEASURE_LABELS = {"gain": "log det gain", "gain_min_eig": "smallest-eigenvalue gain",
                  "gain_shape": "log det gain of the direction alone (trace scaled to setup 1's)"}


def _fmt(v, spec=".2f") -> str:
    return "-" if v is None or (isinstance(v, float) and not np.isfinite(v)) else format(v, spec)


def table_markdown(recs: list[InformationRecord], summ: InformationSummary, done: list) -> str:
    """design_information.md: every material's picks and scores, the scores per measure and set, the posterior
    check (``done``: :class:`studies.design_information.checks.CandidateVolumes`)."""
    names = list(recs[0].config["criteria"])
    lines = ["| material | set | truth (eta, n, sigma_y) | first setup | stage-1 E_rel | "
             + " | ".join(f"{n}: pick, score" for n in names) + " |", "|---:|---|---|---|---:|" + "---|" * len(names)]
    for k, r in enumerate(recs):
        t, sc = r.truth, r.scores()
        lines.append(f"| {r.case} | {'selection' if k < summ.selection else 'held out'} | {t.eta:.3g}, {t.n:.3g}, "
                     f"{t.sigma_y:.3g} | {r.first_setup} | {r.stage_1.e_rel:.3f} | "
                     + " | ".join(f"{sc[n].pick}{' (fallback)' if n in r.fallbacks else ''}, "
                                  f"{_fmt(sc[n].score)}" for n in names) + " |")
    for measure, label in MEASURE_LABELS.items():
        for part in ("selection", "held_out"):
            per = getattr(getattr(summ, measure), part)
            if not per:
                continue
            lines += ["", f"{label}, {part.replace('_', ' ')} ({getattr(summ, part)} materials):", "",
                      "| criterion | beats candidate mean | sign test p | median normalised score | "
                      f"within {100 * WITHIN:.0f} % of best | median Spearman |", "|---|---:|---:|---:|---:|---:|"]
            for n, v in per.items():
                lines.append(f"| {n} | {v.beats_mean}/{v.materials} | {_fmt(v.sign_test_p, '.3g')} | "
                             f"{_fmt(v.median_score)} | {v.within}/{v.materials} | {_fmt(v.median_spearman)} |")
    lines += ["", "Recommended on the selection materials (the largest positive median normalised score of the criteria "
              f"`virheo design` offers): {summ.recommended or 'none, no criterion beats the candidate mean'}."]
    if done:
        lines += ["", "Posterior check (Spearman between -log posterior volume and the realised gain, per material):",
                  "", "| material | candidates | " + " | ".join(I.MEASURES) + " |",
                  "|---:|---:|" + "---:|" * len(I.MEASURES)]
        for c in done:
            rho = checks.volume_agreement(c, recs[c.case])
            lines.append(f"| {c.case} | {len(c.candidates)} | " + " | ".join(_fmt(rho[m]) for m in I.MEASURES)
                         + " |")
    return "\n".join(lines) + "\n"
