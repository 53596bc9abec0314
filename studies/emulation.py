"""Emulation study of section 7.1: one setup vs two setups at equal simulation count.

Materials are drawn by Poisson-disk sampling in the normalised material space; each is estimated
several times from random first setups.  A two-setup run is Algorithm 1 with N = 2 (G generations
on setup 1, then 7 stage-1 candidates re-scored on setup 2 and G generations on setups 1 + 2, i.e.
7G + 7 + 14G simulations); the matching one-setup run continues CMA-ES on setup 1 alone for 3G + 1
generations (21G + 7 simulations), as in the paper.  Both share their first G generations (same seed, same
start), which the store serves once.

The study runs on the skeleton of :mod:`studies.study`: every finished case is kept in
``OUT/cases/case_MM_RR/case.json``, so a killed study resumes where it stopped.  Writes ``emulation.json``,
``emulation.md`` and ``errors_vs_simulations.png``.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mpm.files import JsonRecord
from mpm.params import DEFAULT_DENSITY_KG_M3, Material, Setup
from similarity import estimate as E
from similarity.space import denormalize, e_rel
from studies.report import save_figure
from studies.sampling import poisson_points, random_setups
from studies.study import Study

GOOD = 0.1  # E_rel <= 0.1 counts as good enough (section 7.1)


def poisson_materials(count: int, seed: int = 0, radius: float = 0.3) -> list[Material]:
    """``count`` materials spread over the normalised space by Poisson-disk sampling
    (:func:`studies.sampling.poisson_points`), kept away from the box faces (5 %..95 %), where the paper's materials
    lie too."""
    return [Material.from_array(denormalize(0.05 + 0.9 * p)) for p in poisson_points(count, seed, radius)[0]]


@dataclass
class Outcome(JsonRecord):
    """The estimate of one run (one setup, or two setups) against the truth."""

    estimate: Material
    e_rel: float
    simulations: int
    e_rel_after_setup_1: float | None = None  # two setups: E_rel of the stage-1 estimate

    OMIT_IF_NONE = ("e_rel_after_setup_1",)
    READERS = {"estimate": lambda d: Material(**d)}


@dataclass
class EmulationRecord(JsonRecord):
    """One finished case: a material, a first setup, the one-setup and the two-setup run.

    ``curves``: E_rel of the best candidate so far vs simulation count (Fig. 10): ``single`` (one setup),
    ``first`` and ``second`` (the two stages of the two-setup run), lists of (simulations, E_rel)."""

    material: int
    run: int
    config: dict
    truth: Material
    first_setup: str
    setups: list
    single: Outcome
    two_setups: Outcome
    curves: dict

    READERS = {"truth": lambda d: Material(**d), "single": Outcome.from_dict, "two_setups": Outcome.from_dict}

    def case_dict(self) -> dict:
        """The case as emulation.json lists it (without the configuration the study holds once)."""
        return {k: v for k, v in self.to_dict().items() if k != "config"}


@dataclass(frozen=True)
class EmulationCase:
    material: int
    run: int
    truth: Material
    first_setup: Setup
    folder: Path | None


def run_case(case: EmulationCase, *, preset, generations: int, forward, seed: int = 0,
             density: float = DEFAULT_DENSITY_KG_M3, progress=None, config: dict | None = None) -> EmulationRecord:
    """The two-setup run (``generations`` per stage) and the one-setup run of equal simulation count from one
    first setup; CMA-ES seed ``seed + 1000 material + run``."""
    truth = case.truth
    run_seed = seed + 1000 * case.material + case.run
    double, filmed = E.emulate_virheometry(truth, case.first_setup, n_setups=2, preset=preset, seed=run_seed,
                                           density=density, forward=forward, generations=generations,
                                           progress=progress)
    single = E.estimate(filmed[:1], preset=preset, seed=run_seed, forward=forward, generations=3 * generations + 1,
                        progress=progress, propose=None)
    offset = double.stages[0].simulations  # stage 2's count includes its warm-start re-scoring
    second = [(s + offset, v) for s, v in E.e_rel_history(double.stages[1], truth)] if len(double.stages) > 1 else []
    return EmulationRecord(
        material=case.material, run=case.run, config=config, truth=truth, first_setup=str(case.first_setup),
        setups=double.setups,
        single=Outcome(single.material, e_rel(truth, single.material), single.simulations),
        two_setups=Outcome(double.material, e_rel(truth, double.material), double.simulations,
                           e_rel(truth, double.stages[0].material)),
        curves={"single": E.e_rel_history(single.stages[0], truth), "first": E.e_rel_history(double.stages[0], truth),
                "second": second})


@dataclass
class EmulationSummary(JsonRecord):
    cases: int
    good_single: int  # cases with E_rel <= GOOD after one setup
    good_two_setups: int
    median_e_rel_single: float | None
    median_e_rel_two_setups: float | None


def summary(recs: list[EmulationRecord]) -> EmulationSummary:
    single = [r.single.e_rel for r in recs]
    double = [r.two_setups.e_rel for r in recs]
    return EmulationSummary(cases=len(recs), good_single=int(sum(v <= GOOD for v in single)),
                            good_two_setups=int(sum(v <= GOOD for v in double)),
                            median_e_rel_single=float(np.median(single)) if recs else None,
                            median_e_rel_two_setups=float(np.median(double)) if recs else None)


def planned_cases(out, *, materials: int, runs: int, seed: int) -> list[EmulationCase]:
    """The cases of a study: ``runs`` random first setups for each of ``materials`` Poisson-disk materials
    (case folders under ``out``; None: no folders)."""
    rng = np.random.default_rng(seed)
    return [EmulationCase(i, run, truth, first, None if out is None else
                          Path(out) / "cases" / f"case_{i:02d}_{run:02d}")
            for i, truth in enumerate(poisson_materials(materials, seed))
            for run, first in enumerate(random_setups(runs, rng, replace=True))]


class EmulationStudy(Study):
    """The section 7.1 emulation study on the skeleton of :mod:`studies.study`."""

    name = "emulation"
    record = EmulationRecord

    def cases(self):
        c = self.config
        return planned_cases(self.out, materials=c["materials"], runs=c["runs"], seed=c.get("seed", 0))

    def run_case(self, case, *, forward, progress=None):
        c = self.config
        preset = E.get_preset(c["preset"])
        return run_case(case, preset=preset, generations=int(c.get("generations") or preset.generations),
                        seed=c.get("seed", 0), density=c.get("density", DEFAULT_DENSITY_KG_M3), forward=forward,
                        progress=progress, config=c)

    def announce(self, case) -> str:
        t, c = case.truth, self.config
        return (f"material {case.material + 1}/{c['materials']} run {case.run + 1}/{c['runs']}: eta={t.eta:.3g} "
                f"n={t.n:.3g} sigma_y={t.sigma_y:.3g}, first setup {case.first_setup}")

    def report(self, rec) -> str:
        return (f"  E_rel one setup {rec.single.e_rel:.3f}, after setup 1 {rec.two_setups.e_rel_after_setup_1:.3f}, "
                f"two setups {rec.two_setups.e_rel:.3f} (setups {', '.join(map(str, rec.setups))})")

    def summary(self, recs) -> EmulationSummary:
        return summary(recs)

    def table(self, recs, summ) -> str:
        return table_markdown(recs, summ)

    def plots(self, recs, summ) -> None:
        plot_errors(self.out / "errors_vs_simulations.png", recs)

    def result(self, recs, summ, wall_seconds) -> dict:
        return {"settings": recs[0].config, "summary": summ.to_dict(), "wall_seconds": wall_seconds,
                "cases": [r.case_dict() for r in recs]}


def table_markdown(recs: list[EmulationRecord], s: EmulationSummary) -> str:
    lines = ["| material (eta, n, sigma_y) | first setup | second setup | E_rel one setup | E_rel two setups |",
             "|---|---|---|---|---|"]
    for r in recs:
        t = r.truth
        second = r.setups[1] if len(r.setups) > 1 else "-"
        lines.append(f"| {t.eta:.3g}, {t.n:.3g}, {t.sigma_y:.3g} | {r.first_setup} | {second} | "
                     f"{r.single.e_rel:.3f} | {r.two_setups.e_rel:.3f} |")
    lines.append("")
    lines.append(f"Good (E_rel <= {GOOD}): one setup {s.good_single}/{s.cases}, "
                 f"two setups {s.good_two_setups}/{s.cases} (paper: 11/30 and 20/30).")
    return "\n".join(lines) + "\n"


def plot_errors(path, recs: list[EmulationRecord]) -> Path:
    """Fig. 10-style plot: E_rel of the best candidate vs simulation count, one panel per case."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = max(1, len(recs))
    cols = min(3, n)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(4 * cols, 3 * rows), dpi=100, squeeze=False)
    for ax, r in zip(axes.ravel(), recs):
        for key, colour, label in (("single", "k", "one setup"), ("first", "tab:orange", "setup 1"),
                                   ("second", "tab:blue", "setups 1+2")):
            if r.curves[key]:
                x, y = zip(*r.curves[key])
                ax.plot(x, y, color=colour, lw=1.5 if key != "single" else 2.5, label=label,
                        zorder=3 if key != "single" else 2)
        ax.axhline(GOOD, color="grey", ls=":", lw=1)
        ax.set_yscale("log")
        ax.set_title(f"material {r.material + 1}, run {r.run + 1} ({r.first_setup})", fontsize=8)
        ax.set_xlabel("simulation count", fontsize=8)
        ax.set_ylabel("E_rel", fontsize=8)
        ax.tick_params(labelsize=7)
    for ax in axes.ravel()[len(recs):]:
        ax.axis("off")
    axes.ravel()[0].legend(fontsize=7)
    return save_figure(fig, path)


def run_study(out, *, materials: int = 6, runs: int = 3, preset="demo", generations: int | None = None,
              seed: int = 0, density: float | None = None, forward, progress=None) -> dict:
    """Run (or resume) the study case by case and write emulation.json, emulation.md and
    errors_vs_simulations.png into ``out``; ``forward`` (:class:`mpm.forward.Forward`) simulates.
    ``density``: of every material (default 1000 kg/m^3; named in the settings only when given)."""
    settings = {"materials": materials, "runs": runs, "generations": generations, "seed": seed}
    if density is not None:
        settings["density"] = density
    settings |= {"simulator": forward.simulator, "preset": E.get_preset(preset).name}
    return EmulationStudy(out, settings).run(forward=forward, progress=progress)
