"""Calibration of the laws' verdicts on emulated footage: is "sigma_y > 0" (or "n = 1") right when it is resolved?

Materials (``design``, seeded): 4 power-law materials (sigma_y = 0 exactly), 4 Bingham (n = 1 exactly), 2
Newtonian and 8 Herschel-Bulkley, two of those with a small yield stress (0.5-2 Pa) and two with n near 1
(0.9-0.97); eta log-uniform over 0.3-5 Pa s^n, n over 0.35-0.85, sigma_y over 3-20 Pa where free; setup 1 a
random 1 mm-grid setup.  Per case:

1. footage of setup 1 simulated by the footage model (finer than the estimating one: the model misfit is real);
2. a one-setup estimate (Algorithm 1, the preset's model);
3. the second setup that ``virheo design`` proposes at that estimate (its default criterion), and its footage;
4. the two-setup estimate, then the posterior and the laws' evidence exactly as ``virheo report`` computes them
   (:func:`similarity.posterior.analyse`).

Outcomes per question (yield stress, shear thinning): among the cases with |ln BF| >= ln 10 the share whose
verdict is right (target >= 90 %), the cases decisively wrong (|ln BF| >= ln 100 against the truth; target none)
and the cases left unresolved per true law.  Resumable case by case (:mod:`studies.study`), run one of each true law
in turn (:func:`interleaved`).  Writes
``laws.json``, ``laws.md`` and ``laws.png``.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mpm.files import JsonRecord
from mpm.forward import ForwardModel
from mpm.params import DEFAULT_DENSITY_KG_M3 as DENSITY
from mpm.params import Material, Setup
from similarity.evidence import JEFFREYS, QUESTIONS, RESOLVED
from similarity.space import e_rel
from studies.report import save_figure, write_json
from studies.study import Study

DECISIVE = JEFFREYS[0][0]  # ln 100
TRUE_LAWS = ("power-law",) * 4 + ("bingham",) * 4 + ("newtonian",) * 2 + ("herschel-bulkley",) * 8
FOOTAGE_MODEL = ForwardModel(cell_mm=1.26, ppc=2)  # the footage: the paper's discretisation
QUICK_LAWS = ("power-law", "herschel-bulkley")


# -- design --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class LawCase:
    index: int
    law: str  # the true law
    truth: Material
    setup: Setup  # setup 1
    folder: Path


def design(laws=TRUE_LAWS, seed: int = 0) -> list[tuple[str, Material, Setup]]:
    """(true law, material, setup 1) per case, drawn from ``seed`` (module docstring)."""
    from studies.sampling import random_setups

    out, hb = [], 0
    for i, law in enumerate(laws):
        rng = np.random.default_rng([seed, i])
        eta, n, sigma_y = 10 ** rng.uniform(np.log10(0.3), np.log10(5.0)), rng.uniform(0.35, 0.85), rng.uniform(3, 20)
        if law == "herschel-bulkley":
            if hb < 2:
                sigma_y = rng.uniform(0.5, 2.0)  # near the power law's face
            elif hb < 4:
                n = rng.uniform(0.9, 0.97)  # near Bingham's face
            hb += 1
        if law in ("bingham", "newtonian"):
            n = 1.0
        if law in ("power-law", "newtonian"):
            sigma_y = 0.0
        out.append((law, Material(float(eta), float(n), float(sigma_y)), random_setups(1, rng, replace=True)[0]))
    return out


def interleaved(laws) -> list[int]:
    """The cases' indices in the order they run: one of each true law in turn (in the order the laws first appear),
    so that a round stopped partway has scored every law.  The order changes no case's result."""
    by_law: dict[str, list[int]] = {}
    for i, law in enumerate(laws):
        by_law.setdefault(law, []).append(i)
    queues = list(by_law.values())
    return [q[k] for k in range(max(map(len, queues))) for q in queues if k < len(q)]


def holds(question, truth: Material) -> bool:
    """Whether the true material has the question's property (a yield stress; shear thinning)."""
    return truth.sigma_y > 0 if question.name == "yield stress" else truth.n < 1


# -- one case ------------------------------------------------------------------------------------------
@dataclass
class LawRecord(JsonRecord):
    """One finished case: the truth, the setups, the two-setup estimate and the laws' evidence."""

    case: int
    config: dict
    law: str
    truth: Material
    setups: list  # "WxH"
    estimate: Material
    e_rel: float
    evidence: dict  # similarity.evidence.EvidenceSummary's JSON
    wall_seconds: dict  # footage, stage 1, design, estimate, posterior, total
    simulations_run: int | None
    # the emulator against the simulator where the evidence came from: "posterior" (the Herschel-Bulkley posterior's
    # draws) and "laws" (the special laws' on their faces), each PosteriorCheck's JSON or None (not checked)
    checks: dict | None = None

    READERS = {"truth": lambda d: Material(**d), "estimate": lambda d: Material(**d)}

    def verdict(self, question: str) -> dict | None:
        return next((v for v in self.evidence["verdicts"] if v["question"] == question), None)

    @property
    def trusted(self) -> bool | None:
        """Every check of the emulator passed (None: the record keeps no checks)."""
        if self.checks is None:
            return None
        return all(c is None or c["passed"] for c in self.checks.values())


def _film(truth, setup, folder, config, forward):
    from similarity.emulation import film
    from similarity.presets import filming

    model = ForwardModel(**config["footage_model"])
    return film(truth, setup, folder, density=DENSITY, forward=forward,
                preset=filming(config["preset"], model, name=f"footage-{model.cell_mm:g}mm"))


def run_case(case: LawCase, *, config: dict, forward, progress=None) -> LawRecord:
    """Footage, stage-1 estimate, designed second setup, two-setup estimate and the laws' evidence of one case."""
    from similarity import estimate as E
    from similarity.simulated_design import SIMULATION_PRESET, rank_by_simulation
    from similarity.posterior import analyse

    folder, truth = Path(case.folder), case.truth
    ran = forward.simulations_run
    seed = config["seed"] + case.index
    clock = {"start": time.perf_counter()}
    first = _film(truth, case.setup, folder, config, forward)
    clock["footage"] = time.perf_counter()
    stage1 = E.estimate([first], preset=config["preset"], seed=seed, forward=forward,
                        generations=config["generations"], progress=progress, propose=None)
    clock["stage 1"] = time.perf_counter()
    second, _ = rank_by_simulation(stage1.material, [case.setup], preset=SIMULATION_PRESET, forward=forward).best()
    clock["design"] = time.perf_counter()
    experiments = [first, _film(truth, second, folder, config, forward)]
    est = E.estimate(experiments, preset=config["preset"], seed=seed, forward=forward,
                     generations=config["generations"], progress=progress, propose=None)
    clock["estimate"] = time.perf_counter()
    write_json(folder / "result.json", est.to_dict() | {
        "folders": [str(Path(e.path).resolve()) for e in experiments], "simulator": config["simulator"],
        "truth": truth.to_dict(), "e_rel": e_rel(truth, est.material)})
    a = analyse(folder, forward=forward, new_simulations=config["new_simulations"], half_width=config["half_width"],
                seed=seed, min_ess=config["min_ess"], progress=progress)
    clock["posterior"] = time.perf_counter()
    steps = list(clock)
    wall = {b: clock[b] - clock[a_] for a_, b in zip(steps, steps[1:])}
    wall["total"] = clock["posterior"] - clock["start"]
    return LawRecord(case=case.index, config=config, law=case.law, truth=truth,
                     setups=[str(case.setup), str(second)], estimate=est.material, e_rel=e_rel(truth, est.material),
                     evidence=a.summary.evidence.to_dict(), wall_seconds=wall,
                     simulations_run=forward.simulations_run - ran,
                     checks={name: None if c is None else c.to_dict()
                             for name, c in (("posterior", a.summary.emulator.check),
                                             ("laws", a.summary.emulator.laws_check))})


# -- the study --------------------------------------------------------------------------------------------
@dataclass
class QuestionSummary(JsonRecord):
    """How one question's verdicts did against the truth."""

    question: str
    cases: int
    resolved: int  # |ln BF| >= ln 10
    right: int  # of those, the verdict matches the truth
    right_share: float | None  # right / resolved (None: none resolved)
    decisively_wrong: int  # |ln BF| >= ln 100 against the truth
    unresolved_by_law: dict  # true law -> cases left unresolved
    passed: bool  # right_share >= 0.9 and decisively_wrong == 0


@dataclass
class LawSummary(JsonRecord):
    questions: list  # QuestionSummary
    most_probable_right: int  # cases whose most probable law is the true one
    cases: int
    untrusted: int = 0  # cases whose evidence came from an emulator that failed a check (scored like the others)


def summarise(recs: list[LawRecord]) -> LawSummary:
    qs = []
    for q in QUESTIONS:
        rows = [(r, r.verdict(q.name)) for r in recs if r.verdict(q.name) is not None]
        resolved = [(r, v) for r, v in rows if abs(v["log_bf"]) >= RESOLVED]
        right = sum((v["log_bf"] > 0) == holds(q, r.truth) for r, v in resolved)
        wrong = sum(abs(v["log_bf"]) >= DECISIVE and (v["log_bf"] > 0) != holds(q, r.truth) for r, v in rows)
        unresolved = {}
        for r, v in rows:
            if abs(v["log_bf"]) < RESOLVED:
                unresolved[r.law] = unresolved.get(r.law, 0) + 1
        share = right / len(resolved) if resolved else None
        qs.append(QuestionSummary(question=q.name, cases=len(rows), resolved=len(resolved), right=int(right),
                                  right_share=share, decisively_wrong=int(wrong), unresolved_by_law=unresolved,
                                  passed=bool(share is not None and share >= 0.9 and wrong == 0)))
    best = sum(max(r.evidence["probabilities"], key=r.evidence["probabilities"].get) == r.law for r in recs)
    return LawSummary(questions=qs, most_probable_right=int(best), cases=len(recs),
                      untrusted=sum(r.trusted is False for r in recs))


def run_study(out, *, quick: bool = False, preset: str | None = None, generations: int | None = None,
              new_simulations: int = 12, seed: int = 0, min_ess: float = 1000.0, forward, progress=None) -> dict:
    """Run (or resume) the cases and write the outputs; ``quick``: 2 materials on coarse models (the machinery's
    test).  Returns what laws.json holds."""
    from similarity.presets import get_preset

    p = get_preset(preset or ("demo" if quick else "survey"))
    footage = ForwardModel(cell_mm=2.5, ppc=1) if quick else FOOTAGE_MODEL
    config = {"preset": p.name, "generations": int(generations or p.generations), "new_simulations": int(new_simulations),
              "seed": int(seed), "min_ess": float(min_ess), "simulator": forward.simulator,
              "footage_model": {"cell_mm": footage.cell_mm, "ppc": footage.ppc}, "quick": bool(quick),
              "half_width": 0.5 if quick else 0.1}  # the emulator's first box: the report's default, wider when quick
    return LawStudy(out, config).run(forward=forward, progress=progress)


CHECK_WORDS = {None: "not kept", True: "passed", False: "FAILED"}  # LawRecord.trusted in the table


class LawStudy(Study):
    name = "laws"
    record = LawRecord

    def cases(self):
        laws = QUICK_LAWS if self.config["quick"] else TRUE_LAWS
        planned = design(laws, self.config["seed"])
        for i in interleaved(laws):
            law, truth, setup = planned[i]
            yield LawCase(i, law, truth, setup, self.out / "cases" / f"case_{i:02d}")

    def run_case(self, case, *, forward, progress=None):
        return run_case(case, config=self.config, forward=forward, progress=progress)

    def announce(self, case) -> str:
        t = case.truth
        return f"case {case.index + 1} ({case.law}): eta={t.eta:.3g} n={t.n:.3g} sigma_y={t.sigma_y:.3g}, setup {case.setup}"

    def report(self, rec) -> str:
        return "  " + "; ".join(v["text"] for v in rec.evidence["verdicts"])

    def summary(self, recs):
        return summarise(recs)

    def table(self, recs, summ: LawSummary) -> str:
        lines = ["| case | true law | truth (eta, n, sigma_y) | setups | estimate | E_rel | ln BF yield stress | "
                 "ln BF shear thinning | most probable law | emulator checks | wall [s] |",
                 "|---:|---|---|---|---|---:|---:|---:|---|---|---:|"]
        for r in recs:
            t, e = r.truth, r.estimate
            cells = []
            for q in QUESTIONS:
                v = r.verdict(q.name)
                mark = ("–" if abs(v["log_bf"]) < RESOLVED else "right" if (v["log_bf"] > 0) == holds(q, t) else "WRONG")
                cells.append(f"{v['log_bf']:+.2f} ± {v['log_bf_err']:.2f} ({mark})")
            best = max(r.evidence["probabilities"], key=r.evidence["probabilities"].get)
            lines.append(f"| {r.case} | {r.law} | {t.eta:.3g}, {t.n:.3g}, {t.sigma_y:.3g} | {' + '.join(r.setups)} | "
                         f"{e.eta:.3g}, {e.n:.3g}, {e.sigma_y:.3g} | {r.e_rel:.3f} | {cells[0]} | {cells[1]} | {best} | "
                         f"{CHECK_WORDS[r.trusted]} | "
                         f"{r.wall_seconds['total']:.0f} |")
        lines += ["", "| question | cases | resolved (\\|ln BF\\| >= ln 10) | right among them | decisively wrong | "
                  "unresolved, by true law | target met |", "|---|---:|---:|---:|---:|---|---|"]
        for q in summ.questions:
            share = "–" if q.right_share is None else f"{q.right}/{q.resolved} ({100 * q.right_share:.0f} %)"
            un = ", ".join(f"{k} {v}" for k, v in sorted(q.unresolved_by_law.items())) or "none"
            lines.append(f"| {q.question} | {q.cases} | {q.resolved} | {share} | {q.decisively_wrong} | {un} | "
                         f"{'yes' if q.passed else 'no'} |")
        lines.append(f"\nMost probable law the true one in {summ.most_probable_right}/{summ.cases} cases. Cases whose "
                     f"evidence came from an emulator that failed a check: {summ.untrusted} (scored like the others).")
        return "\n".join(lines) + "\n"

    def plots(self, recs, summ) -> None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(1, 2, figsize=(8, 3.4), dpi=100)
        for ax, q, key in zip(axes, QUESTIONS, ("sigma_y", "n")):
            x = [getattr(r.truth, key) for r in recs]
            y = [r.verdict(q.name)["log_bf"] for r in recs]
            err = [r.verdict(q.name)["log_bf_err"] for r in recs]
            ax.errorbar(x, y, yerr=err, fmt="o", ms=4)
            for level in (RESOLVED, -RESOLVED):
                ax.axhline(level, color="0.6", lw=0.8, ls="--")
            ax.axhline(0, color="0.3", lw=0.6)
            ax.set_xlabel(f"true {key}", fontsize=8)
            ax.set_ylabel(f"ln BF, {q.yes} over {q.no}", fontsize=8)
            ax.set_title(q.name, fontsize=9)
        save_figure(fig, self.out / "laws.png")
