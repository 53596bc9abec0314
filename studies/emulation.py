"""Emulation study of section 7.1: one setup vs two setups at equal simulation count.

Materials are drawn by Poisson-disk sampling in the normalised material space; each is estimated
several times from random first setups.  A two-setup run is Algorithm 1 with N = 2 (G generations
on setup 1, then 7 stage-1 candidates re-scored on setup 2 and G generations on setups 1 + 2, i.e.
7G + 7 + 14G simulations); the matching one-setup run continues CMA-ES on setup 1 alone for 3G + 1
generations (21G + 7 simulations), as in the paper.  Both
share their first G generations (same seed, same start), which the store serves once.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mpm.params import DEFAULT_DENSITY_KG_M3, SETUP_RANGE_MM, Material, Setup
from similarity import estimate as E
from similarity.space import denormalize, e_rel
from studies.report import save_figure, write_json

GOOD = 0.1  # E_rel <= 0.1 counts as good enough (section 7.1)


def poisson_materials(count: int, seed: int = 0, radius: float = 0.3) -> list[Material]:
    """``count`` materials spread over the normalised space by Poisson-disk sampling (scipy.stats.qmc).

    The points are kept away from the box faces (5 %..95 %), where the paper's materials lie too.
    """
    from scipy.stats import qmc

    r = radius
    while True:
        engine = qmc.PoissonDisk(d=3, radius=r, seed=seed)
        pts = engine.random(count)
        if len(pts) >= count:
            break
        r *= 0.85
    return [Material.from_array(denormalize(0.05 + 0.9 * p)) for p in pts[:count]]


def random_setups(count: int, rng: np.random.Generator) -> list[Setup]:
    lo, hi = SETUP_RANGE_MM
    return [Setup(float(w), float(h)) for w, h in rng.integers(lo, hi + 1, size=(count, 2))]


@dataclass
class Case:
    material_index: int
    run: int
    truth: Material
    first_setup: Setup
    single: E.Estimate
    double: E.Estimate

    def curves(self) -> dict:
        """E_rel vs simulation count: single setup, and the two stages of the two-setup run."""
        single = E.e_rel_history(self.single.stages[0], self.truth)
        first = E.e_rel_history(self.double.stages[0], self.truth)
        offset = self.double.stages[0].simulations  # stage 2's count includes its warm-start re-scoring
        second = [(s + offset, v) for s, v in E.e_rel_history(self.double.stages[1], self.truth)] \
            if len(self.double.stages) > 1 else []
        return {"single": single, "first": first, "second": second}

    def to_dict(self) -> dict:
        return {
            "material": self.material_index, "run": self.run, "truth": self.truth.to_dict(),
            "first_setup": str(self.first_setup), "setups": self.double.setups,
            "single": {"estimate": self.single.material.to_dict(), "e_rel": e_rel(self.truth, self.single.material),
                       "simulations": self.single.simulations},
            "two_setups": {"estimate": self.double.material.to_dict(), "e_rel": e_rel(self.truth, self.double.material),
                           "simulations": self.double.simulations,
                           "e_rel_after_setup_1": e_rel(self.truth, self.double.stages[0].material)},
            "curves": self.curves(),
        }


def run_study(*, materials: int = 6, runs: int = 3, preset="demo", generations: int | None = None, seed: int = 0,
              density: float = DEFAULT_DENSITY_KG_M3, forward, progress=None) -> list[Case]:
    preset = E.get_preset(preset)
    g = int(generations or preset.generations)
    rng = np.random.default_rng(seed)
    cases = []
    for i, truth in enumerate(poisson_materials(materials, seed)):
        for run, first in enumerate(random_setups(runs, rng)):
            if progress:
                progress({"event": "message", "text": f"material {i + 1}/{materials} run {run + 1}/{runs}: "
                          f"eta={truth.eta:.3g} n={truth.n:.3g} sigma_y={truth.sigma_y:.3g}, first setup {first}"})
            run_seed = seed + 1000 * i + run
            double, filmed = E.emulate_virheometry(truth, first, n_setups=2, preset=preset, seed=run_seed,
                                                   density=density, forward=forward, generations=g,
                                                   progress=progress)
            single = E.estimate(filmed[:1], preset=preset, seed=run_seed, forward=forward,
                                generations=3 * g + 1, progress=progress, propose=None)
            cases.append(Case(i, run, truth, first, single, double))
            if progress:
                progress({"event": "message", "text": f"  E_rel one setup {e_rel(truth, single.material):.3f}, "
                          f"after setup 1 {e_rel(truth, double.stages[0].material):.3f}, two setups "
                          f"{e_rel(truth, double.material):.3f} (setups {', '.join(map(str, double.setups))})"})
    return cases


def summary(cases: list[Case]) -> dict:
    single = [e_rel(c.truth, c.single.material) for c in cases]
    double = [e_rel(c.truth, c.double.material) for c in cases]
    return {
        "cases": len(cases),
        "good_single": int(sum(v <= GOOD for v in single)),
        "good_two_setups": int(sum(v <= GOOD for v in double)),
        "median_e_rel_single": float(np.median(single)) if cases else None,
        "median_e_rel_two_setups": float(np.median(double)) if cases else None,
    }


def table_markdown(cases: list[Case]) -> str:
    s = summary(cases)
    lines = ["| material (eta, n, sigma_y) | first setup | second setup | E_rel one setup | E_rel two setups |",
             "|---|---|---|---|---|"]
    for c in cases:
        t = c.truth
        second = c.double.setups[1] if len(c.double.setups) > 1 else "-"
        lines.append(f"| {t.eta:.3g}, {t.n:.3g}, {t.sigma_y:.3g} | {c.first_setup} | {second} | "
                     f"{e_rel(t, c.single.material):.3f} | {e_rel(t, c.double.material):.3f} |")
    lines.append("")
    lines.append(f"Good (E_rel <= {GOOD}): one setup {s['good_single']}/{s['cases']}, "
                 f"two setups {s['good_two_setups']}/{s['cases']} (paper: 11/30 and 20/30).")
    return "\n".join(lines) + "\n"


def plot_errors(path, cases: list[Case]) -> Path:
    """Fig. 10-style plot: E_rel of the best candidate vs simulation count, one panel per case."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = max(1, len(cases))
    cols = min(3, n)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(4 * cols, 3 * rows), dpi=100, squeeze=False)
    for ax, c in zip(axes.ravel(), cases):
        curves = c.curves()
        for key, colour, label in (("single", "k", "one setup"), ("first", "tab:orange", "setup 1"),
                                   ("second", "tab:blue", "setups 1+2")):
            if curves[key]:
                x, y = zip(*curves[key])
                ax.plot(x, y, color=colour, lw=1.5 if key != "single" else 2.5, label=label,
                        zorder=3 if key != "single" else 2)
        ax.axhline(GOOD, color="grey", ls=":", lw=1)
        ax.set_yscale("log")
        ax.set_title(f"material {c.material_index + 1}, run {c.run + 1} ({c.first_setup})", fontsize=8)
        ax.set_xlabel("simulation count", fontsize=8)
        ax.set_ylabel("E_rel", fontsize=8)
        ax.tick_params(labelsize=7)
    for ax in axes.ravel()[len(cases):]:
        ax.axis("off")
    axes.ravel()[0].legend(fontsize=7)
    return save_figure(fig, path)


def write(out, cases: list[Case], *, settings: dict, wall_seconds: float) -> dict:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    result = {"settings": settings, "summary": summary(cases), "wall_seconds": wall_seconds,
              "cases": [c.to_dict() for c in cases]}
    write_json(out / "emulation.json", result)
    (out / "emulation.md").write_text(table_markdown(cases))
    plot_errors(out / "errors_vs_simulations.png", cases)
    return result


def timed_study(out, **kw) -> dict:
    t0 = time.perf_counter()
    cases = run_study(**kw)
    settings = {k: v for k, v in kw.items() if k in ("materials", "runs", "generations", "seed", "density")}
    settings["simulator"] = kw["forward"].simulator
    settings["preset"] = E.get_preset(kw.get("preset", "demo")).name
    return write(out, cases, settings=settings, wall_seconds=time.perf_counter() - t0)
