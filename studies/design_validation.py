"""How reliable the second-setup criteria proved: the held-out figures of `virheo study design-information`
(:mod:`studies.design_information`), shipped as ``studies/data/design_validation.json`` (the documented run's
``design_validation.json``), and the line `virheo design` and the report print from them.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from mpm.files import JsonRecord, read_json
from mpm.params import SETUP_RANGE_MM, Setup

SUMMARY_FILE = Path(__file__).resolve().parent / "data" / "design_validation.json"
# `virheo design`'s default criterion, as the study names it: the one that beat the candidate mean on the held-out
# materials (docs/uncertainty.md, "Does the design pay off?")
DEFAULT_CRITERION = "information"
WITHIN = 0.1  # "within 10 % of the best candidate": normalised score >= 1 - WITHIN
# the baseline "largest": the largest box, ranking setups by their area W x H (not offered by `virheo design`)
LARGEST = Setup(float(SETUP_RANGE_MM[1]), float(SETUP_RANGE_MM[1]))
SHIPPED = ("within", "beats_mean", "materials", "sign_test_p", "median_score", "median_spearman", "median_gain")


@dataclass
class CriterionValidation(JsonRecord):
    """One criterion on the held-out materials (log det gain)."""

    within: int  # materials where the pick came within WITHIN of the best candidate
    beats_mean: int  # materials where the pick beat the seeded candidates' mean
    materials: int
    sign_test_p: float | None
    median_score: float | None  # median normalised score
    median_spearman: float | None
    median_gain: float


@dataclass
class DesignValidation(JsonRecord):
    """``design_validation.json``: what `virheo design` reads."""

    study: str
    config: dict
    within: float  # WITHIN of the run
    recommended: str | None
    median_gain_seeded: float | None
    criteria: dict  # name -> CriterionValidation

    READERS = {"criteria": lambda d: {k: CriterionValidation.from_dict(v) for k, v in d.items()}}


def shipped_summary(summ, config: dict) -> DesignValidation:
    """What `virheo design` reads, from a :class:`studies.design_information.InformationSummary`: per criterion on
    the held-out materials, how often the pick came within ``WITHIN`` of the best candidate, beat the candidate
    mean, and its median realised gain."""
    held = summ.gain.held_out
    return DesignValidation(study="virheo study design-information", config=config, within=WITHIN,
                            recommended=summ.recommended, median_gain_seeded=summ.median_gain_seeded,
                            criteria={k: CriterionValidation(**{f: getattr(v, f) for f in SHIPPED})
                                      for k, v in held.items()})


def validation(criterion: str, theta: str, path=SUMMARY_FILE) -> dict | None:
    """The shipped held-out figures of ``criterion`` ("information", "perpendicularity" or "eig") with Theta map
    ``theta`` ("reference", "fitted"; "information" uses none), as validated; None when that combination was not
    validated (a custom map)."""
    name = "information" if criterion == "information" else "eig" if criterion == "eig" and theta == "reference" else (
        f"perpendicularity-{theta}" if criterion == "perpendicularity" else None)
    if name is None or not Path(path).is_file():
        return None
    data = DesignValidation.from_dict(read_json(path))
    if name not in data.criteria:
        return None
    big = data.criteria.get("largest")
    return {"name": name, **data.criteria[name].to_dict(), "recommended": data.recommended,
            "within_fraction": data.within, "median_gain_seeded": data.median_gain_seeded,
            "largest": None if big is None else big.to_dict()}


def reliability_line(v: dict | None) -> str:
    """How reliable the criterion proved, for users (a second line says when it proved weak), or "not validated"."""
    if v is None:
        return ("reliability: not validated (virheo study design-information checked the information criterion with "
                "the demo preset's model, EIG with the published Theta map and perpendicularity with the published and "
                "the fitted one)")
    line = ("reliability: not validated by estimation outcome (whether filming the proposal improves the estimate "
            "has not been measured); in the simulator's own information (virheo study design-information) "
            f"within {100 * v['within_fraction']:.0f} % of the best candidate in {v['within']} of "
            f"{v['materials']} validation materials, better than the candidates' mean in {v['beats_mean']} of "
            f"{v['materials']} (median normalised score {v['median_score']:.2f})")
    if v["sign_test_p"] >= 0.05:
        worse = v["median_score"] is not None and v["median_score"] < 0
        line += (f"\n  weak: this criterion did not beat the average random setup (sign test p = {v['sign_test_p']:.2g})"
                 + ("; its picks realised less information than a random setup, so treat the proposal as a hint on "
                    "the direction only" if worse else ", so the choice of setup matters little"))
        big = v.get("largest")
        if big:
            line += (f"; larger boxes realised more: {LARGEST} mm came within {100 * v['within_fraction']:.0f} % of the "
                     f"best candidate in {big['within']} of {big['materials']}")
    return line
