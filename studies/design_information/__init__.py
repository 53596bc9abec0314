"""Does the design pay off?  Each criterion's second setup against a seeded set of candidates, scored by the
information it realises in the simulator at the true material (:mod:`similarity.information`).

Materials: a scrambled Sobol design over 5..95 % of the normalised space with one random first setup each
(:func:`studies.calibration.design`, the cases of the calibration and design studies).  Per material:

1. **what a user knows after setup 1**: emulated footage of the first setup and a short stage-1 CMA-ES run on it
   (Algorithm 1, one stage, ``generations`` generations, the preset's model); its estimate, not the truth, is
   what every criterion sees;
2. **each criterion's pick** over the full 51 x 51 grid from that estimate: ``eig`` (expected information gain
   under stage 1's archive belief, published Theta map), ``perpendicularity-fitted`` and
   ``perpendicularity-reference`` (section 6 with our fitted and the published Theta map); ``information`` picks
   among its 16 setups (:func:`similarity.information.grid_setups`) by the simulated log det gain at the estimate
   (:func:`similarity.information.predicted_gains`), and predicts every candidate the same way; two baselines that
   `virheo design` does not offer: ``random`` and ``largest`` (the 70 x 70 mm box, predicting by the area W x H);
   a criterion that cannot rank (Theta's plane-Poiseuille model does not flow) takes the random pick, and the
   record says so;
3. **candidates**: ``candidates`` seeded random setups (distinct, other than the first) plus every pick;
4. **realised information** of each candidate at the true material on emulated footage of the preset's final
   model: the PSD-projected FD Hessians at the pinned step, gain = log det(H_1 + H_c + eps I) - log det(H_1 + eps I)
   (:func:`similarity.information.log_det_gain`), and the smallest-eigenvalue gain beside it;
5. **scores**: per criterion the normalised score (pick - mean of the seeded candidates) / (best candidate - that
   mean), and Spearman's rank correlation between the criterion's predicted information of the candidates and
   the realised gains (``random`` predicts nothing).

The first ``materials - held_out`` materials are the *selection* set: the recommended criterion is the one with
the largest median normalised score there, if positive (else none).  The last ``held_out`` materials are
reported apart: they decide the verdict.  Two further parts, optional (:mod:`studies.design_information.checks`): a
Fig. 10-style **map** of realised information over a coarse grid of setups for the first materials (``maps``),
and a **posterior check** (``posterior_check`` materials): for every candidate, the volume of an emcee posterior
(eq. 1 of :mod:`similarity.likelihood` on an emulated two-setup loss) against the realised gain.

The study runs on the skeleton of :mod:`studies.study`.  Every simulation goes through the store, every finished
material is kept in ``cases/case_XX/case.json``, every map and posterior check in its own JSON, so a killed study
resumes where it stopped.  Writes
``design_information.json``, ``design_information.md``, ``predicted_vs_realised.png``, ``maps.png`` and
``design_validation.json``: the held-out figures that `virheo design` prints, shipped as
``studies/data/design_validation.json`` (:mod:`studies.design_validation`).
"""
from __future__ import annotations

import time

import numpy as np

from mpm.files import write_json
from mpm.params import SETUP_RANGE_MM, Setup
from similarity import information as I
from similarity.progress import simulation_tick
from studies.design_information import checks
from studies.design_information.plots import plot_maps, plot_predicted
from studies.design_information.records import (CriterionScores, InformationRecord, InformationSummary, MeasureScores,
                                                StageOne, Verdict)
from studies.design_information.table import table_markdown
from studies.design_study import DesignCase, case_folder, case_seed
from studies.design_validation import DEFAULT_CRITERION, LARGEST, WITHIN, shipped_summary
from studies.study import Study, tell

# name -> (criterion of similarity.design.rank_setups, Theta map); the baselines "random" and "largest"
# (:data:`studies.design_validation.LARGEST`, other than the first) are not offered by `virheo design`
CRITERIA = {"eig": ("eig", "reference"), "perpendicularity-fitted": ("perpendicularity", "fitted"),
            "perpendicularity-reference": ("perpendicularity", "reference"), "information": ("information", None),
            "random": None, "largest": None}


def _config(materials, held_out, candidates, preset, generations, fd_step, seed, simulator) -> dict:
    from similarity.estimate import get_preset

    return {"materials": int(materials), "held_out": int(held_out), "candidates": int(candidates),
            "preset": get_preset(preset).name, "generations": int(generations), "fd_step": float(fd_step),
            "seed": int(seed), "simulator": simulator, "criteria": list(CRITERIA)}


def seeded_candidates(count: int, first: Setup, seed: int, index: int) -> list[Setup]:
    """``count`` distinct random setups of the 1 mm grid other than ``first``, seeded by (seed, index)."""
    lo, hi = SETUP_RANGE_MM
    rng = np.random.default_rng([int(seed), int(index), 7])
    out, seen = [], {str(first)}
    while len(out) < count:
        s = Setup(*(float(v) for v in rng.integers(int(lo), int(hi) + 1, size=2)))
        if str(s) not in seen:
            seen.add(str(s))
            out.append(s)
    return out


def _rank(name, estimate, first, covariance, thetas):
    """The ranking of criterion ``name`` (None for the baselines), or the reason it cannot rank."""
    from similarity.design import rank_setups

    how = CRITERIA[name]
    if how is None:
        return None, None
    criterion, theta = how
    try:
        return rank_setups(estimate, [first], theta=thetas[theta], criterion=criterion,
                           covariance=covariance if criterion == "eig" else None), None
    except ValueError as exc:
        return None, str(exc).splitlines()[0]


def _largest(first: Setup) -> Setup:
    """The baseline "largest": the 70 x 70 mm box, or 70 x 69 mm when that was the first."""
    return LARGEST if str(first) != str(LARGEST) else Setup(LARGEST.width_mm, LARGEST.height_mm - 1.0)


def _simulated(estimate, first, cands, *, config, preset, forward, tick):
    """The ``information`` criterion: (its pick, as `virheo design` makes it, predicted gain by setup name of its
    grid and of the other candidates, why it fell back)."""
    from similarity.simulated_design import rank_by_simulation

    try:
        ranking = rank_by_simulation(estimate, [first], preset=preset, forward=forward, fd_step=config["fd_step"],
                                     tick=tick)
        names = {str(g) for g in I.grid_setups()}
        extra = [c for c in cands if str(c) not in names]
        gains = (I.predicted_gains(estimate, [first], extra, preset=preset, fd_step=config["fd_step"],
                                   forward=forward, tick=tick) if extra else [])
    except ValueError as exc:
        return None, {}, str(exc).splitlines()[0]
    predicted = {str(Setup(float(w), float(h))): float(g)
                 for w, h, g in zip(ranking.width_mm, ranking.height_mm, ranking.score)}
    predicted.update({str(s): float(g) for s, g in zip(extra, gains) if np.isfinite(g)})
    return ranking.best()[0], predicted, None


def _predicted(ranking, setups, name: str = "") -> list:
    """The ranking's predicted information (higher = better) of each setup; None where it has none ("largest":
    the setup's area; "information": the ranking is the dict of predicted gains by setup name)."""
    if name == "largest":
        return [s.width_mm * s.height_mm for s in setups]
    if isinstance(ranking, dict):
        return [ranking.get(str(s)) for s in setups]
    if ranking is None:
        return [None] * len(setups)
    sign = 1.0 if ranking.higher_is_better else -1.0  # S_p: lower is better
    score = {(float(w), float(h)): sign * float(v)
             for w, h, v in zip(ranking.width_mm, ranking.height_mm, ranking.score)}
    return [score.get((s.width_mm, s.height_mm)) for s in setups]


def run_case(case: DesignCase, *, config: dict, forward, thetas, tick=None) -> InformationRecord:
    """One material (module docstring, steps 1 to 4)."""
    from similarity import estimate as E
    from similarity.belief import stage_belief
    from similarity.proposers import Random
    from similarity.space import e_rel

    index, truth, first = case.index, case.truth, case.first
    t0 = time.perf_counter()
    preset = E.get_preset(config["preset"])
    footage = E.emulate(truth, [first], preset=preset, forward=forward)[0]
    frames = int(len(footage.frames))
    est = E.estimate([footage], preset=preset, seed=case_seed(config["seed"], index), forward=forward,
                     generations=config["generations"], propose=None)
    try:
        covariance, belief_note = stage_belief(est.stages[0], frames).covariance, None
    except ValueError as exc:  # too few or degenerate evaluations: the plane-Poiseuille Laplace belief
        covariance, belief_note = None, str(exc).splitlines()[0]
    random_pick = Random([config["seed"], index])(est.material, [first])
    rankings, picks, fallbacks = {}, {}, {}
    for name in (n for n in config["criteria"] if n != "information"):
        rankings[name], why = _rank(name, est.material, first, covariance, thetas)
        picks[name] = (rankings[name].best()[0] if rankings[name] is not None
                       else _largest(first) if name == "largest" else random_pick)
        if why is not None:
            fallbacks[name] = why
    seeded = seeded_candidates(config["candidates"], first, config["seed"], index)
    cands = list(seeded)
    for s in picks.values():
        if str(s) not in {str(c) for c in cands}:
            cands.append(s)
    if "information" in config["criteria"]:
        pick, rankings["information"], why = _simulated(est.material, first, cands, config=config, preset=preset,
                                                         forward=forward, tick=tick)
        picks["information"] = pick if pick is not None else random_pick
        if why is not None:
            fallbacks["information"] = why
        if str(picks["information"]) not in {str(c) for c in cands}:
            cands.append(picks["information"])
    losses = I.stencil_losses(truth, [first] + cands, preset=preset, fd_step=config["fd_step"], forward=forward,
                              tick=tick)
    hessians = I.setup_hessians(losses, config["fd_step"])
    if hessians[0] is None:
        raise RuntimeError(f"material {index}: a simulation of the first setup's stencil failed")
    return InformationRecord(
        case=index, config=config, truth=truth, first_setup=str(first), frames_per_setup=frames,
        stage_1=StageOne(estimate=est.material, loss=est.loss, simulations=est.simulations,
                         e_rel=e_rel(truth, est.material), belief=belief_note or "archive"),
        candidates=[str(s) for s in cands], seeded=len(seeded), stencil_losses=losses.tolist(),
        hessian_first=hessians[0].tolist(), hessians=[None if h is None else h.tolist() for h in hessians[1:]],
        **{m: I.realised_gains(hessians[0], hessians[1:], m).tolist() for m in I.MEASURES},
        picks={k: str(v) for k, v in picks.items()}, fallbacks=fallbacks,
        predicted={k: _predicted(rankings[k], cands, k) for k in config["criteria"]},
        wall_seconds=time.perf_counter() - t0)


# -- summary ----------------------------------------------------------------------------------------------------
def _group(recs: list[InformationRecord], names, measure) -> dict[str, CriterionScores]:
    per = {}
    for name in names:
        sc = [r.scores(measure)[name] for r in recs]
        s = np.array([v.score for v in sc])
        rho = np.array([v.spearman for v in sc])
        wins, decided, p = I.sign_test(s)
        per[name] = CriterionScores(
            scores=s.tolist(), median_score=float(np.nanmedian(s)) if np.isfinite(s).any() else None,
            beats_mean=wins, decided=decided, sign_test_p=p, within=int(np.sum(s >= 1.0 - WITHIN)),
            materials=len(recs), spearman=rho.tolist(),
            median_spearman=float(np.nanmedian(rho)) if np.isfinite(rho).any() else None,
            median_gain=float(np.median([v.gain for v in sc])))
    return per


def _verdict(name: str, v: CriterionScores) -> Verdict:
    return Verdict(criterion=name, beats_mean=f"{v.beats_mean}/{v.materials}", sign_test_p=v.sign_test_p,
                   median_score=v.median_score, median_spearman=v.median_spearman,
                   met=bool(v.beats_mean > v.materials / 2 and v.sign_test_p < 0.05
                            and v.median_score is not None and v.median_score >= 0.8),
                   spearman_met=bool(v.median_spearman is not None and v.median_spearman >= 0.6))


def summary(recs: list[InformationRecord]) -> InformationSummary:
    """Selection and held-out scores per criterion and measure, the recommended criterion, and the verdicts of the
    default and the recommended criterion on the held-out materials (the issue's acceptance)."""
    if not recs:
        raise ValueError("no finished materials to summarise")
    cfg = recs[0].config
    n_sel = cfg["materials"] - cfg["held_out"]  # records come in material order: selection first
    sel, held = recs[:n_sel], recs[n_sel:]
    names = list(cfg["criteria"])
    measures = {m: MeasureScores(selection=_group(sel, names, m) if sel else {},
                                 held_out=_group(held, names, m) if held else {}) for m in I.MEASURES}
    recommended = None  # unless a criterion's median score on the selection materials is positive
    if sel:
        med = {n: measures["gain"].selection[n].median_score for n in names if CRITERIA[n] is not None}
        best = max(med, key=lambda n: -np.inf if med[n] is None else med[n])
        if med[best] is not None and med[best] > 0:
            recommended = best
    verdicts = {}
    if held:
        # a run from before the simulated criterion judged the default of its time, the paper's criterion
        default = DEFAULT_CRITERION if DEFAULT_CRITERION in names else "perpendicularity-reference"
        for key, name in (("default", default), ("recommended", recommended)):
            if name is not None:
                verdicts[f"verdict_{key}"] = _verdict(name, measures["gain"].held_out[name])
    seeded = [float(np.nanmedian(r.realised()[:r.seeded])) for r in held]
    return InformationSummary(materials=len(recs), selection=len(sel), held_out=len(held), **measures,
                              median_gain_seeded=float(np.median(seeded)) if held else None,
                              recommended=recommended, **verdicts)


# -- the study --------------------------------------------------------------------------------------------------
def check_options(materials: int = 30, held_out: int = 10, candidates: int = 8, preset="demo", generations: int = 20,
                  fd_step: float = I.STEP, seed: int = 0, maps: int = 2, map_steps: int = 6,
                  posterior_check: int = 3) -> None:
    """One-line ValueError for options :func:`run_study` cannot work with (named as the command line names them)."""
    from similarity.estimate import get_preset

    get_preset(preset)
    for name, value, least in (("materials", materials, 1), ("held_out", held_out, 0), ("candidates", candidates, 2),
                               ("generations", generations, 1), ("maps", maps, 0), ("map_steps", map_steps, 2),
                               ("posterior_check", posterior_check, 0)):
        if value < least:
            raise ValueError(f"--{name.replace('_', '-')} {value} must be >= {least}")
    if held_out >= materials:
        raise ValueError(f"--held-out {held_out} must be smaller than --materials {materials} (some materials select)")
    if not 0 < fd_step < 0.05 + 1e-12:
        raise ValueError(f"--fd-step {fd_step} must lie in (0, 0.05]: the materials keep 0.05 off the space's faces")


def run_study(out, *, materials: int = 30, held_out: int = 10, candidates: int = 8, preset="demo",
              generations: int = 20, fd_step: float = I.STEP, seed: int = 0, maps: int = 2, map_steps: int = 6,
              posterior_check: int = 3, forward, progress=None) -> dict:
    """Run (or resume) the study (module docstring) and write its outputs; ``forward`` simulates.  Returns what
    design_information.json holds."""
    from surrogate.theta import load

    check_options(materials, held_out, candidates, preset, generations, fd_step, seed, maps, map_steps, posterior_check)
    if forward.store is None:
        raise ValueError("the design-information study needs a simulation store")
    config = _config(materials, held_out, candidates, preset, generations, fd_step, seed, forward.simulator)
    study = InformationStudy(out, config, thetas={t: load(t) for t in ("reference", "fitted")}, maps=maps,
                             map_steps=map_steps, posterior_check=posterior_check)
    return study.run(forward=forward, progress=progress)


def records(out) -> list[InformationRecord]:
    """Every finished material under ``out``, in material order."""
    return InformationStudy(out).records()


def _ticker(progress):
    """The store's per-simulation callback that reports to ``progress``; None without one."""
    return simulation_tick(progress)


class InformationStudy(Study):
    """The design-information study on the skeleton of :mod:`studies.study`."""

    name = "design_information"
    record = InformationRecord

    def __init__(self, out, config: dict | None = None, *, thetas=None, maps: int = 0, map_steps: int = 6,
                 posterior_check: int = 0):
        super().__init__(out, config)
        self.thetas, self.maps, self.map_steps, self.posterior_check = thetas, maps, map_steps, posterior_check

    def cases(self):
        from studies.calibration import design

        for i, (truth, first) in enumerate(design(self.config["materials"], self.config["seed"])):
            yield DesignCase(i, truth, first, case_folder(self.out, i))

    def run_case(self, case, *, forward, progress=None):
        return run_case(case, config=self.config, forward=forward, thetas=self.thetas, tick=_ticker(progress))

    def announce(self, case) -> str:
        t = case.truth
        return (f"material {case.index + 1}/{self.config['materials']}: eta={t.eta:.3g} n={t.n:.3g} "
                f"sigma_y={t.sigma_y:.3g}, first setup {case.first}")

    def report(self, rec) -> str:
        return "  scores: " + ", ".join(f"{k} {v.score:.2f} ({v.pick})" for k, v in rec.scores().items())

    def after_cases(self, recs, *, forward, progress=None) -> None:
        """The information maps and the posterior checks (:mod:`studies.design_information.checks`)."""
        for rec in recs[:self.maps]:
            tell(progress, f"information map of material {rec.case} ({self.map_steps} x {self.map_steps} setups)")
            checks.information_map(self.out, rec, steps=self.map_steps, forward=forward, tick=_ticker(progress))
        for rec in recs[:self.posterior_check]:
            tell(progress, f"posterior check of material {rec.case} ({len(rec.candidates)} candidates)")
            checks.posterior_volume(self.out, rec, forward=forward)

    def summary(self, recs) -> InformationSummary:
        return summary(recs)

    def table(self, recs, summ) -> str:
        return table_markdown(recs, summ, checks.finished_checks(self.out))

    def plots(self, recs, summ) -> None:
        plot_predicted(self.out / "predicted_vs_realised.png", recs)
        maps = checks.finished_maps(self.out)
        if maps:
            plot_maps(self.out / "maps.png", maps, recs)

    def result(self, recs, summ, wall_seconds) -> dict:
        shipped = shipped_summary(summ, recs[0].config) if summ.held_out else None
        done = checks.finished_checks(self.out)
        for c in done:
            c.spearman = checks.volume_agreement(c, recs[c.case])
        return {"config": recs[0].config, "summary": summ.to_dict(),
                "shipped": None if shipped is None else shipped.to_dict(),
                "posterior_check": [c.to_dict() for c in done], "wall_seconds": wall_seconds,
                "cases": [r.to_dict() for r in recs]}

    def write(self, *, wall_seconds: float | None = None) -> dict:
        """The outputs of :class:`studies.study.Study` and ``design_validation.json`` (the shipped held-out figures,
        ``studies/data/design_validation.json`` of the documented run) when some materials are held out."""
        result = super().write(wall_seconds=wall_seconds)
        if result["shipped"]:
            write_json(self.out / "design_validation.json", result["shipped"])
        return result
