"""Does the recommended second setup give a better estimate?  Each design arm's second setup judged by the two-setup
estimate it yields, on footage of a finer model, at equal simulation work (pre-registered in docs/uncertainty.md,
"Outcome study").

Per material (:func:`draw`: half runny, half thick pastes, each with a random first setup) and CMA-ES seed:

1. **footage** of setup 1, emulated with the footage model (default: 1.26 mm cells, two particles per axis,
   sticking walls), so that the estimating model does not share the footage's discretisation;
2. **stage 1**: Algorithm 1 on setup 1 at the preset's model (default ``survey``), shared by every arm;
3. **each arm's second setup** from stage 1's estimate (:data:`ARMS`): ``information`` (the default criterion at
   its own model), ``perpendicularity`` and ``eig`` (the published Theta map), ``largest`` (70x70 mm), ``random``
   (two draws per material, the same for every seed) and ``repeat`` (setup 1 again: the null);
4. **equal budget**: every arm gets ``budget_particle_steps`` of simulation work (particles x time steps, the same on
   every machine) after stage 1, the criterion's own simulations and stage 2's warm start included; stage 2 (both
   setups, warm-started from stage 1) gets the candidate draws that fit in the rest (:func:`stage_2_draws`), a
   partial last generation included;
5. **outcomes**: the flow-curve error against the truth over 1-100 1/s (:func:`similarity.space.flow_curve_error`,
   primary), E_rel, the CPU seconds spent; after every case, for :func:`posterior_materials` and seed 0, each arm's
   posterior (`virheo report`'s analysis of the two-setup run, filmed into ``posterior/mNN_ARM/``): the 90 % flow
   band's width at 10 1/s and whether the truth lies inside (``posterior/mNN_ARM.json``).

The summary (:func:`verdict`) averages each arm's flow-curve error per material over the seeds (and the random
draws), and tests each arm against ``random`` and ``perpendicularity`` (one-sided paired Wilcoxon signed-rank, and
the bootstrap 90 % interval of the median paired difference).  Every case is kept in ``cases/mNN_sK/case.json`` and
every simulation in the store: a killed study resumes where it stopped.  Writes ``design_outcome.json`` and
``design_outcome.md``.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mpm.model import ForwardModel
from mpm.params import DEFAULT_DENSITY_KG_M3 as DENSITY
from mpm.params import SETUP_RANGE_MM, Material, Setup
from similarity.space import e_rel, flow_curve_error
from studies.design_outcome.records import ArmRun, OutcomeRecord, PosteriorOutcome
from studies.design_outcome.verdict import ARMS, DEFAULT_ARM, compare, per_material, verdict  # noqa: F401
from studies.study import Study

RANDOM_DRAWS = 2
LARGEST = Setup(70.0, 70.0)
# the pre-registered draw: (eta range Pa s^n, log-uniform), n range, (sigma_y range Pa)
RUNNY = ((0.5, 10.0), (0.35, 0.95), (0.5, 5.0))
PASTE = ((5.0, 28.0), (0.35, 0.95), (15.0, 38.0))



def draw(count: int, seed: int) -> list[tuple[Material, Setup]]:
    """``count`` materials and first setups: the first half runny, the rest thick pastes; per material eta
    (log-uniform), n, sigma_y, then the setup's width and height on the 1 mm grid, from ``default_rng(seed)``."""
    rng = np.random.default_rng(int(seed))
    lo, hi = SETUP_RANGE_MM
    out = []
    for i in range(int(count)):
        (e0, e1), (n0, n1), (s0, s1) = RUNNY if i < count // 2 else PASTE
        eta = float(np.exp(rng.uniform(np.log(e0), np.log(e1))))
        n = float(rng.uniform(n0, n1))
        sy = float(rng.uniform(s0, s1))
        w, h = (float(v) for v in rng.integers(int(lo), int(hi) + 1, size=2))
        out.append((Material(eta, n, sy), Setup(w, h)))
    return out


def random_setups(seed: int, index: int, first: Setup) -> list[Setup]:
    """The ``random`` arm's draws for material ``index``: distinct, other than setup 1 (the same for every CMA-ES
    seed)."""
    from similarity.proposers import Random

    out = []
    for d in range(RANDOM_DRAWS):
        out.append(Random([int(seed), int(index), d])(None, [first, *out]))
    return out


BUDGET_PARTICLE_STEPS = 6.0e9  # each arm's work after stage 1 (pre-registered: 70x70 mm gets 3 generations, below)


def stage_2_draws(budget: float, criterion: float, c_first: float, c_second: float) -> int:
    """Candidate draws of stage 2 that fit in ``budget`` (particle-steps) after the criterion's simulations and the
    warm start (POPSIZE of stage 1's candidates simulated in the arm's setup), each draw simulating both setups (work
    ``c_first`` + ``c_second``); at least one generation."""
    from similarity.cma_stage import POPSIZE

    left = budget - criterion - POPSIZE * c_second
    per_draw = c_first + c_second
    if not (per_draw > 0 and math.isfinite(left)):
        raise ValueError(f"no measured work to budget with (setup 1: {c_first}, second setup: {c_second})")
    return max(POPSIZE, int(math.floor(left / per_draw)))


POSTERIORS = 4  # materials with a posterior outcome (pre-registered)


def posterior_materials(count: int, posteriors: int = POSTERIORS) -> list[int]:
    """The materials with a posterior outcome: the first half of ``posteriors`` among the runny materials, the rest
    among the pastes (0, 1, 4, 5 of 8 by default)."""
    half, runny = count // 2, (posteriors + 1) // 2
    return sorted({*range(min(runny, half)), *range(half, min(half + posteriors - runny, count))})


@dataclass(frozen=True)
class OutcomeCase:
    index: int
    seed_index: int
    truth: Material
    first: Setup
    folder: Path


class DesignOutcome(Study):
    name = "design_outcome"
    record = OutcomeRecord
    case_files = ("cases/m*_s*/case.json",)

    def __init__(self, out, config: dict | None = None, *, posteriors: int = POSTERIORS):
        super().__init__(out, config)
        self.n_posteriors = int(posteriors)

    def cases(self):
        c = self.config
        for i, (truth, first) in enumerate(draw(c["materials"], c["seed"])):
            for k in range(c["seeds"]):
                yield OutcomeCase(i, k, truth, first, self.out / "cases" / f"m{i:02d}_s{k}")

    def announce(self, case) -> str:
        return f"material {case.index} ({case.truth}), setup 1 {case.first}, seed {case.seed_index}"

    def report(self, record) -> str:
        return (f"material {record.material_index} seed {record.seed_index}: flow-curve error "
                + ", ".join(f"{a.arm} {a.flow_error:.3f}" for a in record.arms))

    def run_case(self, case, *, forward, progress=None):
        return run_case(case, self.config, forward=forward, progress=progress)

    def after_cases(self, records, *, forward, progress=None) -> None:
        """The posterior outcome of every arm of seed 0 for :func:`posterior_materials`, one file each.  Arms whose
        two-setup runs are the same (the same second setup, stage-2 draws and estimate: e.g. three arms that picked
        70x70 mm) share one analysis, which is deterministic; an arm without an estimate has none."""
        from dataclasses import replace

        from mpm.files import read_json, write_json
        from studies.study import tell

        for r in records:
            if r.seed_index != 0 or r.material_index not in posterior_materials(self.config["materials"],
                                                                                self.n_posteriors):
                continue
            done: dict = {}  # the same run -> its outcome
            for a in r.arms:
                if a.estimate is None:
                    continue
                path = self.out / "posterior" / f"m{r.material_index:02d}_{a.arm}.json"
                run = (a.second_setup, a.draws, tuple(a.estimate.as_array()))
                if path.is_file():
                    done.setdefault(run, PosteriorOutcome.from_dict(read_json(path)))
                    continue
                if run in done:
                    tell(progress, f"posterior: material {r.material_index}, {a.arm}: the run of {done[run].arm}")
                    write_json(path, replace(done[run], arm=a.arm, wall_seconds=0.0))
                    continue
                tell(progress, f"posterior: material {r.material_index}, {a.arm}")
                done[run] = posterior_outcome(r, a, self.config, self.out / "posterior" /
                                              f"m{r.material_index:02d}_{a.arm}", forward=forward)
                write_json(path, done[run])

    def posteriors(self) -> list[PosteriorOutcome]:
        from mpm.files import read_json

        return [PosteriorOutcome.from_dict(read_json(p)) for p in sorted((self.out / "posterior").glob("m*.json"))]

    def result(self, records, summary, wall_seconds):
        return super().result(records, summary, wall_seconds) | {
            "posterior": [p.to_dict() for p in self.posteriors()]}

    def summary(self, records):
        return verdict(records)

    def table(self, records, summary) -> str:
        lines = ["# Does the recommended second setup give a better estimate?", "",
                 f"{summary.materials} materials, {summary.cases} cases. Flow-curve error: RMS of log10 stress over "
                 "1-100 1/s against the truth, per material averaged over the seeds (and the random draws).", "",
                 "| arm | median flow-curve error | median E_rel | vs random: median difference [90 % interval], "
                 "Wilcoxon p | vs perpendicularity | runs with the first random draw (criterion failed) | runs without an "
                 "estimate |", "|---|---:|---:|---|---|---:|---:|"]
        for arm, s in summary.arms.items():
            cells = []
            for ref in ("random", "perpendicularity"):
                c = s.against.get(ref)
                cells.append("" if c is None or c.median_difference is None else
                             f"{c.median_difference:+.3f} [{c.interval[0]:+.3f}, {c.interval[1]:+.3f}], "
                             f"p = {c.wilcoxon_p:.3g}")
            lines.append(f"| {arm} | {s.median_flow_error:.3f} | {s.median_e_rel:.3f} | {cells[0]} | {cells[1]} | "
                         f"{s.fallbacks} | {s.failed} |")
        lines += ["", f"Verdict: {summary.verdict}.", ""]
        post = self.posteriors()
        if post:
            lines += ["Posterior of each arm's two-setup run (seed 0): the 90 % flow band's width at 10 1/s (95th over "
                      "5th percentile stress) and whether the true stress lies inside.", "",
                      "| arm | materials | median band width at 10 1/s | truth inside |", "|---|---:|---:|---:|"]
            for arm in ARMS:
                mine = [p for p in post if p.arm.split("_")[0] == arm]
                if mine:
                    lines.append(f"| {arm} | {len({p.material_index for p in mine})} | "
                                 f"{np.median([p.band_width_10 for p in mine]):.2f} | "
                                 f"{sum(p.truth_inside_10 for p in mine)}/{len(mine)} |")
            lines.append("")
        return "\n".join(lines)

    def plots(self, records, summary) -> None:
        return None


def _work(result) -> float:
    """Particle-steps of one simulation (ValueError when it failed: no work to budget with)."""
    steps = result.particle_steps if result.ok else None
    if steps is None:
        raise ValueError(f"a simulation at stage 1's estimate failed ({result.error or 'no work recorded'})")
    return steps


def run_case(case: OutcomeCase, config: dict, *, forward, progress=None) -> OutcomeRecord:
    """Stage 1 and every arm of one case."""
    from similarity.simulated_design import SIMULATION_PRESET, rank_by_simulation
    from similarity.emulation import emulate, film
    from similarity.estimate import estimate, get_preset
    from similarity.cma_stage import POPSIZE
    from similarity.information import SIMULATIONS_PER_SETUP
    from similarity.presets import filming
    from similarity.proposers import Eig, Perpendicularity

    t0 = time.perf_counter()
    preset = get_preset(config["preset"])
    footage_model = ForwardModel(*config["footage_model"])
    shoot = filming(preset, footage_model, "outcome-footage")
    shots: dict = {}

    def film_all(setups) -> None:
        """Footage of every setup not filmed yet, simulated in one batch (the workers share the footage model's long
        runs), then written as experiment folders and read back, as a user's footage is (the camera as its file
        gives it, so that the posterior outcome's run of the same folders finds every simulation in the store)."""
        todo = list({str(s): s for s in setups if str(s) not in shots}.values())
        if todo:
            emulate(case.truth, todo, density=DENSITY, preset=shoot, forward=forward)
            shots.update((str(s), film(case.truth, s, case.folder / "footage", preset=shoot, forward=forward,
                                       density=DENSITY)) for s in todo)

    def footage(setup: Setup):
        film_all([setup])
        return shots[str(setup)]

    randoms = random_setups(config["seed"], case.index, case.first)
    film_all([case.first, LARGEST, *randoms])  # the setups known before stage 1
    first = footage(case.first)
    g1 = config["stage_1_generations"]
    seed = int(case.seed_index)
    s1 = estimate([first], preset=preset, seed=seed, forward=forward, generations=g1, n_setups=1, propose=None,
                  progress=progress)
    m1 = s1.material

    def work_at(setup: Setup) -> float:
        return _work(forward.results(m1, [footage(setup)], preset.search)[0])

    picks: list[tuple[str, Setup, str | None, float]] = []  # arm, setup, fallback, criterion's particle-steps
    for arm in ARMS:
        fallback, cost = None, 0.0
        try:
            if arm == "information":
                ranking = rank_by_simulation(m1, [case.first], preset=config["criterion_preset"] or SIMULATION_PRESET,
                                             forward=forward)
                setup = ranking.best()[0]
                cost = SIMULATIONS_PER_SETUP * sum(f.particle_steps or 0.0 for f in ranking.facts.values())
            elif arm == "perpendicularity":
                setup = Perpendicularity("reference")(m1, [case.first])
            elif arm == "eig":
                setup = Eig(len(first.frames), "reference")(m1, [case.first], stage=s1.stages[0])
            elif arm == "largest":
                setup = LARGEST
            elif arm == "repeat":
                setup = case.first
            else:
                for d, r in enumerate(randoms):
                    picks.append((f"random_{d}", r, None, 0.0))
                continue
        except ValueError as exc:
            setup, fallback = randoms[0], str(exc).splitlines()[0]
        picks.append((arm, Setup(setup.width_mm, setup.height_mm), fallback, cost))

    film_all([setup for _, setup, _, _ in picks])
    c_first = work_at(case.first)
    runs = []
    for arm, setup, fallback, cost in picks:
        t1 = time.perf_counter()
        before = forward.simulations_run
        try:
            c_second = work_at(setup)
            draws = stage_2_draws(config["budget_particle_steps"], cost, c_first, c_second)
            est = estimate([first, footage(setup)], preset=preset, seed=seed, forward=forward,
                           generations=[g1, draws / POPSIZE], n_setups=2, propose=None, progress=progress)
        except (ValueError, RuntimeError) as exc:  # pre-registered: a missing outcome for this arm and case
            runs.append(ArmRun(arm, str(setup), fallback, cost, c_first, math.nan, 0, False, None, math.nan,
                               math.nan, forward.simulations_run - before, time.perf_counter() - t1,
                               failed=str(exc).splitlines()[0]))
            continue
        runs.append(ArmRun(arm, str(setup), fallback, cost, c_first, c_second, draws, est.stages[0].material == m1,
                           est.material, flow_curve_error(case.truth, est.material), e_rel(case.truth, est.material),
                           forward.simulations_run - before, time.perf_counter() - t1))
    return OutcomeRecord(config, case.index, case.seed_index, case.truth, str(case.first), m1,
                         flow_curve_error(case.truth, m1), e_rel(case.truth, m1), runs, time.perf_counter() - t0)


def posterior_outcome(record: OutcomeRecord, arm: ArmRun, config: dict, folder: Path, *, forward
                      ) -> PosteriorOutcome:
    """Film the arm's two setups into ``folder``, estimate there as the case did (read back from folders as the
    case's footage was: the store serves every simulation), write the run's result.json and analyse it as
    `virheo report --laws herschel-bulkley` does."""
    from mpm.files import write_json
    from similarity.cma_stage import POPSIZE
    from similarity.emulation import film
    from similarity.estimate import estimate, get_preset
    from similarity.posterior import analyse
    from similarity.presets import filming

    t0 = time.perf_counter()
    preset = get_preset(config["preset"])
    shoot = filming(preset, ForwardModel(*config["footage_model"]), "outcome-footage")
    setups = [Setup.parse(record.first_setup), Setup.parse(arm.second_setup)]
    experiments = [film(record.truth, s, folder, preset=shoot, forward=forward, density=DENSITY) for s in setups]
    est = estimate(experiments, preset=preset, seed=int(record.seed_index), forward=forward,
                   generations=[config["stage_1_generations"], arm.draws / POPSIZE], n_setups=2, propose=None)
    write_json(folder / "result.json", est.to_dict() | {
        "folders": [str(Path(e.path).resolve()) for e in experiments], "simulator": config["simulator"],
        "truth": record.truth.to_dict(), "e_rel": e_rel(record.truth, est.material)})
    summary = analyse(folder, forward=forward, laws=("herschel-bulkley",)).summary  # the band: HB's posterior
    i = int(np.argmin(np.abs(np.asarray(summary.flow_band["shear_rate"]) - 10.0)))
    lo, hi = summary.flow_band["5"][i], summary.flow_band["95"][i]
    true = float(record.truth.stress(summary.flow_band["shear_rate"][i]))
    return PosteriorOutcome(record.material_index, arm.arm, [str(s) for s in setups], est.material,
                            summary.band_width(10.0), bool(lo <= true <= hi), time.perf_counter() - t0,
                            est.material == arm.estimate)


def run_study(out, *, materials: int = 8, seeds: int = 2, seed: int = 62, preset: str = "survey",
              footage_model: ForwardModel = ForwardModel(1.26, 2), criterion_preset: str | None = None,
              stage_1_generations: int = 12, budget_particle_steps: float | None = None, posteriors: int = POSTERIORS,
              simulator: str | None = None, forward, progress=None) -> dict:
    """Run (or resume) the study in ``out`` case by case, then the posterior outcomes of ``posteriors`` materials;
    returns what ``design_outcome.json`` holds."""
    from similarity.estimate import get_preset

    budget_particle_steps = BUDGET_PARTICLE_STEPS if budget_particle_steps is None else budget_particle_steps
    if materials < 2 or seeds < 1 or stage_1_generations < 1 or not budget_particle_steps > 0:
        raise ValueError("--materials >= 2, --seeds >= 1, --stage-1-generations >= 1 and --budget-particle-steps > 0")
    if forward.store is None:
        raise ValueError("the outcome study needs a simulation store (stage 1 is shared by the arms through it)")
    config = {"materials": int(materials), "seeds": int(seeds), "seed": int(seed), "preset": get_preset(preset).name,
              "footage_model": [footage_model.cell_mm, footage_model.ppc], "criterion_preset": criterion_preset,
              "stage_1_generations": int(stage_1_generations), "budget_particle_steps": float(budget_particle_steps),
              "simulator": simulator, "arms": list(ARMS)}
    if not 0 <= posteriors <= materials:
        raise ValueError(f"--posteriors {posteriors} must be within 0..--materials")
    return DesignOutcome(out, config, posteriors=posteriors).run(forward=forward, progress=progress)
