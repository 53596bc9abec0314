"""Calibration of the posterior on emulated footage: does the 90 % credible region hold the truth 90 % of the time?

Cases: materials by a scrambled Sobol design over the normalised material space (kept 5 % off its faces,
like the emulation study's), one random setup each.  Per case and setting:

1. footage of the true material, simulated by the estimating model (setting ``same``) or at half its cell
   width (setting ``finer``), written as an experiment folder;
2. a one-setup estimate (Algorithm 1, one stage, the preset's model);
3. the posterior exactly as ``virheo report`` computes it (:func:`similarity.posterior.analyse`: noise
   scale with the discretisation error, emulator from the store plus a space-filling batch, emcee);
4. the credible level of the truth in three kinds of region, and in the HPD region had N_eff been k times
   the one counted (:mod:`studies.credible`).

Every simulation goes through the store and every finished case is kept in ``case.json``, so a killed study
resumes where it stopped.  Writes ``calibration.json``, ``calibration.md`` and ``reliability.png``.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from mpm.params import DEFAULT_DENSITY_KG_M3 as DENSITY
from mpm.files import JsonRecord
from mpm.params import Material, Setup
from similarity.posterior import NOISE_COUNT
from similarity.space import denormalize, e_rel, normalize
from studies.credible import (LEVELS, NOMINAL, PARAMETERS, REGIONS, TEMPERING, coverage, credible_levels,
                               tempered_level, tempered_summary)
from studies.report import save_figure, write_json
from studies.study import Study

SETTINGS = ("same", "finer")


# -- design --------------------------------------------------------------------------------------------
def design(cases: int, seed: int = 0) -> list[tuple[Material, Setup]]:
    """``cases`` (material, setup) pairs: scrambled Sobol materials in 5 %..95 % of the normalised space,
    a random 1 mm-grid setup each.  The first k cases do not depend on ``cases`` (a study can grow)."""
    import warnings

    from scipy.stats import qmc

    from studies.sampling import random_setups

    if cases < 1:
        raise ValueError(f"cases={cases} must be >= 1")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # Sobol' balance wants 2^k points; any prefix is space-filling
        u = qmc.Sobol(d=3, scramble=True, seed=seed).random(int(cases))
    return [(Material.from_array(denormalize(0.05 + 0.9 * p)), random_setups(1, np.random.default_rng([seed, i]), replace=True)[0])
            for i, p in enumerate(u)]


def footage_preset(preset, setting: str):
    """The preset whose final model films the footage: the estimating one, or one at half its cell width."""
    from similarity.presets import filming, get_preset

    preset = get_preset(preset)
    if setting == "same":
        return preset
    if setting != "finer":
        raise ValueError(f"setting '{setting}' must be one of {', '.join(SETTINGS)}")
    model = preset.final.resolved()
    return filming(preset, replace(model, cell_mm=model.cell_mm / 2.0), name=f"{preset.name}-fine")


# -- one case ------------------------------------------------------------------------------------------
@dataclass
class CalibrationRecord(JsonRecord):
    """One finished case: the truth, the estimate, the posterior's summary and the truth's credible levels.

    ``posterior``, ``noise`` and ``emulator`` are parts of :class:`similarity.posterior_summary.PosteriorSummary`'s
    JSON; ``width_90`` (mean width of the 90 % intervals, normalised) is computed from the saved samples."""

    case: int
    setting: str
    config: dict
    truth: Material
    truth_normalised: list
    setup: str
    estimate: Material
    e_rel: float
    loss: float
    simulations_estimate: int
    footage_cell_mm: float
    credible_level: dict  # region kind -> level, and per_parameter (:func:`credible_levels`)
    truth_in_trust_region: bool
    posterior: dict
    noise: dict
    emulator: dict
    wall_seconds: dict  # estimate, total
    simulations_run: int | None
    width_90: float | None = None
    tempered: dict | None = None  # str(k) -> [HPD level, weights' ESS fraction] (:func:`tempered_level`)

    OMIT_IF_NONE = ("width_90", "tempered")
    READERS = {"truth": lambda d: Material(**d), "estimate": lambda d: Material(**d)}


@dataclass(frozen=True)
class CalibrationCase:
    index: int
    truth: Material
    setup: Setup
    setting: str
    folder: Path


def run_case(case: CalibrationCase, *, config: dict, forward, progress=None) -> CalibrationRecord:
    """Footage, estimate, posterior and credible levels of one case, in ``case.folder``."""
    from similarity import estimate as E
    from similarity.emulation import film
    from similarity.posterior import analyse

    folder, truth, setup = Path(case.folder), case.truth, case.setup
    t0 = time.perf_counter()
    ran = forward.simulations_run
    # 1. footage, as an experiment folder (the estimate and the posterior read it like real footage)
    exp = film(truth, setup, folder, density=DENSITY, preset=footage_preset(config["preset"], case.setting),
               forward=forward)
    # 2. one-setup estimate
    seed = config["seed"] + case.index
    est = E.estimate([exp], preset=config["preset"], seed=seed, forward=forward,
                     generations=config["generations"], progress=progress, propose=None)
    t_est = time.perf_counter() - t0
    result = est.to_dict() | {"folders": [str(Path(exp.path).resolve())], "simulator": config["simulator"],
                              "truth": truth.to_dict(), "e_rel": e_rel(truth, est.material)}
    write_json(folder / "result.json", result)
    # 3. the posterior of `virheo report`
    a = analyse(folder, forward=forward, new_simulations=config["new_simulations"],
                half_width=config["half_width"], seed=seed, min_ess=config["min_ess"],
                max_steps=config["max_steps"], discretisation=True, noise_count=config["noise_count"],
                progress=progress)
    summ = a.summary.to_dict()
    lo, hi = (np.asarray(v, float) for v in a.summary.emulator.trust_region)
    x_true = normalize(truth.as_array())
    return CalibrationRecord(
        case=case.index, setting=case.setting, config=config, truth=truth, truth_normalised=x_true.tolist(),
        setup=str(setup), estimate=est.material, e_rel=e_rel(truth, est.material), loss=est.loss,
        simulations_estimate=est.simulations,
        footage_cell_mm=footage_preset(config["preset"], case.setting).final.resolved().cell_mm,
        credible_level=credible_levels(a.posterior.samples, x_true, log_density=a.log_prob),
        truth_in_trust_region=bool(np.all((x_true >= lo) & (x_true <= hi))),
        posterior={k: summ["posterior"][k] for k in ("mean", "quantiles", "ess", "converged", "iterations",
                                                      "acceptance")},
        noise={k: summ["noise"][k] for k in ("n_eff", "loss_at_optimum", "discretisation", "emulator", "variance")},
        emulator=summ["emulator"],
        wall_seconds={"estimate": t_est, "total": time.perf_counter() - t0},
        simulations_run=forward.simulations_run - ran,
    )


# -- the study --------------------------------------------------------------------------------------------
@dataclass
class SettingSummary(JsonRecord):
    """Coverage and sharpness of the cases of one setting."""

    cases: int
    coverage_90: dict  # region kind -> fraction of cases whose truth lies in its 90 % region
    inside_90: dict  # region kind -> number of such cases
    coverage_90_per_parameter: dict
    reliability: dict  # levels, and the coverage at each per region kind and parameter
    truth_in_trust_region: int
    median_e_rel: float
    median_width_90: float
    median_ess: float
    converged: int
    mean_wall_seconds: float
    tempered: dict | None = None  # str(k) -> cases, inside_90, median_level, below_0_4, min_ess_fraction

    OMIT_IF_NONE = ("tempered",)


@dataclass
class CalibrationSummary:
    settings: dict  # setting -> SettingSummary

    def to_dict(self) -> dict:
        return {s: v.to_dict() for s, v in self.settings.items()}


def case_folder(out, setting: str, index: int) -> Path:
    return Path(out) / "cases" / setting / f"case_{index:02d}"


def _config(preset, generations, new_simulations, half_width, seed, min_ess, max_steps, simulator,
            noise_count) -> dict:
    from similarity.estimate import get_preset

    p = get_preset(preset)
    return {"preset": p.name, "generations": int(generations or p.generations), "new_simulations": int(new_simulations),
            "half_width": float(half_width), "seed": int(seed), "min_ess": float(min_ess), "max_steps": int(max_steps),
            "simulator": simulator, "noise_count": noise_count}


def run_study(out, *, cases: int = 20, settings=SETTINGS, preset="demo", generations: int | None = None,
              new_simulations: int = 24, half_width: float = 0.1, seed: int = 0, min_ess: float = 1000.0,
              max_steps: int = 20000, forward, progress=None, noise_count: str = NOISE_COUNT) -> dict:
    """Run (or resume) ``cases`` cases in each of ``settings``, case by case, and write the outputs;
    ``forward`` (:class:`mpm.forward.Forward`) simulates.  Returns what calibration.json holds."""
    for s in settings:
        footage_preset(preset, s)  # unknown settings stop here
    config = _config(preset, generations, new_simulations, half_width, seed, min_ess, max_steps, forward.simulator,
                     noise_count)
    return CalibrationStudy(out, config, cases=cases, settings=settings).run(forward=forward, progress=progress)


class CalibrationStudy(Study):
    """The calibration study on the skeleton of :mod:`studies.study`."""

    name = "calibration"
    record = CalibrationRecord
    case_files = tuple(f"cases/{s}/case_*/case.json" for s in SETTINGS)

    def __init__(self, out, config: dict | None = None, *, cases: int = 0, settings=SETTINGS):
        super().__init__(out, config)
        self.n_cases, self.settings = int(cases), tuple(settings)

    def cases(self):
        for i, (truth, setup) in enumerate(design(self.n_cases, self.config["seed"])):
            for s in self.settings:
                yield CalibrationCase(i, truth, setup, s, case_folder(self.out, s, i))

    def run_case(self, case, *, forward, progress=None):
        return run_case(case, config=self.config, forward=forward, progress=progress)

    def announce(self, case) -> str:
        t = case.truth
        return (f"case {case.index + 1}/{self.n_cases} ({case.setting}): eta={t.eta:.3g} n={t.n:.3g} "
                f"sigma_y={t.sigma_y:.3g}, setup {case.setup}")

    def report(self, rec) -> str:
        lv = rec.credible_level
        return (f"  E_rel {rec.e_rel:.3f}; credible level of the truth: HPD {lv['hpd']:.2f}, ellipsoid "
                f"{lv['ellipsoid']:.2f}, intervals {lv['intervals']:.2f}")

    def records(self) -> list[CalibrationRecord]:
        """Every finished case (both settings), in setting then case order, with its sharpness."""
        found = super().records()
        for r in found:  # sharpness: mean width of the 90 % intervals in the normalised space
            samples = case_folder(self.out, r.setting, r.case) / "posterior_samples.npy"
            if r.width_90 is None and samples.is_file():
                q = np.quantile(np.load(samples), [0.05, 0.95], axis=0)
                r.width_90 = float(np.mean(q[1] - q[0]))
            log_prob = samples.with_name("posterior_log_prob.npy")
            if r.tempered is None and log_prob.is_file():
                lp = np.load(log_prob)
                r.tempered = {f"{k:g}": list(tempered_level(lp, r.credible_level["hpd"], k)) for k in TEMPERING}
        return found

    def plots(self, recs, summ) -> None:
        plot_reliability(self.out / "reliability.png", summ)

    def result(self, recs, summ, wall_seconds) -> dict:
        return {"config": recs[0].config, "levels": LEVELS.tolist(), "nominal": NOMINAL, "summary": summ.to_dict(),
                "wall_seconds": wall_seconds, "cases": [r.to_dict() for r in recs]}


    def summary(self, recs: list[CalibrationRecord]) -> CalibrationSummary:
        """Per setting: coverage of the 90 % regions, the reliability curve, accuracy and sharpness."""
        out = {}
        at = int(np.flatnonzero(np.isclose(LEVELS, NOMINAL))[0])
        for s in SETTINGS:
            rs = [r for r in recs if r.setting == s]
            if not rs:
                continue
            lv = [r.credible_level for r in rs]
            out[s] = SettingSummary(
                cases=len(rs),
                coverage_90={k: float(coverage([v[k] for v in lv])[at]) for k in REGIONS},
                inside_90={k: int(round(len(rs) * coverage([v[k] for v in lv])[at])) for k in REGIONS},
                coverage_90_per_parameter={p: float(coverage([v["per_parameter"][p] for v in lv])[at])
                                           for p in PARAMETERS},
                reliability={"levels": LEVELS.tolist(),
                             **{k: coverage([v[k] for v in lv]).tolist() for k in REGIONS},
                             **{p: coverage([v["per_parameter"][p] for v in lv]).tolist() for p in PARAMETERS}},
                truth_in_trust_region=int(sum(r.truth_in_trust_region for r in rs)),
                median_e_rel=float(np.median([r.e_rel for r in rs])),
                median_width_90=float(np.median([np.nan if r.width_90 is None else r.width_90 for r in rs])),
                median_ess=float(np.median([r.posterior["ess"] for r in rs])),
                converged=int(sum(bool(r.posterior["converged"]) for r in rs)),
                mean_wall_seconds=float(np.mean([r.wall_seconds["total"] for r in rs])),
                tempered=tempered_summary([r.tempered for r in rs if r.tempered is not None]),
            )
        return CalibrationSummary(out)

    def table(self, recs: list[CalibrationRecord], summ: CalibrationSummary) -> str:
        lines = ["| setting | case | truth (eta, n, sigma_y) | setup | E_rel | HPD level | ellipsoid level | "
                 "in 90 % HPD | in 90 % interval (eta, n, sigma_y) | 90 % interval width | box +- | ESS | N_eff | "
                 "s^2 | wall [s] |",
                 "|---|---:|---|---|---:|---:|---:|---|---|---:|---:|---:|---:|---:|---:|"]
        for r in recs:
            t, lv = r.truth, r.credible_level
            per = " ".join("y" if lv["per_parameter"][p] <= NOMINAL else "n" for p in PARAMETERS)
            width = float("nan") if r.width_90 is None else r.width_90
            lines.append(f"| {r.setting} | {r.case} | {t.eta:.3g}, {t.n:.3g}, {t.sigma_y:.3g} | "
                         f"{r.setup} | {r.e_rel:.3f} | {lv['hpd']:.2f} | {lv['ellipsoid']:.2f} | "
                         f"{'yes' if lv['hpd'] <= NOMINAL else 'no'} | {per} | {width:.2f} | "
                         f"{r.emulator.get('half_width', float('nan')):g} | {r.posterior['ess']:.0f} | "
                         f"{r.noise['n_eff']:.0f} | {r.noise['variance']:.2e} | {r.wall_seconds['total']:.0f} |")
        lines += ["", "| setting | cases | 90 % HPD | 90 % ellipsoid | 90 % intervals jointly | eta | n | sigma_y | "
                  "truth in trust region | median E_rel | median 90 % interval width |",
                  "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
        for s, v in summ.settings.items():
            n, cov, inside = v.cases, v.coverage_90, v.inside_90
            lines.append(f"| {s} | {n} | {inside['hpd']}/{n} ({100 * cov['hpd']:.0f} %) | "
                         f"{inside['ellipsoid']}/{n} ({100 * cov['ellipsoid']:.0f} %) | "
                         f"{inside['intervals']}/{n} ({100 * cov['intervals']:.0f} %) | "
                         + " | ".join(f"{100 * v.coverage_90_per_parameter[p]:.0f} %" for p in PARAMETERS)
                         + f" | {v.truth_in_trust_region}/{n} | {v.median_e_rel:.3f} | {v.median_width_90:.2f} |")
        if any(v.tempered for v in summ.settings.values()):
            lines += ["", "Had N_eff been k times the one counted (the same samples reweighted, `tempered_level`):", "",
                      "| setting | k | cases | truth in 90 % HPD | median credible level | levels below 0.4 | "
                      "smallest weights' ESS |", "|---|---:|---:|---:|---:|---:|---:|"]
            for s, v in summ.settings.items():
                for k, t in (v.tempered or {}).items():
                    lines.append(f"| {s} | {k} | {t['cases']} | {t['inside_90']}/{t['cases']} | "
                                 f"{t['median_level']:.2f} | {t['below_0_4']}/{t['cases']} | "
                                 f"{100 * t['min_ess_fraction']:.0f} % |")
        return "\n".join(lines) + "\n"


def plot_reliability(path, summ: CalibrationSummary) -> Path:
    """Nominal level vs empirical coverage, one panel per setting, with the binomial 90 % band of a calibrated
    posterior around the diagonal."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy.stats import binom

    n_pan = max(1, len(summ.settings))
    fig, axes = plt.subplots(1, n_pan, figsize=(3.6 * n_pan, 3.5), dpi=100, squeeze=False)
    for ax, (s, v) in zip(axes[0], summ.settings.items()):
        rel, n = v.reliability, v.cases
        lv = np.asarray(rel["levels"])
        ax.fill_between(lv, binom.ppf(0.05, n, lv) / n, binom.ppf(0.95, n, lv) / n, color="0.88",
                        label="90 % band if calibrated")
        ax.plot([0, 1], [0, 1], color="0.5", lw=1)
        for key, style, label in (("hpd", "o-", "HPD region"), ("ellipsoid", "s--", "ellipsoid"),
                                  ("intervals", "^:", "intervals jointly")):
            ax.plot(lv, rel[key], style, ms=4, lw=1.6, label=label)
        for p, c in zip(PARAMETERS, ("tab:red", "tab:purple", "tab:brown")):
            ax.plot(lv, rel[p], color=c, lw=0.8, alpha=0.7, label=f"{p} interval")
        ax.set_xlim(0, 1)
        ax.set_ylim(0, 1.02)
        ax.set_aspect("equal")
        ax.set_xlabel("nominal level", fontsize=8)
        ax.set_ylabel("fraction of cases covered", fontsize=8)
        ax.set_title(f"footage by the {'estimating' if s == 'same' else 'finer'} model ({n} case{'s' * (n != 1)})",
                     fontsize=9)
        ax.tick_params(labelsize=7)
    axes[0][0].legend(fontsize=6, loc="lower right")
    return save_figure(fig, path)
