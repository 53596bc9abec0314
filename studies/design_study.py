"""Which second setup helps most? EIG vs perpendicularity vs random at equal simulation budget (emulated footage).

Cases: materials by a scrambled Sobol design over the normalised material space (5 %..95 % of each range)
and one random first setup each, exactly the cases of the calibration study (:func:`studies.calibration.design`).
Per case, two-setup ViRheometry (Algorithm 1, N = 2, :func:`similarity.estimate.emulate_virheometry`) runs
once per criterion of :mod:`similarity.proposers`: the second setup is chosen by

* ``perpendicularity``: section 6, the loss normal most perpendicular to the first setup's;
* ``eig``: the largest expected information gain under the belief of stage 1's own CMA-ES evaluations
  (:mod:`similarity.belief`), so it costs no simulation beyond the paper's;
* ``random``: a uniformly random setup of the 1 mm grid (seeded per case).

Equal budget: the three runs of a case share the CMA-ES seed (case i: ``seed + 1000 i``), so stage 1 is the
same run (the store serves it once) and stage 2 costs the same number of simulations whatever the setup
(7 warm-start candidates re-scored, then G generations on both setups).  A criterion that cannot propose
(the plane-Poiseuille model of the stage-1 estimate does not flow in the first setup) takes the random
setup instead; the record says so.  When stage 1's archive cannot carry the belief's quadratic fit, ``eig``
uses the plane-Poiseuille Laplace belief of :func:`similarity.design.rank_setups` (recorded as
``without_belief``).

Every simulation goes through the store and every finished case is kept in ``case.json``, so a killed study
resumes where it stopped.  Writes ``design.json``, ``design.md`` and ``e_rel.png``.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mpm.files import JsonRecord
from mpm.params import DEFAULT_DENSITY_KG_M3 as DENSITY
from mpm.params import Material, Setup
from similarity.proposers import CRITERIA, Eig, Perpendicularity, Random
from similarity.space import e_rel
from studies.emulation import GOOD
from studies.report import save_figure
from studies.study import Study

PAIRS = (("eig", "perpendicularity"), ("perpendicularity", "random"), ("eig", "random"))
COLOURS = {"perpendicularity": "tab:blue", "eig": "tab:red", "random": "0.45"}
ORDERED = "eig >= perpendicularity > random"  # the summary's key: whether the good counts fall in this order


def case_seed(seed: int, index: int) -> int:
    """CMA-ES seed of case ``index`` (stage k uses this + k - 1), shared by the three criteria."""
    return int(seed) + 1000 * int(index)


class _Guarded:
    """A criterion's proposer that falls back to the case's random setup when it cannot propose."""

    def __init__(self, inner, fallback: Random):
        self.inner, self.fallback = inner, fallback
        self.fallbacks: dict[int, str] = {}  # setups done -> why

    def __call__(self, material, done, *, stage=None):
        try:
            if isinstance(self.inner, Eig):
                return self.inner(material, done, stage=stage)
            return self.inner(material, done)
        except ValueError as exc:
            self.fallbacks[len(done)] = str(exc).splitlines()[0]
            return self.fallback(material, done)


def proposer(name: str, *, seed: int, index: int, frames_per_setup: int, theta) -> _Guarded:
    """The proposer of criterion ``name`` for case ``index``."""
    rand = Random([seed, index])
    inner = {"perpendicularity": lambda: Perpendicularity(theta), "eig": lambda: Eig(frames_per_setup, theta),
             "random": lambda: rand}
    if name not in inner:
        raise ValueError(f"criterion '{name}' must be one of {', '.join(CRITERIA)}")
    return _Guarded(inner[name](), rand)


@dataclass
class StageOne(JsonRecord):
    """Stage 1 of a case (the same run for every criterion when ``stage_1_shared``)."""

    estimate: Material
    loss: float
    simulations: int
    e_rel: float

    READERS = {"estimate": lambda d: Material(**d)}


@dataclass
class CriterionRun(JsonRecord):
    """The two-setup run of one criterion."""

    second_setup: str | None
    estimate: Material
    e_rel: float
    loss: float
    simulations: int
    simulations_stage_2: int
    simulations_run: int | None
    fallback: str | None  # why the criterion could not propose (the random setup was taken), or None
    belief: dict | None  # stage 1's archive belief (eig), :class:`similarity.belief.Belief` as JSON
    without_belief: str | None
    wall_seconds: float

    READERS = {"estimate": lambda d: Material(**d)}


@dataclass
class DesignRecord(JsonRecord):
    """One finished case: its truth, first setup, stage 1 and one run per criterion."""

    case: int
    config: dict
    truth: Material
    first_setup: str
    frames_per_setup: int
    cma_seed: int
    stage_1: StageOne
    stage_1_shared: bool
    criteria: dict  # criterion -> CriterionRun
    wall_seconds: float

    READERS = {"truth": lambda d: Material(**d), "stage_1": StageOne.from_dict,
               "criteria": lambda d: {k: CriterionRun.from_dict(v) for k, v in d.items()}}


@dataclass
class CriterionSummary(JsonRecord):
    good: int  # cases with E_rel <= GOOD after two setups
    cases: int
    fraction_good: float | None
    median_e_rel: float | None
    simulations: list  # the distinct simulation counts of its runs
    fallbacks: int


@dataclass
class PairedSummary(JsonRecord):
    better: int  # cases where the first criterion's E_rel is lower
    equal: int
    worse: int
    same_second_setup: int


@dataclass
class DesignSummary(JsonRecord):
    cases: int
    good_threshold: float
    criteria: dict  # criterion -> CriterionSummary
    paired: dict  # "a vs b" -> PairedSummary
    eig_with_archive_belief: int
    stage_1_shared: int
    equal_budget: int
    ordered: bool | None = None  # eig >= perpendicularity > random in good cases (None: not all three ran)

    READERS = {"criteria": lambda d: {k: CriterionSummary.from_dict(v) for k, v in d.items()},
               "paired": lambda d: {k: PairedSummary.from_dict(v) for k, v in d.items()}}

    def to_dict(self) -> dict:
        d = super().to_dict()
        ordered = d.pop("ordered")
        return d if ordered is None else d | {ORDERED: ordered}

    @classmethod
    def from_dict(cls, data: dict) -> "DesignSummary":
        return super().from_dict(data | {"ordered": data.get(ORDERED)})


@dataclass(frozen=True)
class DesignCase:
    """A material and its first setup (:func:`studies.calibration.design`), and the folder of its case (also the
    cases of :mod:`studies.design_information`)."""

    index: int
    truth: Material
    first: Setup
    folder: Path


def _config(preset, generations, seed, simulator) -> dict:
    from similarity.estimate import get_preset

    p = get_preset(preset)
    return {"preset": p.name, "generations": int(generations or p.generations), "seed": int(seed),
            "simulator": simulator, "criteria": list(CRITERIA)}


def run_case(case: DesignCase, *, config: dict, forward, theta, progress=None) -> DesignRecord:
    """The three two-setup runs of one case."""
    from similarity import estimate as E

    index, truth, first = case.index, case.truth, case.first
    t0 = time.perf_counter()
    footage = E.emulate(truth, [first], density=DENSITY, preset=config["preset"], forward=forward)[0]
    frames = int(len(footage.frames))
    seed = case_seed(config["seed"], index)
    runs, stage_1 = {}, []
    for name in config["criteria"]:
        prop = proposer(name, seed=config["seed"], index=index, frames_per_setup=frames, theta=theta)
        before = forward.simulations_run
        t1 = time.perf_counter()
        est, _ = E.emulate_virheometry(truth, first, n_setups=2, preset=config["preset"], seed=seed, density=DENSITY,
                                       forward=forward, generations=config["generations"], progress=progress,
                                       propose=prop)
        s1 = est.stages[0]
        stage_1.append(StageOne(s1.material, s1.loss, s1.simulations, e_rel(truth, s1.material)))
        eig = prop.inner if isinstance(prop.inner, Eig) else None
        belief = eig.beliefs.get(1) if eig else None
        runs[name] = CriterionRun(
            second_setup=est.setups[1] if len(est.setups) > 1 else None, estimate=est.material,
            e_rel=e_rel(truth, est.material), loss=est.loss, simulations=est.simulations,
            simulations_stage_2=sum(s.simulations for s in est.stages[1:]), simulations_run=forward.simulations_run - before,
            fallback=prop.fallbacks.get(1), belief=None if belief is None else belief.to_dict(),
            without_belief=eig.without_belief.get(1) if eig else None, wall_seconds=time.perf_counter() - t1)
    return DesignRecord(case=index, config=config, truth=truth, first_setup=str(first), frames_per_setup=frames,
                        cma_seed=seed, stage_1=stage_1[0], stage_1_shared=all(s == stage_1[0] for s in stage_1),
                        criteria=runs, wall_seconds=time.perf_counter() - t0)


def case_folder(out, index: int) -> Path:
    return Path(out) / "cases" / f"case_{index:02d}"


def run_study(out, *, cases: int = 20, preset="demo", generations: int | None = None, seed: int = 0, forward,
              progress=None) -> dict:
    """Run (or resume) ``cases`` cases, case by case, and write the outputs; ``forward``
    (:class:`mpm.forward.Forward`) simulates.  Returns what design.json holds."""
    from surrogate.theta import load

    if forward.store is None:
        raise ValueError("the design study needs a simulation store (it shares stage 1 between the criteria)")
    config = _config(preset, generations, seed, forward.simulator)
    return DesignStudy(out, config, cases=cases, theta=load("reference")).run(forward=forward, progress=progress)


def records(out) -> list[DesignRecord]:
    """Every finished case under ``out``, in case order."""
    return DesignStudy(out).records()


class DesignStudy(Study):
    """The second-setup design study on the skeleton of :mod:`studies.study`."""

    name = "design"
    record = DesignRecord

    def __init__(self, out, config: dict | None = None, *, cases: int = 0, theta=None):
        super().__init__(out, config)
        self.n_cases, self.theta = int(cases), theta

    def cases(self):
        from studies.calibration import design

        for i, (truth, first) in enumerate(design(self.n_cases, self.config["seed"])):
            yield DesignCase(i, truth, first, case_folder(self.out, i))

    def run_case(self, case, *, forward, progress=None):
        return run_case(case, config=self.config, forward=forward, theta=self.theta, progress=progress)

    def announce(self, case) -> str:
        t = case.truth
        return (f"case {case.index + 1}/{self.n_cases}: eta={t.eta:.3g} n={t.n:.3g} sigma_y={t.sigma_y:.3g}, "
                f"first setup {case.first}")

    def report(self, rec) -> str:
        return "  E_rel after two setups: " + ", ".join(f"{k} {v.e_rel:.3f} ({v.second_setup})"
                                                          for k, v in rec.criteria.items())

    def summary(self, recs: list[DesignRecord]) -> DesignSummary:
        """Per criterion: cases with E_rel <= GOOD after two setups, median E_rel, budget; paired comparisons."""
        n = len(recs)
        crit = list(recs[0].config["criteria"]) if recs else list(CRITERIA)
        per = {}
        for c in crit:
            v = np.array([r.criteria[c].e_rel for r in recs])
            good = int(np.sum(v <= GOOD))
            per[c] = CriterionSummary(good=good, cases=n, fraction_good=good / n if n else None,
                                      median_e_rel=float(np.median(v)) if n else None,
                                      simulations=sorted({r.criteria[c].simulations for r in recs}),
                                      fallbacks=int(sum(r.criteria[c].fallback is not None for r in recs)))
        paired = {}
        for a, b in PAIRS:
            if a in crit and b in crit:
                d = np.array([r.criteria[a].e_rel - r.criteria[b].e_rel for r in recs])
                tie = np.abs(d) <= 1e-12
                paired[f"{a} vs {b}"] = PairedSummary(
                    better=int(np.sum((d < 0) & ~tie)), equal=int(np.sum(tie)), worse=int(np.sum((d > 0) & ~tie)),
                    same_second_setup=int(sum(r.criteria[a].second_setup == r.criteria[b].second_setup
                                              for r in recs)))
        ordered = None
        if all(c in per for c in ("eig", "perpendicularity", "random")):
            ordered = bool(per["eig"].good >= per["perpendicularity"].good > per["random"].good)
        return DesignSummary(
            cases=n, good_threshold=GOOD, criteria=per, paired=paired,
            eig_with_archive_belief=int(sum(r.criteria["eig"].belief is not None for r in recs
                                            if "eig" in r.criteria)),
            stage_1_shared=int(sum(bool(r.stage_1_shared) for r in recs)),
            equal_budget=int(sum(len({v.simulations for v in r.criteria.values()}) == 1 for r in recs)),
            ordered=ordered)

    def table(self, recs: list[DesignRecord], summ: DesignSummary) -> str:
        crit = list(summ.criteria)
        head = " | ".join(f"{c}: second setup, E_rel" for c in crit)
        lines = [f"| case | truth (eta, n, sigma_y) | first setup | E_rel after setup 1 | {head} |",
                 "|---:|---|---|---:|" + "---|" * len(crit)]
        for r in recs:
            t = r.truth
            cells = []
            for c in crit:
                v = r.criteria[c]
                mark = " (fallback: random)" if v.fallback else ""
                cells.append(f"{v.second_setup}, {v.e_rel:.3f}{mark}")
            lines.append(f"| {r.case} | {t.eta:.3g}, {t.n:.3g}, {t.sigma_y:.3g} | {r.first_setup} | "
                         f"{r.stage_1.e_rel:.3f} | " + " | ".join(cells) + " |")
        n = summ.cases
        lines += ["", f"| criterion | E_rel <= {GOOD} after two setups | median E_rel | simulations per run |",
                  "|---|---:|---:|---:|"]
        for c, v in summ.criteria.items():
            lines.append(f"| {c} | {v.good}/{n} ({100 * v.fraction_good:.0f} %) | {v.median_e_rel:.3f} | "
                         f"{', '.join(map(str, v.simulations))} |")
        lines += ["", "| pair | first better | equal | first worse | same second setup |", "|---|---:|---:|---:|---:|"]
        for k, v in summ.paired.items():
            lines.append(f"| {k} | {v.better} | {v.equal} | {v.worse} | {v.same_second_setup} |")
        lines += ["", f"Stage 1 shared by the criteria in {summ.stage_1_shared}/{n} cases; equal simulation budget "
                  f"in {summ.equal_budget}/{n}; EIG from stage 1's archive belief in "
                  f"{summ.eig_with_archive_belief}/{n}."]
        return "\n".join(lines) + "\n"

    def plots(self, recs: list[DesignRecord], summ: DesignSummary) -> None:
        plot_e_rel(self.out / "e_rel.png", recs, summ)


def plot_e_rel(path, recs: list[DesignRecord], summ: DesignSummary) -> Path:
    """E_rel after two setups per case and criterion (log scale), with the E_rel = GOOD line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    crit = list(summ.criteria)
    n = max(1, len(recs))
    fig, ax = plt.subplots(figsize=(max(4.0, 0.35 * n + 2.0), 3.4), dpi=100)
    x = np.arange(len(recs))
    for k, c in enumerate(crit):
        y = [max(r.criteria[c].e_rel, 1e-4) for r in recs]
        v = summ.criteria[c]
        ax.plot(x + (k - 1) * 0.18, y, "o", ms=5, color=COLOURS.get(c), label=f"{c} ({v.good}/{v.cases} good)")
    ax.plot(x, [max(r.stage_1.e_rel, 1e-4) for r in recs], "_", ms=10, color="k", label="after setup 1")
    ax.axhline(GOOD, color="grey", ls=":", lw=1)
    ax.set_yscale("log")
    ax.set_xticks(x)
    ax.set_xticklabels([str(r.case) for r in recs], fontsize=7)
    ax.set_xlabel("case", fontsize=8)
    ax.set_ylabel("E_rel after two setups", fontsize=8)
    ax.tick_params(labelsize=7)
    ax.legend(fontsize=7)
    return save_figure(fig, path)
