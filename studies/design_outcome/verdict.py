"""The outcome study's test and pass rule (pre-registered in docs/uncertainty.md): per-material errors, paired
Wilcoxon signed-rank and bootstrap intervals against ``random`` and ``perpendicularity``, the verdict."""
from __future__ import annotations

import numpy as np

from studies.design_outcome.records import ArmSummary, Comparison, OutcomeRecord, OutcomeSummary

ARMS = ("information", "perpendicularity", "eig", "largest", "random", "repeat")
DEFAULT_ARM = "information"  # the shipped default criterion of `virheo design`
BOOTSTRAP = 10_000
LEVEL = 0.90
ALPHA = 0.05


def per_material(records: list[OutcomeRecord], field: str = "flow_error") -> dict:
    """arm -> {material index -> mean of ``field`` over its seeds (and the random draws)}; a run without an estimate
    (NaN, or null as JSON keeps it) is left out, and a material without any run of the arm is missing for it."""
    acc: dict = {}
    for r in records:
        for a in r.arms:
            v = getattr(a, field)
            if v is not None and np.isfinite(v):
                acc.setdefault(a.arm.split("_")[0], {}).setdefault(r.material_index, []).append(float(v))
    return {arm: {m: float(np.mean(v)) for m, v in sorted(ms.items())} for arm, ms in acc.items()}


def compare(arm: dict, reference: dict, name: str, seed: int = 62) -> Comparison:
    """Paired comparison of two arms' per-material errors (:class:`Comparison`)."""
    from scipy.stats import wilcoxon

    common = sorted(set(arm) & set(reference))
    d = np.array([arm[m] - reference[m] for m in common])
    if not len(d):
        return Comparison(name, 0, None, None, None)
    rng = np.random.default_rng(seed)
    boots = np.median(d[rng.integers(0, len(d), size=(BOOTSTRAP, len(d)))], axis=1)
    tail = (1 - LEVEL) / 2
    nonzero = d[d != 0]  # identical runs (e.g. two arms that picked the same setup) carry no sign: dropped
    p = float(wilcoxon(nonzero, alternative="less", method="exact").pvalue) if nonzero.size else 1.0  # exact null
    return Comparison(name, len(d), float(np.median(d)), [float(np.quantile(boots, tail)),
                                                          float(np.quantile(boots, 1 - tail))], p)


def verdict(records: list[OutcomeRecord]) -> OutcomeSummary:
    """The pre-registered test and pass rule (module docstring; docs/uncertainty.md)."""
    flow, erel = per_material(records), per_material(records, "e_rel")
    arms = {}
    for arm in ARMS:
        if arm not in flow:
            continue
        against = {ref: compare(flow[arm], flow[ref], ref) for ref in ("random", "perpendicularity")
                   if ref in flow and ref != arm}
        runs = [a for r in records for a in r.arms if a.arm.split("_")[0] == arm]
        arms[arm] = ArmSummary(float(np.median(list(flow[arm].values()))), float(np.median(list(erel[arm].values()))),
                               [flow[arm][m] for m in sorted(flow[arm])], against,
                               sum(a.fallback is not None for a in runs), sum(a.estimate is None for a in runs))
    best = min(arms, key=lambda a: arms[a].median_flow_error) if arms else None

    def beats_random(a: str) -> bool:
        c = arms[a].against.get("random")
        return c is not None and c.wilcoxon_p is not None and c.wilcoxon_p < ALPHA

    passes = None
    if DEFAULT_ARM in arms and best is not None:
        vs_best = (compare(flow[DEFAULT_ARM], flow[best], best) if best != DEFAULT_ARM else None)
        no_worse = vs_best is None or (vs_best.interval is not None and vs_best.interval[0] <= 0.0)
        passes = beats_random(DEFAULT_ARM) and no_worse
    winners = [a for a in arms if a != "random" and beats_random(a)]
    if passes:
        recommended, text = DEFAULT_ARM, f"the default, {DEFAULT_ARM}, passes: it beats random and is no worse than the best arm"
    elif best in winners:
        recommended, text = best, f"{best} wins: it beats random and has the lowest median flow-curve error"
    else:
        recommended = None
        text = ((f"{', '.join(winners)} beat{'s' if len(winners) == 1 else ''} random on the flow-curve error "
                 f"(p < 0.05) without the lowest median error, and the default does not pass" if winners else
                 "no arm beats random on the flow-curve error (p < 0.05)")
                + (f"; the lowest median error: {best}" if best else ""))
    return OutcomeSummary(len({r.material_index for r in records}), len(records), arms, best, passes, recommended, text,
                          winners)
