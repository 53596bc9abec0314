"""Loss-landscape studies of section 5: MPM landscapes, finite-difference loss normals, matching to the
plane-Poiseuille normal (eq. 43) and the data that Theta is fitted to (section 5.5).

A study draws materials M by Poisson-disk sampling in the normalised material space (or in a box of
it, ``StudyConfig.region``) and, for each, setups S from the 1 mm grid. For each pair (M, S) the
footage of M in S is emulated with the preset's forward model, and the loss L(M~, M; S) (eq. 3) is
evaluated

* on a regular ``grid`` ^ 3 block of points M~ around M, ``half_width`` either side in normalised
  coordinates (the landscape of Fig. 6), and
* on the 18-point finite-difference stencil of :mod:`similarity.fd_hessian` with step ``fd_step``,
  giving the Hessian, its eigenvalues, the loss normal q_max and the condition number.

Every simulation goes through :meth:`mpm.forward.Forward.pair_losses` and the store, all pairs in one
batch: a killed study re-run with the same arguments serves what finished from the store. With
``grid=3`` and ``half_width=fd_step`` the block contains the stencil, so a pair costs 26 simulations
plus its reference.

Matching: for each candidate wall stress C = P L of the 1D search (P fixed, as in
:mod:`surrogate.theta`) the plane-Poiseuille loss normal is computed (:func:`similarity.normals.normals_at`)
and scored by eq. 43 against the landscape, refined by trilinear interpolation to a spacing of d0 / 2
(:func:`surrogate.theta_fit.refined_landscape`); the best C is the target of the Theta fit.
``virheo theta fit`` re-matches every landscape from its stored losses, so a fit never depends on the
match stored in a study folder.

Folder layout: ``study.json`` (the configuration, materials and setups), ``landscapes.json`` (per pair:
loss values, Hessian, spectrum, matching), ``landscape_*.png`` (Fig. 6-style slices).
"""
from __future__ import annotations

import json
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from mpm.files import read_json
from mpm.params import DEFAULT_DENSITY_KG_M3, Material, Setup
from similarity import estimate as E
from similarity.emulation import probe_pairs
from similarity.fd_hessian import angle_deg, hessian_from_stencil, spectrum, stencil
from similarity.normals import P_SEARCH, normals_at
from similarity.space import denormalize, normalize
from similarity.progress import Message, simulation_tick
from studies.conditioning import conditioning  # noqa: F401 (re-exported)
from studies.landscape_plots import plot_slices
from studies.report import write_json
from studies.sampling import poisson_disk, random_setups  # noqa: F401 (poisson_disk re-exported)
from surrogate import theta_fit

STUDY_FILE = "study.json"
RESULT_FILE = "landscapes.json"
FORMAT = "virheometry-landscapes/1"
C_SEARCH = np.geomspace(0.5, 2000.0, 400)  # Pa: candidate wall stresses C = P L of the 1D search


@dataclass(frozen=True)
class StudyConfig:
    """Size and resolution of a landscape study."""

    materials: int = 10
    setups_per_material: int = 3
    grid: int = 3  # points per axis of the landscape block
    half_width: float = 0.05  # normalised half-width of the block
    fd_step: float = 0.05  # finite-difference step (normalised)
    preset: str = "demo"
    seed: int = 0
    density: float = DEFAULT_DENSITY_KG_M3
    region: tuple | None = None  # SI box ((eta_lo, eta_hi), (n_lo, n_hi), (sy_lo, sy_hi)); None: the space

    def check(self) -> "StudyConfig":
        if self.materials < 1 or self.setups_per_material < 1:
            raise ValueError(f"a study needs >= 1 material and >= 1 setup per material "
                             f"(got {self.materials} and {self.setups_per_material})")
        if self.grid < 2:
            raise ValueError(f"--grid {self.grid}: a landscape grid needs at least 2 points per axis")
        for name in ("half_width", "fd_step"):
            v = getattr(self, name)
            if not 0 < v <= 0.2:
                raise ValueError(f"{name}={v} must lie in (0, 0.2] (normalised material space)")
        E.get_preset(self.preset)
        if self.region is not None:
            self.region_box()
        return self

    def region_box(self) -> tuple[np.ndarray, np.ndarray]:
        """Normalised corners (lo, hi) of the box the materials are drawn from: ``region`` within the margin."""
        lo, hi = np.full(3, self.margin), np.full(3, 1.0 - self.margin)
        if self.region is None:
            return lo, hi
        r = np.asarray(self.region, dtype=float)
        if r.shape != (3, 2) or not np.all(np.isfinite(r)) or np.any(r[:, 0] >= r[:, 1]):
            raise ValueError("region must give a range lo:hi with lo < hi for each of eta, n, sigma_y")
        a, b = np.maximum(lo, normalize(r[:, 0])), np.minimum(hi, normalize(r[:, 1]))
        if np.any(b - a < 1e-3):
            names = ", ".join(k for k, bad in zip(("eta", "n", "sigma_y"), b - a < 1e-3) if bad)
            raise ValueError(f"region leaves no room for materials in {names}: probes {self.margin:.2f} "
                             "(normalised) either side must stay inside the material space")
        return a, b

    def to_dict(self) -> dict:
        """The configuration as stored in study.json (``region`` only when set)."""
        d = asdict(self)
        if self.region is None:
            del d["region"]
        else:
            d["region"] = [list(map(float, r)) for r in self.region]
        return d

    @property
    def margin(self) -> float:
        """Materials stay this far from the faces of [0, 1]^3, so every probe is inside the space."""
        return max(self.half_width, self.fd_step) + 0.02


@dataclass
class Pair:
    material: Material
    setup: Setup


# -- sampling: studies.sampling ------------------------------------------------------------------------
def grid_offsets(size: int, half_width: float) -> np.ndarray:
    """Offsets (size^3, 3) of a regular block [-half_width, half_width]^3, index order (eta, n, sigma_y)."""
    if size < 2:
        raise ValueError(f"grid size {size}: a landscape grid needs at least 2 points per axis")
    axis = half_width * np.linspace(-1.0, 1.0, size)
    g = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), axis=-1)
    return g.reshape(-1, 3)


def sample_pairs(config: StudyConfig) -> list[Pair]:
    """The study's (M, S) pairs: Poisson-disk materials (in ``config.region``), each with its own random setups."""
    pts, _ = poisson_disk(config.materials, config.seed, box=config.region_box())
    rng = np.random.default_rng(config.seed)
    pairs = []
    for u in pts:
        m = Material.from_array(denormalize(u))
        pairs += [Pair(m, s) for s in random_setups(config.setups_per_material, rng, replace=False)]
    return pairs


# -- matching ------------------------------------------------------------------------------------------
def poiseuille_normals(material: Material, c_pa=C_SEARCH) -> np.ndarray:
    """Plane-Poiseuille loss normals (k, 3) of ``material`` for wall stresses ``c_pa`` (NaN where no flow)."""
    c = np.asarray(c_pa, dtype=float)
    q = normals_at(np.broadcast_to(material.as_array(), (len(c), 3)), np.full_like(c, P_SEARCH), c / P_SEARCH)
    return np.where((c > material.sigma_y)[:, None], q, np.nan)


def match(material: Material, losses, grid: int, half_width: float, c_pa=C_SEARCH, d0: float = theta_fit.D0) -> dict:
    """The best wall stress C of the 1D search for one ``grid``^3 landscape (eq. 43, on the landscape
    refined by :func:`surrogate.theta_fit.refined_landscape`) and its normal."""
    q = poiseuille_normals(material, c_pa)
    i, scores = theta_fit.best_match(*theta_fit.refined_landscape(losses, grid, half_width, d0), q, d0)
    return {"C_Pa": float(np.asarray(c_pa)[i]), "score": float(scores[i]), "q_pp": q[i].tolist(),
            "scores": [None if not np.isfinite(s) else float(s) for s in scores]}


# -- the study -----------------------------------------------------------------------------------------
def _prepare(out: Path, config: StudyConfig) -> list[Pair]:
    out.mkdir(parents=True, exist_ok=True)
    pairs = sample_pairs(config)
    meta = {"format": FORMAT, "config": config.to_dict(),
            "pairs": [{"material": p.material.to_dict(), "setup": p.setup.to_dict()} for p in pairs]}
    path = out / STUDY_FILE
    if path.exists():
        old = json.loads(path.read_text())
        if old.get("config") != meta["config"]:
            raise ValueError(f"{out} holds a landscape study with another configuration; use another --out")
    else:
        write_json(path, meta)
    return pairs


def run(out, config: StudyConfig, *, forward, progress=None, plots: int = 3) -> dict:
    """Run (or resume) a landscape study in folder ``out``; returns the content of ``landscapes.json``."""
    config.check()
    out = Path(out)
    t0 = time.perf_counter()
    pairs = _prepare(out, config)
    preset = E.get_preset(config.preset)
    say = (lambda text: progress(Message(text))) if progress else (lambda text: None)

    # ground-truth footage, one batch for all pairs
    by_material: dict = {}
    for i, p in enumerate(pairs):
        by_material.setdefault(p.material, []).append(i)
    say(f"{len(pairs)} pairs: simulating the ground-truth footage")
    frames = [None] * len(pairs)
    for m, idx in by_material.items():
        shots = E.emulate(m, [pairs[i].setup for i in idx], density=config.density, preset=preset, forward=forward)
        for i, e in zip(idx, shots):
            frames[i] = e

    block = grid_offsets(config.grid, config.half_width)
    probes = stencil(config.fd_step)
    offsets = np.vstack([block, probes])
    jobs = probe_pairs([(p.material, ref) for p, ref in zip(pairs, frames)], offsets)
    say(f"{len(jobs)} landscape probes ({len(offsets)} per pair)")
    tick = simulation_tick(progress)
    losses = forward.pair_losses(jobs, preset.final, tick).reshape(len(pairs), -1)

    records = []
    for p, row in zip(pairs, losses):
        grid_losses, fd = row[: len(block)], row[len(block):]
        rec = {"material": p.material.to_dict(), "setup": p.setup.to_dict(), "losses": row[: len(block)].tolist()}
        if np.all(np.isfinite(fd)):
            spec = spectrum(hessian_from_stencil(fd, config.fd_step))
            rec |= {"hessian": hessian_from_stencil(fd, config.fd_step).tolist(), **spec.to_dict()}
        else:
            rec |= {"hessian": None, "q_max": None, "eigenvalues": None, "condition": None}
        if np.any(np.isfinite(grid_losses)) and np.nanmax(grid_losses) > 0:
            mt = match(p.material, grid_losses, config.grid, config.half_width)
            rec["match"] = mt
            if rec["q_max"] is not None:
                rec["match"]["angle_fd_deg"] = float(angle_deg(rec["q_max"], mt["q_pp"]))
        else:
            rec["match"] = None
        records.append(rec)
    simulations = len({forward.request(m, e, preset.final).key for m, e in jobs}) + len(pairs)
    result = {"format": FORMAT, "config": config.to_dict(), "offsets": block.tolist(),
              "fd_stencil": probes.tolist(), "pairs": records, "simulations": simulations,
              "wall_seconds": time.perf_counter() - t0}
    write_json(out / RESULT_FILE, result)
    for k, rec in enumerate(records[:plots]):
        if rec["match"] is not None:
            plot_slices(out / f"landscape_{k:02d}.png", rec, block, config.grid)
    return result


def load(folder) -> dict:
    """A finished study's ``landscapes.json`` (ValueError / FileNotFoundError for anything else)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise NotADirectoryError(f"{folder} is not a folder (expected a landscape study written by 'virheo study landscapes')")
    path = folder / RESULT_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{folder} is not a finished landscape study: no {RESULT_FILE} "
                                "(run 'virheo study landscapes --out FOLDER' first)")
    data = read_json(path)
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise ValueError(f"{path} is not a landscape study file (format {FORMAT})")
    return data
