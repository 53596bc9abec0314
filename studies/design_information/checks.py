"""The two optional parts of `virheo study design-information` (:mod:`studies.design_information`), each run after
the materials and kept in its own JSON so that a killed study resumes:

* a Fig. 10-style **map** of realised information over a coarse grid of setups after a material's first setup
  (``maps/map_XX.json``);
* a **posterior check**: for every candidate of a material, the volume of an emcee posterior (eq. 1 of
  :mod:`similarity.likelihood` on an emulated two-setup loss) against the realised gain
  (``posterior_check/check_XX.json``).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mpm.files import JsonRecord, read_json, write_json
from mpm.params import SETUP_RANGE_MM, Material, Setup
from similarity import information as I


@dataclass
class InformationMap(JsonRecord):
    """Realised gain (log det) over a ``steps`` x ``steps`` grid of setups (rows: heights, columns: widths)."""

    case: int
    config: dict
    steps: int
    sizes_mm: list
    stencil_losses: list  # (steps * steps, 18), None where a simulation failed
    gain: list  # (steps, steps)


@dataclass
class CandidateVolumes(JsonRecord):
    """The emcee posterior log-volume of each candidate of a material."""

    case: int
    config: dict
    points: int
    half_width: float
    tau: float
    emulator_rmse: list
    candidates: list
    log_volume: list  # 1/2 log det(cov) in the normalised space, per candidate
    spearman: dict | None = None  # measure -> Spearman(-log volume, gain) (:func:`volume_agreement`), in the result

    OMIT_IF_NONE = ("spearman",)


def map_sizes(steps: int) -> np.ndarray:
    lo, hi = SETUP_RANGE_MM
    return np.round(np.linspace(lo, hi, steps))


def map_path(out, case: int) -> Path:
    return Path(out) / "maps" / f"map_{case:02d}.json"


def check_path(out, case: int) -> Path:
    return Path(out) / "posterior_check" / f"check_{case:02d}.json"


def information_map(out, rec, *, steps: int, forward, tick=None) -> InformationMap:
    """Realised gain over a ``steps`` x ``steps`` grid of setups after the first setup of material ``rec`` (an
    :class:`studies.design_information.InformationRecord`); kept in ``maps/map_XX.json`` and read back."""
    from similarity.estimate import get_preset

    path, cfg = map_path(out, rec.case), rec.config
    if path.is_file():
        m = read_json(path)
        if m.get("steps") == steps and m.get("config") == cfg:
            return InformationMap.from_dict(m)
    sizes = map_sizes(steps)
    setups = [Setup(float(w), float(h)) for h in sizes for w in sizes]
    losses = I.stencil_losses(rec.truth, setups, preset=get_preset(cfg["preset"]), fd_step=cfg["fd_step"],
                              forward=forward, tick=tick)
    gain = I.realised_gains(rec.hessian_first, I.setup_hessians(losses, cfg["fd_step"]))
    m = InformationMap(case=rec.case, config=cfg, steps=steps, sizes_mm=sizes.tolist(), stencil_losses=losses.tolist(),
                       gain=gain.reshape(steps, steps).tolist())
    write_json(path, m)
    return m


def posterior_volume(out, rec, *, forward, points: int = 40, half_width: float = 0.15, min_ess: float = 400.0,
                     max_steps: int = 6000) -> CandidateVolumes:
    """For every candidate of material ``rec``: the log-volume 1/2 log det(cov) of the emcee posterior (normalised
    space) of the two-setup footage (first setup + candidate), the loss emulated
    (:class:`surrogate.emulator.LossEmulator`) from ``points`` space-filling simulations in the box truth +-
    ``half_width`` (the prior, cut to that box); eq. (1) of :mod:`similarity.likelihood` with one residual per
    frame and s^2 = the stage-1 estimate's loss (the misfit a user saw after setup 1) + the emulators' mean
    held-out RMSE, one tau for every candidate of the material.  Kept in ``posterior_check/check_XX.json``."""
    from similarity.belief import frames_precision
    from similarity.emulation import emulate
    from similarity.estimate import get_preset
    from similarity.mcmc import sample
    from similarity.space import denormalize, normalize
    from surrogate.emulator import LossEmulator, box, space_filling

    path, cfg = check_path(out, rec.case), rec.config
    if path.is_file():
        c = read_json(path)
        if c.get("config") == cfg:
            return CandidateVolumes.from_dict(c)
    preset = get_preset(cfg["preset"])
    u = normalize(rec.truth.as_array())
    X = np.vstack([u, space_filling(u, half_width, points, seed=rec.case)])
    mats = [Material.from_array(denormalize(x)) for x in X]
    setups = [Setup.parse(rec.first_setup)] + [Setup.parse(s) for s in rec.candidates]
    shots = emulate(rec.truth, setups, preset=preset, forward=forward)
    losses = forward.losses(mats, shots, preset.final)  # (points + 1, setups)
    test = np.zeros(len(X), bool)
    test[np.random.default_rng(rec.case).choice(len(X), size=len(X) // 5, replace=False)] = True
    emus, rmse = [], []
    for k in range(1, len(setups)):
        y = losses[:, [0, k]].mean(axis=1)
        ok = np.isfinite(y)
        rmse.append(LossEmulator(seed=0).validate(X[ok & ~test], y[ok & ~test], X[ok & test], y[ok & test]).rmse)
        emus.append(LossEmulator(seed=0).fit(X[ok], y[ok]))
    tau = frames_precision(rec.stage_1.loss + float(np.mean(rmse)), 2 * rec.frames_per_setup)
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
    c = CandidateVolumes(case=rec.case, config=cfg, points=points, half_width=half_width, tau=tau, emulator_rmse=rmse,
                       candidates=rec.candidates, log_volume=logvol)
    write_json(path, c)
    return c


def volume_agreement(check: CandidateVolumes, rec) -> dict:
    """Spearman between -log posterior volume and each measure's realised gain over a material's candidates."""
    return {m: I.rank_agreement(-np.array(check.log_volume), rec.realised(m)) for m in I.MEASURES}


def finished_maps(out) -> list[InformationMap]:
    return [InformationMap.from_dict(read_json(p)) for p in sorted(Path(out).glob("maps/map_*.json"))]


def finished_checks(out) -> list[CandidateVolumes]:
    return [CandidateVolumes.from_dict(read_json(p)) for p in sorted(Path(out).glob("posterior_check/check_*.json"))]
