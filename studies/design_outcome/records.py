"""The records of the design outcome study: one arm's run, one case, the comparisons and the summary, a posterior
outcome (:mod:`studies.design_outcome`)."""
from __future__ import annotations

from dataclasses import dataclass, field

from mpm.files import JsonRecord
from mpm.params import Material


@dataclass
class ArmRun(JsonRecord):
    """One arm's two-setup estimate in one case."""

    arm: str  # "random_0", "random_1" for the random draws
    second_setup: str
    fallback: str | None  # why the criterion could not propose (the first random draw was taken), or None
    criterion_particle_steps: float  # the criterion's own simulations' work (particles x time steps)
    c_first: float  # particle-steps of one simulation of setup 1 at the estimation model, at stage 1's estimate
    c_second: float  # the same in the arm's setup
    draws: int  # stage 2's candidate draws (studies.design_outcome.stage_2_draws)
    stage_1_shared: bool  # its stage 1 is the case's stage 1 (served by the store)
    estimate: Material | None  # None: the arm has no estimate in this case (``failed`` says why)
    flow_error: float  # NaN without an estimate
    e_rel: float
    simulations: int
    wall_seconds: float
    failed: str | None = None  # why stage 2 could not run (every simulation failed, no work measured), or None

    READERS = {"estimate": lambda d: Material(**d)}  # JSON keeps NaN as null: verdict.per_material reads it


@dataclass
class OutcomeRecord(JsonRecord):
    """One finished case: a material and a CMA-ES seed, stage 1 and every arm."""

    config: dict
    material_index: int
    seed_index: int
    truth: Material
    first_setup: str
    stage_1: Material
    stage_1_flow_error: float
    stage_1_e_rel: float
    arms: list  # ArmRun
    wall_seconds: float

    READERS = {"truth": lambda d: Material(**d), "stage_1": lambda d: Material(**d),
               "arms": lambda d: [ArmRun.from_dict(a) for a in d]}


@dataclass
class Comparison(JsonRecord):
    """An arm against a reference arm over the materials (paired: arm minus reference, flow-curve error)."""

    reference: str
    materials: int
    median_difference: float | None
    interval: list | None  # bootstrap LEVEL interval of the median difference
    wilcoxon_p: float | None  # one-sided: the arm's error is lower


@dataclass
class ArmSummary(JsonRecord):
    median_flow_error: float
    median_e_rel: float
    per_material: list  # flow-curve error per material, averaged over seeds and draws
    against: dict  # reference -> Comparison
    fallbacks: int = 0  # runs whose criterion could not propose (the first random draw was taken)
    failed: int = 0  # runs without an estimate (left out of the averages)

    READERS = {"against": lambda d: {k: Comparison.from_dict(v) for k, v in d.items()}}


@dataclass
class OutcomeSummary(JsonRecord):
    materials: int
    cases: int
    arms: dict  # arm -> ArmSummary
    best: str | None  # the arm of the lowest median flow-curve error
    default_passes: bool | None
    recommended: str | None  # the arm the study supports (None: none by the pass rule)
    verdict: str
    beat_random: list = field(default_factory=list)  # arms (not random) whose flow-curve error beat random's, p < 0.05

    READERS = {"arms": lambda d: {k: ArmSummary.from_dict(v) for k, v in d.items()}}


@dataclass
class PosteriorOutcome(JsonRecord):
    """The posterior of one arm's two-setup run (`virheo report`'s analysis, default options)."""

    material_index: int
    arm: str
    setups: list
    estimate: Material
    band_width_10: float  # 95th over 5th percentile stress of the 90 % flow band at 10 1/s
    truth_inside_10: bool  # the true stress at 10 1/s lies within that band
    wall_seconds: float
    same_estimate: bool = True  # its estimate is the case's arm's (the store served the same run)

    READERS = {"estimate": lambda d: Material(**d)}
