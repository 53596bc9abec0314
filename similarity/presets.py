"""Estimation presets: CMA-ES budget and forward models (:class:`mpm.forward.ForwardModel`).

A preset names what it is for: ``demo`` (emulated footage, about a minute on a laptop), ``footage`` (real
footage: Algorithm 1 in log(eta) on a cheap two-particle model, finished at the paper's discretisation on sticking
walls), ``footage-1p`` (the previous real-footage default: one particle per cell per axis, finished with slipping
walls) and ``paper`` (the paper's budget and discretisation).  Costs and accuracy: docs/performance.md; why these defaults: docs/decisions.md#presets.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

from mpm.forward import ForwardModel
from mpm.params import Setup

PAPER_SIGMA0 = 0.1  # stage-1 step size in [0, 1]^3: the paper's Sigma = 1 in a [0, 10]^3 box

VALIDATED = ForwardModel()  # the solver's default: converged against a 2x finer run on the shared footage
# the paper's discretisation, sticking walls: Table 1 fits the shared footage best under it (docs/validation.md)
PAPER_MODEL = ForwardModel(cell_mm=1.26, ppc=2)
# footage-1p: the validated one-particle cells with walls slipping by one global slip length, which corrects that
# model's thin-film bias toward the footage (docs/decisions.md#walls)
FOOTAGE_SLIP_LENGTH_M = 1e-3
FOOTAGE_1P_MODEL = replace(VALIDATED, slip_length_m=FOOTAGE_SLIP_LENGTH_M)


@dataclass(frozen=True)
class Preset:
    """CMA-ES budget and forward model of :func:`similarity.estimate.estimate`.

    Stage k of Algorithm 1 runs ``generations`` generations on the model (``cell_mm``, ``ppc``) with step
    ``sigma0 * (2/3)^(k-1)``.  With ``finish_generations`` > 0 a last stage fits all setups again on the
    ``finish`` discretisation, warm-started from the last stage, so the answer is at that fidelity.
    """

    name: str
    generations: int  # per stage (paper: 100)
    cell_mm: float | None  # search model; None: the solver's default
    ppc: int | None = None
    sigma0: float = PAPER_SIGMA0
    finish_generations: int = 0
    finish: ForwardModel = VALIDATED
    purpose: str = ""
    slip_length_m: float | None = None  # walls' Navier slip length in every stage; None: each stage's own
    density_correction: bool = False  # the solver's density correction in every stage
    search_space: str = "linear"  # CMA-ES coordinates (similarity.space.SEARCH_SPACES); linear: the paper's
    carry_covariance: bool = False  # the finishing stage starts with the last search stage's covariance shape

    @property
    def search(self) -> ForwardModel:
        """The forward model of Algorithm 1's stages."""
        return ForwardModel(self.cell_mm, self.ppc, self.slip_length_m, self.density_correction)

    @property
    def final(self) -> ForwardModel:
        """The forward model of the last stage, i.e. of the estimate's loss."""
        if self.finish_generations == 0:
            return self.search
        finish = self.finish if self.slip_length_m is None else replace(self.finish, slip_length_m=self.slip_length_m)
        return replace(finish, density_correction=finish.density_correction or self.density_correction)


PRESETS = {p.name: p for p in (
    Preset("demo", generations=65, cell_mm=5.0, ppc=1, sigma0=0.2,
           purpose="emulated footage (virheo demo, emulation studies): 5 mm cells, under a minute on 2 cores "
                   "with the native engine"),
    Preset("footage", generations=12, cell_mm=2.0, ppc=2, sigma0=0.2, finish_generations=6, finish=PAPER_MODEL,
           search_space="log-eta", carry_covariance=True,
           purpose="real footage: CMA-ES on log(eta), 2 mm cells with two particles per axis, then 6 generations at "
                   "the paper's 1.26 mm cells with two particles per axis, started with the last search stage's "
                   "covariance shape; sticking walls"),
    Preset("footage-1p", generations=12, cell_mm=3.0, ppc=1, sigma0=0.2, finish_generations=6,
           finish=FOOTAGE_1P_MODEL,
           purpose="real footage, one particle per axis: 3 mm cells on sticking walls, then 6 generations at the "
                   "validated 1.5 mm cells with walls slipping by 1 mm (biased on thin films; cheaper)"),
    Preset("survey", generations=12, cell_mm=2.5, ppc=2, sigma0=0.2, search_space="log-eta",
           purpose="real or emulated footage in minutes: CMA-ES on log(eta) at 2.5 mm cells with two particles per "
                   "axis, sticking walls, no finishing stage (the laws' verdicts on the shared footage and their "
                   "calibration, docs/uncertainty.md)"),
    Preset("paper", generations=100, cell_mm=PAPER_MODEL.cell_mm, ppc=PAPER_MODEL.ppc,
           purpose="publication: the paper's budget and discretisation (1.26 mm, 2 particles per cell per axis)"),
)}


def filming(preset, model: ForwardModel, name: str) -> Preset:
    """``preset`` with ``model`` as its one and final model (no finishing stage; its walls and density correction
    too): what films emulated footage, or simulates a run's own model."""
    return replace(get_preset(preset), name=name, cell_mm=model.cell_mm, ppc=model.ppc, finish_generations=0,
                   slip_length_m=model.slip_length_m, density_correction=bool(model.density_correction))


def get_preset(preset) -> Preset:
    if isinstance(preset, Preset):
        return preset
    try:
        return PRESETS[str(preset)]
    except KeyError:
        raise ValueError(f"unknown preset '{preset}': choose one of {', '.join(PRESETS)}") from None


def setup_of(experiment) -> Setup:
    return Setup(float(experiment.width_mm), float(experiment.height_mm))
