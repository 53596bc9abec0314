"""Does the design pay off?  Each criterion's second setup against a seeded set of candidates, scored by the
information it realises in the simulator at the true material (:mod:`similarity.information`).

Materials: a scrambled Sobol design over 5..95 % of the normalised space with one random first setup each
(:func:`studies.calibration.design`, the cases of the calibration and design studies).  Per material:

1. **what a user knows after setup 1**: emulated footage of the first setup and a short stage-1 CMA-ES run on it
   (Algorithm 1, one stage, ``generations`` generations, the preset's model); its estimate, not the truth, is
   what every criterion sees;
2. **each criterion's pick** over the full 51 x 51 grid from that estimate: ``eig`` (expected information gain
   under stage 1's archive belief, published Theta map), ``perpendicularity-fitted`` and
   ``perpendicularity-reference`` (section 6 with our fitted and the published Theta map), and two baselines that
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
the largest median normalised score there, if positive (else none).  The last ``held_out`` materials are reported apart: they decide the
verdict.  Two further parts, optional: a Fig. 10-style **map** of realised information over a coarse grid of
setups for the first materials (``maps``), and a **posterior check** (``posterior_check`` materials): for every
candidate, the volume of an emcee posterior (eq. 1 of :mod:`similarity.likelihood` on an emulated two-setup loss)
against the realised gain.

Every simulation goes through the store, every finished material is kept in ``cases/case_XX/case.json``, every
map and posterior check in its own JSON, so a killed study resumes where it stopped.  Writes
``design_information.json``, ``design_information.md``, ``predicted_vs_realised.png``, ``maps.png`` and
``design_validation.json``: the held-out figures that `virheo design` prints, shipped as
``studies/data/design_validation.json``.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from mpm.params import DEFAULT_DENSITY_KG_M3 as DENSITY
from mpm.params import SETUP_RANGE_MM, Material, Setup
from similarity import information as I
from studies.report import finished_case, finished_cases, save_figure, write_json, write_study

# name -> (criterion of similarity.design.rank_setups, Theta map); the baselines "random" and "largest" (the
# largest box other than the first, ranking setups by their area W x H) are not offered by `virheo design`
CRITERIA = {"eig": ("eig", "reference"), "perpendicularity-fitted": ("perpendicularity", "fitted"),
            "perpendicularity-reference": ("perpendicularity", "reference"), "random": None, "largest": None}
LARGEST = Setup(float(SETUP_RANGE_MM[1]), float(SETUP_RANGE_MM[1]))
DEFAULT_CRITERION = "perpendicularity-reference"  # what `virheo design` uses without options
WITHIN = 0.1  # "within 10 % of the best candidate": normalised score >= 1 - WITHIN
SUMMARY_FILE = Path(__file__).resolve().parent / "data" / "design_validation.json"
COLOURS = {"eig": "tab:red", "perpendicularity-fitted": "tab:green", "perpendicularity-reference": "tab:blue",
           "random": "0.45", "largest": "tab:orange"}


def case_seed(seed: int, index: int) -> int:
    """Stage-1 CMA-ES seed of material ``index``."""
    return int(seed) + 1000 * int(index)


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
    """The ranking of criterion ``name`` (None for random), or the reason it cannot rank."""
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


def _predicted(ranking, setups, name: str = "") -> list:
    """The ranking's predicted information (higher = better) of each setup; None where it has none ("largest":
    the setup's area)."""
    if name == "largest":
        return [s.width_mm * s.height_mm for s in setups]
    if ranking is None:
        return [None] * len(setups)
    sign = 1.0 if ranking.criterion == "eig" else -1.0  # S_p: lower is better
    score = {(float(w), float(h)): sign * float(v) for w, h, v in zip(ranking.width_mm, ranking.height_mm, ranking.score)}
    return [score.get((s.width_mm, s.height_mm)) for s in setups]


def stencil_losses(truth: Material, setups, *, preset, fd_step: float, forward, tick=None) -> np.ndarray:
    """Losses (len(setups), 18) of the FD stencil around ``truth`` in each setup against its own emulated footage
    (NaN where a simulation failed): 1 + 18 simulations per setup."""
    from similarity.emulation import emulate, probe_losses
    from similarity.fd_hessian import stencil

    shots = emulate(truth, setups, density=DENSITY, preset=preset, forward=forward)
    return probe_losses([(truth, e) for e in shots], stencil(fd_step), preset.final, forward, tick)


def hessians_of(losses, fd_step: float) -> list:
    """PSD-projected FD Hessians (3, 3) from rows of stencil losses; None where a row is not finite."""
    return [I.setup_hessian(row, fd_step) if np.all(np.isfinite(row)) else None for row in np.asarray(losses, float)]


# realised-information measures (similarity.information): the first is the study's
MEASURES = {"gain": I.log_det_gain, "gain_min_eig": I.min_eig_gain, "gain_shape": I.shape_gain}
MEASURE_LABELS = {"gain": "log det gain", "gain_min_eig": "smallest-eigenvalue gain",
                  "gain_shape": "log det gain of the direction alone (trace scaled to setup 1's)"}


def gains(h_first, hessians, measure: str = "gain") -> np.ndarray:
    """Realised gain of each candidate Hessian (NaN where None) after the first setup's, by ``measure``."""
    ok = np.array([h is not None for h in hessians])
    stack = np.array([h if h is not None else np.eye(3) for h in hessians], float).reshape(-1, 3, 3)
    return np.where(ok, MEASURES[measure](np.asarray(h_first, float), stack), np.nan)


def case_gains(rec: dict, measure: str = "gain") -> np.ndarray:
    """The realised gains of a material's candidates, recomputed from its stored Hessians."""
    return gains(rec["hessian_first"], [None if h is None else np.array(h) for h in rec["hessians"]], measure)


def _listed(values) -> list:
    return [float(v) if np.isfinite(v) else None for v in values]


def run_case(folder, index: int, truth: Material, first: Setup, *, config: dict, forward, thetas, tick=None) -> dict:
    """One material; the record is kept in ``folder/case.json`` and read back when it is there."""
    from similarity import estimate as E
    from similarity.belief import stage_belief
    from similarity.proposers import Random
    from similarity.space import e_rel

    folder = Path(folder)
    rec = finished_case(folder, config)
    if rec is not None:
        return rec
    t0 = time.perf_counter()
    preset = E.get_preset(config["preset"])
    footage = E.emulate(truth, [first], density=DENSITY, preset=preset, forward=forward)[0]
    frames = int(len(footage.frames))
    est = E.estimate([footage], preset=preset, seed=case_seed(config["seed"], index), forward=forward,
                     generations=config["generations"], propose=None)
    stage = est.stages[0]
    try:
        covariance, belief_note = stage_belief(stage, frames).covariance, None
    except ValueError as exc:  # too few or degenerate evaluations: the plane-Poiseuille Laplace belief
        covariance, belief_note = None, str(exc).splitlines()[0]
    random_pick = Random([config["seed"], index])(est.material, [first])
    rankings, picks, fallbacks = {}, {}, {}
    for name in config["criteria"]:
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
    losses = stencil_losses(truth, [first] + cands, preset=preset, fd_step=config["fd_step"], forward=forward,
                            tick=tick)
    hessians = hessians_of(losses, config["fd_step"])
    if hessians[0] is None:
        raise RuntimeError(f"material {index}: a simulation of the first setup's stencil failed")
    rec = {
        "case": index, "config": config, "truth": truth.to_dict(), "first_setup": str(first),
        "frames_per_setup": frames,
        "stage_1": {"estimate": est.material.to_dict(), "loss": est.loss, "simulations": est.simulations,
                    "e_rel": e_rel(truth, est.material), "belief": belief_note or "archive"},
        "candidates": [str(s) for s in cands], "seeded": len(seeded),
        "stencil_losses": [[None if not np.isfinite(v) else float(v) for v in row] for row in losses],
        "hessian_first": hessians[0].tolist(), "hessians": [None if h is None else h.tolist() for h in hessians[1:]],
        **{m: _listed(gains(hessians[0], hessians[1:], m)) for m in MEASURES},
        "picks": {k: str(v) for k, v in picks.items()}, "fallbacks": fallbacks,
        "predicted": {k: _predicted(rankings[k], cands, k) for k in config["criteria"]},
        "wall_seconds": time.perf_counter() - t0,
    }
    folder.mkdir(parents=True, exist_ok=True)
    write_json(folder / "case.json", rec)
    return rec


# -- scores ---------------------------------------------------------------------------------------------------
def case_scores(rec: dict, measure: str = "gain") -> dict:
    """Per criterion: the pick's realised gain, its normalised score, and Spearman (predicted vs realised)."""
    realised = case_gains(rec, measure)
    best = float(np.nanmax(realised))
    out = {}
    for name, pick in rec["picks"].items():
        g = realised[rec["candidates"].index(pick)]
        score = I.normalised_score(g, realised[:rec["seeded"]], best)
        pred = rec["predicted"][name]
        rho = float("nan")
        if any(p is not None for p in pred):
            worst = min(p for p in pred if p is not None) - 1.0  # a setup the criterion rules out ranks last
            rho = I.rank_agreement([worst if p is None else p for p in pred], realised)
        out[name] = {"pick": pick, "gain": float(g), "score": score, "spearman": rho}
    return out


def _group(recs, names, measure) -> dict:
    per = {}
    for name in names:
        sc = [case_scores(r, measure)[name] for r in recs]
        s = np.array([v["score"] for v in sc])
        rho = np.array([v["spearman"] for v in sc])
        wins, decided, p = I.sign_test(s)
        per[name] = {"scores": s.tolist(), "median_score": float(np.nanmedian(s)) if np.isfinite(s).any() else None,
                     "beats_mean": wins, "decided": decided, "sign_test_p": p,
                     "within": int(np.sum(s >= 1.0 - WITHIN)), "materials": len(recs),
                     "spearman": rho.tolist(),
                     "median_spearman": float(np.nanmedian(rho)) if np.isfinite(rho).any() else None,
                     "median_gain": float(np.median([v["gain"] for v in sc]))}
    return per


def summary(recs: list[dict]) -> dict:
    """Selection and held-out scores per criterion and measure, the recommended criterion, and the verdicts of the
    default and the recommended criterion on the held-out materials (the issue's acceptance)."""
    if not recs:
        raise ValueError("no finished materials to summarise")
    cfg = recs[0]["config"]
    n_sel = cfg["materials"] - cfg["held_out"]  # records come in material order: selection first
    sel, held = recs[:n_sel], recs[n_sel:]
    names = list(cfg["criteria"])
    out = {"materials": len(recs), "selection": len(sel), "held_out": len(held)}
    for measure in MEASURES:
        out[measure] = {"selection": _group(sel, names, measure) if sel else {},
                        "held_out": _group(held, names, measure) if held else {}}
    seeded_median = [float(np.nanmedian(case_gains(r)[:r["seeded"]])) for r in held]
    out["median_gain_seeded"] = float(np.median(seeded_median)) if held else None
    ranked = [n for n in names if CRITERIA[n] is not None]  # what `virheo design` offers
    out["recommended"] = None  # unless a criterion's median score on the selection materials is positive
    if sel:
        med = {n: out["gain"]["selection"][n]["median_score"] for n in ranked}
        best = max(ranked, key=lambda n: -np.inf if med[n] is None else med[n])
        if med[best] is not None and med[best] > 0:
            out["recommended"] = best
    if held:
        h = out["gain"]["held_out"]
        for key, name in (("default", DEFAULT_CRITERION), ("recommended", out["recommended"])):
            if name is None:
                continue
            v = h[name]
            out[f"verdict_{key}"] = {
                "criterion": name, "beats_mean": f"{v['beats_mean']}/{v['materials']}", "sign_test_p": v["sign_test_p"],
                "median_score": v["median_score"], "median_spearman": v["median_spearman"],
                "met": bool(v["beats_mean"] > v["materials"] / 2 and v["sign_test_p"] < 0.05
                            and v["median_score"] is not None and v["median_score"] >= 0.8),
                "spearman_met": bool(v["median_spearman"] is not None and v["median_spearman"] >= 0.6)}
    return out


def shipped_summary(summ: dict, config: dict) -> dict:
    """What `virheo design` reads: per criterion on the held-out materials, how often the pick came within
    ``WITHIN`` of the best candidate, beat the candidate mean, and its median realised gain."""
    held = summ["gain"]["held_out"]
    return {"study": "virheo study design-information", "config": config, "within": WITHIN,
            "recommended": summ["recommended"], "median_gain_seeded": summ["median_gain_seeded"],
            "criteria": {k: {f: v[f] for f in ("within", "beats_mean", "materials", "sign_test_p", "median_score",
                                               "median_spearman", "median_gain")} for k, v in held.items()}}


def validation(criterion: str, theta: str, path=SUMMARY_FILE) -> dict | None:
    """The shipped held-out figures of ``criterion`` ("perpendicularity" or "eig") with Theta map ``theta``
    ("reference", "fitted"), as validated; None when that combination was not validated (a custom map)."""
    from mpm.files import read_json

    name = "eig" if criterion == "eig" and theta == "reference" else (
        f"perpendicularity-{theta}" if criterion == "perpendicularity" else None)
    if name is None or not Path(path).is_file():
        return None
    data = read_json(path)
    if name not in data["criteria"]:
        return None
    return {"name": name, **data["criteria"][name], "recommended": data["recommended"], "within_fraction": data["within"],
            "median_gain_seeded": data["median_gain_seeded"], "largest": data["criteria"].get("largest")}


def reliability_line(v: dict | None) -> str:
    """How reliable the criterion proved, for users (a second line says when it proved weak), or "not validated"."""
    if v is None:
        return ("reliability: not validated (virheo study design-information checked EIG with the published Theta map "
                "and perpendicularity with the published and the fitted one)")
    line = (f"reliability: within {100 * v['within_fraction']:.0f} % of the best candidate in {v['within']} of "
            f"{v['materials']} validation materials, better than the candidates' mean in {v['beats_mean']} of "
            f"{v['materials']} (median normalised score {v['median_score']:.2f})")
    if v["sign_test_p"] >= 0.05:
        worse = v["median_score"] is not None and v["median_score"] < 0
        line += (f"\n  weak: this criterion did not beat the average random setup (sign test p = {v['sign_test_p']:.2g})"
                 + ("; its picks realised less information than a random setup, so treat the proposal as a hint on "
                    "the direction only" if worse else ", so the choice of setup matters little"))
        big = v.get("largest")
        if big:
            line += (f"; larger boxes realised more: {LARGEST} mm came within {100 * v['within_fraction']:.0f} % of the "
                     f"best candidate in {big['within']} of {big['materials']}")
    return line


# -- maps and posterior check ----------------------------------------------------------------------------------
def map_sizes(steps: int) -> np.ndarray:
    lo, hi = SETUP_RANGE_MM
    return np.round(np.linspace(lo, hi, steps))


def information_map(out, rec: dict, *, steps: int, forward, tick=None) -> dict:
    """Realised gain over a ``steps`` x ``steps`` grid of setups after the material's first setup; kept in
    ``maps/map_XX.json`` and read back."""
    from mpm.files import read_json
    from similarity.estimate import get_preset

    path = Path(out) / "maps" / f"map_{rec['case']:02d}.json"
    cfg = rec["config"]
    if path.is_file():
        m = read_json(path)
        if m.get("steps") == steps and m.get("config") == cfg:
            return m
    sizes = map_sizes(steps)
    setups = [Setup(float(w), float(h)) for h in sizes for w in sizes]
    losses = stencil_losses(Material(**rec["truth"]), setups, preset=get_preset(cfg["preset"]), fd_step=cfg["fd_step"],
                            forward=forward, tick=tick)
    hs = hessians_of(losses, cfg["fd_step"])
    gain = gains(rec["hessian_first"], hs)
    m = {"case": rec["case"], "config": cfg, "steps": steps, "sizes_mm": sizes.tolist(),
         "stencil_losses": [[None if not np.isfinite(v) else float(v) for v in row] for row in losses],
         "gain": gain.reshape(steps, steps).tolist()}
    write_json(path, m)
    return m


def posterior_volume(out, rec: dict, *, forward, points: int = 40, half_width: float = 0.15, min_ess: float = 400.0,
                     max_steps: int = 6000) -> dict:
    """For every candidate of a material: the log-volume 1/2 log det(cov) of the emcee posterior (normalised space)
    of the two-setup footage (first setup + candidate), the loss emulated (:class:`surrogate.emulator.LossEmulator`)
    from ``points`` space-filling simulations in the box truth +- ``half_width`` (the prior, cut to that box);
    eq. (1) of :mod:`similarity.likelihood` with one residual per frame and s^2 = the stage-1 estimate's loss (the
    misfit a user saw after setup 1) + the emulators' mean held-out RMSE, one tau for every candidate of the
    material.  Kept in ``posterior_check/check_XX.json``."""
    from mpm.files import read_json
    from similarity.belief import frames_precision
    from similarity.emulation import emulate
    from similarity.estimate import get_preset
    from similarity.mcmc import sample
    from similarity.space import denormalize, normalize
    from surrogate.emulator import LossEmulator, box, space_filling

    path = Path(out) / "posterior_check" / f"check_{rec['case']:02d}.json"
    cfg = rec["config"]
    if path.is_file():
        c = read_json(path)
        if c.get("config") == cfg:
            return c
    preset = get_preset(cfg["preset"])
    truth = Material(**rec["truth"])
    u = normalize(truth.as_array())
    X = np.vstack([u, space_filling(u, half_width, points, seed=rec["case"])])
    mats = [Material.from_array(denormalize(x)) for x in X]
    setups = [Setup.parse(rec["first_setup"])] + [Setup.parse(s) for s in rec["candidates"]]
    shots = emulate(truth, setups, density=DENSITY, preset=preset, forward=forward)
    losses = forward.losses(mats, shots, preset.final)  # (points + 1, setups)
    test = np.zeros(len(X), bool)
    test[np.random.default_rng(rec["case"]).choice(len(X), size=len(X) // 5, replace=False)] = True
    emus, rmse = [], []
    for k in range(1, len(setups)):
        y = losses[:, [0, k]].mean(axis=1)
        ok = np.isfinite(y)
        rmse.append(LossEmulator(seed=0).validate(X[ok & ~test], y[ok & ~test], X[ok & test], y[ok & test]).rmse)
        emus.append(LossEmulator(seed=0).fit(X[ok], y[ok]))
    tau = frames_precision(rec["stage_1"]["loss"] + float(np.mean(rmse)), 2 * rec["frames_per_setup"])
    lo, hi = box(u, half_width)
    logvol = []
    for emu in emus:
        def log_prob(x, emu=emu):
            x = np.atleast_2d(x)
            inside = np.all((x >= lo) & (x <= hi), axis=1)
            val = np.full(len(x), -np.inf)
            if inside.any():
                val[inside] = -tau * emu.predict(x[inside])
            return val

        post = sample(log_prob, u, seed=0, min_ess=min_ess, max_steps=max_steps)
        logvol.append(0.5 * float(np.linalg.slogdet(post.cov)[1]))
    c = {"case": rec["case"], "config": cfg, "points": points, "half_width": half_width, "tau": tau,
         "emulator_rmse": rmse, "candidates": rec["candidates"], "log_volume": logvol}
    write_json(path, c)
    return c


def volume_agreement(check: dict, rec: dict) -> dict:
    """Spearman between -log posterior volume and each measure's realised gain over a material's candidates."""
    return {m: I.rank_agreement(-np.array(check["log_volume"]), case_gains(rec, m)) for m in MEASURES}


# -- the study --------------------------------------------------------------------------------------------------
def case_folder(out, index: int) -> Path:
    return Path(out) / "cases" / f"case_{index:02d}"


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
    """Run (or resume) the study (module docstring) and write its outputs; ``forward`` simulates."""
    from studies.calibration import design
    from surrogate.theta import load

    check_options(materials, held_out, candidates, preset, generations, fd_step, seed, maps, map_steps, posterior_check)
    if forward.store is None:
        raise ValueError("the design-information study needs a simulation store")
    config = _config(materials, held_out, candidates, preset, generations, fd_step, seed, forward.simulator)
    thetas = {t: load(t) for t in ("reference", "fitted")}
    tick = (lambda req, res, cached: progress({"event": "simulation", "cached": cached})) if progress else None
    say = (lambda text: progress({"event": "message", "text": text})) if progress else (lambda text: None)
    t0 = time.perf_counter()
    recs = []
    for i, (truth, first) in enumerate(design(materials, seed)):
        say(f"material {i + 1}/{materials}: eta={truth.eta:.3g} n={truth.n:.3g} sigma_y={truth.sigma_y:.3g}, "
            f"first setup {first}")
        rec = run_case(case_folder(out, i), i, truth, first, config=config, forward=forward, thetas=thetas, tick=tick)
        recs.append(rec)
        say("  scores: " + ", ".join(f"{k} {v['score']:.2f} ({v['pick']})" for k, v in case_scores(rec).items()))
    for rec in recs[:maps]:
        say(f"information map of material {rec['case']} ({map_steps} x {map_steps} setups)")
        information_map(out, rec, steps=map_steps, forward=forward, tick=tick)
    for rec in recs[:posterior_check]:
        say(f"posterior check of material {rec['case']} ({len(rec['candidates'])} candidates)")
        posterior_volume(out, rec, forward=forward)
    return write(out, wall_seconds=time.perf_counter() - t0)


def records(out) -> list[dict]:
    return finished_cases(out, "cases/case_*/case.json")


def _fmt(v, spec=".2f") -> str:
    return "-" if v is None or (isinstance(v, float) and not np.isfinite(v)) else format(v, spec)


def table_markdown(recs: list[dict], summ: dict, checks: list[dict]) -> str:
    names = list(recs[0]["config"]["criteria"])
    n_sel = summ["selection"]
    lines = ["| material | set | truth (eta, n, sigma_y) | first setup | stage-1 E_rel | "
             + " | ".join(f"{n}: pick, score" for n in names) + " |", "|---:|---|---|---|---:|" + "---|" * len(names)]
    for k, r in enumerate(recs):
        t, sc = r["truth"], case_scores(r)
        lines.append(f"| {r['case']} | {'selection' if k < n_sel else 'held out'} | {t['eta']:.3g}, {t['n']:.3g}, "
                     f"{t['sigma_y']:.3g} | {r['first_setup']} | {r['stage_1']['e_rel']:.3f} | "
                     + " | ".join(f"{sc[n]['pick']}{' (fallback)' if n in r['fallbacks'] else ''}, "
                                  f"{_fmt(sc[n]['score'])}" for n in names) + " |")
    for measure, label in MEASURE_LABELS.items():
        for part in ("selection", "held_out"):
            per = summ[measure][part]
            if not per:
                continue
            lines += ["", f"{label}, {part.replace('_', ' ')} ({summ[part]} materials):", "",
                      "| criterion | beats candidate mean | sign test p | median normalised score | "
                      f"within {100 * WITHIN:.0f} % of best | median Spearman |", "|---|---:|---:|---:|---:|---:|"]
            for n, v in per.items():
                lines.append(f"| {n} | {v['beats_mean']}/{v['materials']} | {_fmt(v['sign_test_p'], '.3g')} | "
                             f"{_fmt(v['median_score'])} | {v['within']}/{v['materials']} | "
                             f"{_fmt(v['median_spearman'])} |")
    lines += ["", "Recommended on the selection materials (the largest positive median normalised score of the criteria "
              f"`virheo design` offers): {summ['recommended'] or 'none, no criterion beats the candidate mean'}."]
    if checks:
        lines += ["", "Posterior check (Spearman between -log posterior volume and the realised gain, per material):",
                  "", "| material | candidates | " + " | ".join(MEASURES) + " |", "|---:|---:|" + "---:|" * len(MEASURES)]
        for c in checks:
            rho = volume_agreement(c, recs[c["case"]])
            lines.append(f"| {c['case']} | {len(c['candidates'])} | " + " | ".join(_fmt(rho[m]) for m in MEASURES)
                         + " |")
    return "\n".join(lines) + "\n"


def plot_predicted(path, recs: list[dict]) -> Path:
    """Per ranked criterion: predicted information (ranks within the material) against realised gain (ranks)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy.stats import rankdata

    names = [n for n in recs[0]["config"]["criteria"] if n != "random"]
    fig, axes = plt.subplots(1, len(names), figsize=(3.4 * len(names), 3.4), dpi=100, squeeze=False)
    for ax, n in zip(axes[0], names):
        xs, ys = [], []
        for r in recs:
            pred = r["predicted"][n]
            if all(p is None for p in pred):
                continue
            worst = min(p for p in pred if p is not None) - 1.0
            g = case_gains(r)
            ok = np.isfinite(g)
            m = len(g[ok])
            xs += list((rankdata(np.array([worst if p is None else p for p in pred])[ok]) - 0.5) / m)
            ys += list((rankdata(g[ok]) - 0.5) / m)
        med = np.nanmedian([case_scores(r)[n]["spearman"] for r in recs])
        ax.plot(xs, ys, "o", ms=3, alpha=0.5, color=COLOURS.get(n))
        ax.plot([0, 1], [0, 1], ":", color="k", lw=1)
        ax.set(xlabel="predicted information (rank fraction)", ylabel="realised gain (rank fraction)",
               title=f"{n}\nmedian Spearman {med:.2f}")
        ax.title.set_fontsize(8)
    return save_figure(fig, path)


def plot_maps(path, maps: list[dict], recs: list[dict]) -> Path:
    """Fig. 10-style maps of realised gain over the setup grid, first setup and picks marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(maps), figsize=(4.6 * len(maps), 4.6), dpi=100, squeeze=False)
    for ax, m in zip(axes[0], maps):
        r = recs[m["case"]]
        s = np.array(m["sizes_mm"])
        half = (s[1] - s[0]) / 2
        im = ax.imshow(np.array(m["gain"], float), origin="lower", cmap="viridis", interpolation="nearest",
                       extent=(s[0] - half, s[-1] + half, s[0] - half, s[-1] + half))
        fig.colorbar(im, ax=ax, label="realised gain log det")
        f = Setup.parse(r["first_setup"])
        ax.plot(f.width_mm, f.height_mm, "X", color="w", mec="k", ms=11, label="setup 1")
        for k, (n, pick) in enumerate(r["picks"].items()):  # shrinking markers: picks that coincide stay visible
            p = Setup.parse(pick)
            ax.plot(p.width_mm, p.height_mm, "o", color=COLOURS.get(n), mec="k", ms=14 - 2.5 * k, label=n,
                    clip_on=False)
        t = r["truth"]
        ax.set(xlabel="width W [mm]", ylabel="height H [mm]",
               title=f"eta={t['eta']:.3g}, n={t['n']:.3g}, sigma_y={t['sigma_y']:.3g}")
        ax.title.set_fontsize(8)
        ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=3, frameon=False)
    return save_figure(fig, path)


def write(out, *, wall_seconds: float | None = None) -> dict:
    """design_information.json/.md, predicted_vs_realised.png and maps.png from every finished part under ``out``."""
    from mpm.files import read_json

    out = Path(out)
    recs = records(out)
    summ = summary(recs)
    checks = [read_json(p) for p in sorted(out.glob("posterior_check/check_*.json"))]
    maps = [read_json(p) for p in sorted(out.glob("maps/map_*.json"))]
    plot_predicted(out / "predicted_vs_realised.png", recs)
    if maps:
        plot_maps(out / "maps.png", maps, recs)
    checks = [c | {"spearman": volume_agreement(c, recs[c["case"]])} for c in checks]
    shipped = shipped_summary(summ, recs[0]["config"]) if summ["held_out"] else None
    if shipped:  # studies/data/design_validation.json is this file of the documented run
        write_json(out / "design_validation.json", shipped)
    result = {"config": recs[0]["config"], "summary": summ, "shipped": shipped,
              "posterior_check": checks, "wall_seconds": wall_seconds, "cases": recs}
    return write_study(out, "design_information", result, table_markdown(recs, summ, checks))
