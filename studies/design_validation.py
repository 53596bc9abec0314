"""How reliable the second-setup criteria proved: the held-out figures of `virheo study design-information`
(:mod:`studies.design_information`), shipped as ``studies/data/design_validation.json`` (the documented run's
``design_validation.json``); the estimation outcome of `virheo study design-outcome` (:mod:`studies.design_outcome`),
shipped as ``studies/data/design_outcome.json`` (the documented run's ``design_outcome.json``) once it has run; and
the line `virheo design` and the report print from them.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from mpm.files import JsonRecord, read_json
from mpm.params import SETUP_RANGE_MM, Setup

SUMMARY_FILE = Path(__file__).resolve().parent / "data" / "design_validation.json"
OUTCOME_FILE = Path(__file__).resolve().parent / "data" / "design_outcome.json"
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


def validation(criterion: str, theta: str, path=SUMMARY_FILE, outcome_path=OUTCOME_FILE) -> dict | None:
    """The shipped held-out figures of ``criterion`` ("information", "perpendicularity" or "eig") with Theta map
    ``theta`` ("reference", "fitted"; "information" uses none), as validated, with its estimation outcome
    (:func:`outcome`, None where the outcome study has not run or has no such arm); None when that combination was
    not validated (a custom map)."""
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
            "largest": None if big is None else big.to_dict(), "outcome": outcome(name, outcome_path)}


# a criterion as design_validation names it -> its arm in the outcome study (the published Theta map only)
OUTCOME_ARMS = {"information": "information", "eig": "eig", "perpendicularity-reference": "perpendicularity"}


@dataclass
class OutcomeValidation(JsonRecord):
    """One arm of the outcome study, as `virheo design` quotes it."""

    arm: str
    materials: int
    median_flow_error: float
    random_median_flow_error: float | None
    median_difference_vs_random: float | None  # the arm minus random, per material
    interval_vs_random: list | None  # bootstrap 90 % interval of that median difference
    wilcoxon_p_vs_random: float | None
    verdict: str  # the study's verdict in words
    recommended: str | None  # the arm the study supports (None: none by its pass rule)
    beat_random: list | None = None  # arms that beat random (p < 0.05); None: a file written before it was kept
    best: str | None = None  # the arm of the lowest median flow-curve error


# what a user does to follow an arm of the outcome study
ARM_ADVICE = {**{arm: f"virheo design --criterion {arm}" for arm in OUTCOME_ARMS.values()},
              "largest": f"film {LARGEST} mm", "random": "any setup in the range", "repeat": "film setup 1 again"}


def outcome(name: str, path=OUTCOME_FILE) -> dict | None:
    """The shipped outcome study's figures for the criterion ``name`` (:data:`OUTCOME_ARMS`), or None."""
    arm = OUTCOME_ARMS.get(name)
    if arm is None or not Path(path).is_file():
        return None
    summary = read_json(path)["summary"]
    arms = summary.get("arms", {})
    if arm not in arms:
        return None
    mine, rnd = arms[arm], arms.get("random")
    vs = mine.get("against", {}).get("random") or {}
    return OutcomeValidation(arm, int(summary["materials"]), float(mine["median_flow_error"]),
                             None if rnd is None else float(rnd["median_flow_error"]), vs.get("median_difference"),
                             vs.get("interval"), vs.get("wilcoxon_p"), summary["verdict"],
                             summary.get("recommended"), summary.get("beat_random"), summary.get("best")).to_dict()


def outcome_line(o: dict) -> str:
    """The outcome study's figures of one arm, in words."""
    line = (f"reliability by estimation outcome (virheo study design-outcome, {o['materials']} materials, footage of a "
            f"finer model): median flow-curve error {o['median_flow_error']:.3f} (log10 stress RMS, 1-100 1/s)")
    if o["random_median_flow_error"] is not None and o["arm"] != "random":
        line += f" against a random setup's {o['random_median_flow_error']:.3f}"
        if o["wilcoxon_p_vs_random"] is not None:
            lo, hi = o["interval_vs_random"]
            line += (f" (median paired difference {o['median_difference_vs_random']:+.3f}, 90 % interval "
                     f"[{lo:+.3f}, {hi:+.3f}], Wilcoxon p = {o['wilcoxon_p_vs_random']:.2g})")
    line += f"; the study's verdict: {o['verdict']}"
    if o["recommended"] is None and o.get("beat_random"):
        line += (f"\n  weak: the study recommends no criterion ({', '.join(o['beat_random'])} beat a random second "
                 "setup without the lowest median error)")
    elif o["recommended"] is None:
        line += "\n  weak: no criterion beat a random second setup on the estimate it gave"
        if o.get("best") == o["arm"]:  # the pre-registered fallback: the arm of the lowest median error
            line += "; this criterion had the study's lowest median error, so the study recommends it"
        elif o.get("best"):
            line += (f"; the study's lowest median error was {o['best']}'s, so it recommends that "
                     f"({ARM_ADVICE.get(o['best'], o['best'])})")
    elif o["recommended"] != o["arm"]:
        line += f"\n  weak: the study supports {o['recommended']} instead"
    return line


def reliability_line(v: dict | None) -> str:
    """How reliable the criterion proved, for users (a second line says when it proved weak), or "not validated"."""
    if v is None:
        return ("reliability: not validated (virheo study design-information checked the information criterion with "
                "the demo preset's model, EIG with the published Theta map and perpendicularity with the published and "
                "the fitted one)")
    if v.get("outcome"):
        return outcome_line(v["outcome"])
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
