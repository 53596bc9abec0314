"""The files of `virheo study design-information` (:mod:`studies.design_information`) as typed records: a
material's ``case.json`` (:class:`InformationRecord`, with the scores of its picks) and the study's summary
(:class:`InformationSummary`, ``summary`` of ``design_information.json``)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mpm.files import JsonRecord
from mpm.params import Material
from similarity import information as I
from studies import design_study


@dataclass
class StageOne(design_study.StageOne):
    """Stage 1 of a material: what every criterion saw, and the belief EIG ranked under."""

    belief: str  # "archive" (stage 1's archive belief), else why the plane-Poiseuille Laplace belief was used


@dataclass(frozen=True)
class PickScore:
    """A criterion's pick in one material: its realised gain, normalised score and Spearman (predicted vs
    realised over the candidates; NaN for "random", which predicts nothing)."""

    pick: str
    gain: float
    score: float
    spearman: float


@dataclass
class InformationRecord(JsonRecord):
    """One finished material (``case.json``)."""

    case: int
    config: dict
    truth: Material
    first_setup: str
    frames_per_setup: int
    stage_1: StageOne
    candidates: list  # the seeded candidates (first ``seeded``), then the picks not among them
    seeded: int
    stencil_losses: list  # (1 + candidates, 18): the first setup's row, then the candidates'
    hessian_first: list  # (3, 3)
    hessians: list  # per candidate (3, 3), None where a simulation failed
    gain: list  # realised gain of each candidate by each of similarity.information.MEASURES
    gain_min_eig: list
    gain_shape: list
    picks: dict  # criterion -> setup
    fallbacks: dict  # criterion -> why it could not rank (it took the random pick)
    predicted: dict  # criterion -> predicted information of each candidate (None: ruled out or no prediction)
    wall_seconds: float

    READERS = {"truth": lambda d: Material(**d), "stage_1": StageOne.from_dict}

    def realised(self, measure: str = "gain") -> np.ndarray:
        """The realised gains of the candidates, recomputed from the stored Hessians."""
        return I.realised_gains(self.hessian_first, [None if h is None else np.array(h) for h in self.hessians],
                                measure)

    def scores(self, measure: str = "gain") -> dict[str, PickScore]:
        """Per criterion: the pick's realised gain, its normalised score, and Spearman (predicted vs realised)."""
        realised = self.realised(measure)
        best = float(np.nanmax(realised))
        out = {}
        for name, pick in self.picks.items():
            g = float(realised[self.candidates.index(pick)])
            pred = self.predicted[name]
            rho = (I.rank_agreement(I.last_where_ruled_out(pred), realised) if any(p is not None for p in pred)
                   else float("nan"))
            out[name] = PickScore(pick, g, I.normalised_score(g, realised[:self.seeded], best), rho)
        return out


@dataclass
class CriterionScores(JsonRecord):
    """One criterion's scores over a set of materials, by one measure."""

    scores: list  # normalised score per material
    median_score: float | None
    beats_mean: int  # materials where the pick beat the seeded candidates' mean
    decided: int  # materials with a decision (finite, non-zero score)
    sign_test_p: float | None  # one-sided
    within: int  # materials within WITHIN of the best candidate
    materials: int
    spearman: list  # per material
    median_spearman: float | None
    median_gain: float


def _per_criterion(d: dict) -> dict:
    return {name: CriterionScores.from_dict(v) for name, v in d.items()}


@dataclass
class MeasureScores(JsonRecord):
    """Per criterion, on the selection and on the held-out materials (empty where there are none)."""

    selection: dict  # criterion -> CriterionScores
    held_out: dict

    READERS = {"selection": _per_criterion, "held_out": _per_criterion}


@dataclass
class Verdict(JsonRecord):
    """A criterion on the held-out materials against the issue's targets."""

    criterion: str
    beats_mean: str  # "wins/materials"
    sign_test_p: float | None
    median_score: float | None
    median_spearman: float | None
    met: bool  # a majority beats the mean at p < 0.05 and the median score is >= 0.8
    spearman_met: bool  # median Spearman >= 0.6


@dataclass
class InformationSummary(JsonRecord):
    materials: int
    selection: int  # materials in the selection set
    held_out: int
    gain: MeasureScores  # one field per measure of similarity.information.MEASURES
    gain_min_eig: MeasureScores
    gain_shape: MeasureScores
    median_gain_seeded: float | None  # median over the held-out materials of the seeded candidates' median gain
    recommended: str | None  # the criterion with the largest positive median score on the selection materials
    verdict_default: Verdict | None = None
    verdict_recommended: Verdict | None = None

    OMIT_IF_NONE = ("verdict_default", "verdict_recommended")
    READERS = {**{m: MeasureScores.from_dict for m in I.MEASURES},
               "verdict_default": Verdict.from_dict, "verdict_recommended": Verdict.from_dict}
