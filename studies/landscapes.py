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

The study runs on :class:`studies.study.Study`, pair by pair: each pair's footage, then its block and stencil in
one batch through :meth:`mpm.forward.Forward.pair_losses` and the store; a finished pair is kept in
``cases/pair_NNN/case.json``, and a killed study re-run with the same arguments reads those back and serves
from the store what the unfinished pair had simulated. With
``grid=3`` and ``half_width=fd_step`` the block contains the stencil, so a pair costs 26 simulations
plus its reference.

Matching: for each candidate wall stress C = P L of the 1D search (P fixed, as in
:mod:`surrogate.theta`) the plane-Poiseuille loss normal is computed (:func:`similarity.normals.normals_at`)
and scored by eq. 43 against the landscape, refined by trilinear interpolation to a spacing of d0 / 2
(:func:`surrogate.theta_fit.refined_landscape`); the best C is the target of the Theta fit.
``virheo theta fit`` re-matches every landscape from its stored losses, so a fit never depends on the
match stored in a study folder.

Folder layout: ``study.json`` (the configuration, materials and setups), ``cases/pair_NNN/case.json`` (one
finished pair), ``landscapes.json`` (per pair: loss values, Hessian, spectrum, matching; the summary),
``landscapes.md`` (the table) and ``landscape_*.png`` (Fig. 6-style slices).
"""
from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from mpm.files import JsonRecord, read_json
from mpm.params import DEFAULT_DENSITY_KG_M3, Material, Setup
from similarity import estimate as E
from similarity.emulation import probe_pairs
from similarity.fd_hessian import angle_deg, hessian_from_stencil, spectrum, stencil
from similarity.normals import P_SEARCH, normals_at
from similarity.space import denormalize, normalize
from similarity.progress import simulation_tick
from studies.conditioning import conditioning  # noqa: F401 (re-exported)
from studies.landscape_plots import plot_slices
from studies.report import write_json
from studies.sampling import poisson_disk, random_setups  # noqa: F401 (poisson_disk re-exported)
from studies.study import Study
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
@dataclass(frozen=True)
class LandscapeCase:
    """One (M, S) pair of the study and the folder its case.json goes to."""

    index: int
    pair: Pair
    folder: Path


@dataclass
class LandscapeRecord(JsonRecord):
    """One finished pair: the block's losses, the FD Hessian and its spectrum (None where a probe failed), the
    match to the plane-Poiseuille normal (None for a flat landscape) and the simulations the pair needed."""

    config: dict
    material: Material
    setup: Setup
    losses: list
    hessian: list | None
    q_max: list | None
    eigenvalues: list | None
    condition: float | None
    match: dict | None
    simulations: int

    READERS = {"material": lambda d: Material(**d), "setup": lambda d: Setup(**d)}

    def pair_dict(self) -> dict:
        """The pair as ``landscapes.json`` lists it."""
        d = self.to_dict()
        return {k: d[k] for k in ("material", "setup", "losses", "hessian", "q_max", "eigenvalues", "condition",
                                  "match")}

    @property
    def angle_fd_deg(self) -> float | None:
        return None if self.match is None else self.match.get("angle_fd_deg")


@dataclass
class LandscapeSummary(JsonRecord):
    pairs: int
    matched: int  # pairs with a landscape to match and an FD normal to compare with
    median_angle_fd_deg: float | None  # FD loss normal against the matched plane-Poiseuille normal
    simulations: int


class LandscapeStudy(Study):
    """The study case by case: footage of M in S, then the block and the FD stencil around M in one batch."""

    name = "landscapes"
    record = LandscapeRecord
    case_files = ("cases/pair_*/case.json",)

    def __init__(self, out, config: StudyConfig | None = None, *, plots: int = 0, pairs: list | None = None):
        super().__init__(out, None if config is None else config.to_dict())
        self.study, self.plot_count = config, plots
        self.pairs = pairs if pairs is not None or config is None else sample_pairs(config)

    def cases(self):
        return [LandscapeCase(i, p, self.out / "cases" / f"pair_{i:03d}") for i, p in enumerate(self.pairs)]

    def announce(self, case) -> str:
        return f"pair {case.index + 1}: {case.pair.material} in {case.pair.setup} mm"

    def run_case(self, case, *, forward, progress=None) -> LandscapeRecord:
        config, (material, setup) = self.study, (case.pair.material, case.pair.setup)
        preset = E.get_preset(config.preset)
        footage = E.emulate(material, [setup], density=config.density, preset=preset, forward=forward)[0]
        block, probes = grid_offsets(config.grid, config.half_width), stencil(config.fd_step)
        jobs = probe_pairs([(material, footage)], np.vstack([block, probes]))
        row = forward.pair_losses(jobs, preset.final, simulation_tick(progress))
        grid_losses, fd = row[: len(block)], row[len(block):]
        hessian, spec = None, {"q_max": None, "eigenvalues": None, "condition": None}
        if np.all(np.isfinite(fd)):
            hessian = hessian_from_stencil(fd, config.fd_step)
            spec = spectrum(hessian).to_dict()
        mt = None
        if np.any(np.isfinite(grid_losses)) and np.nanmax(grid_losses) > 0:
            mt = match(material, grid_losses, config.grid, config.half_width)
            if spec["q_max"] is not None:
                mt["angle_fd_deg"] = float(angle_deg(spec["q_max"], mt["q_pp"]))
        simulations = len({forward.request(m, e, preset.final).key for m, e in jobs}) + 1  # + the footage
        return LandscapeRecord(self.config, material, setup, grid_losses.tolist(),
                               None if hessian is None else hessian.tolist(), spec["q_max"], spec["eigenvalues"],
                               spec["condition"], mt, simulations)

    def summary(self, records) -> LandscapeSummary:
        angles = [r.angle_fd_deg for r in records if r.angle_fd_deg is not None]
        return LandscapeSummary(len(records), len(angles), float(np.median(angles)) if angles else None,
                                sum(r.simulations for r in records))

    def table(self, records, summary) -> str:
        lines = ["| pair | eta [Pa s^n] | n | sigma_y [Pa] | setup [mm] | condition | C [Pa] | angle FD vs PP [deg] |",
                 "|---|---|---|---|---|---|---|---|"]
        for i, r in enumerate(records):
            m, c = r.material, r.match or {}
            cond = "-" if r.condition is None else f"{r.condition:.3g}"
            angle = "-" if r.angle_fd_deg is None else f"{r.angle_fd_deg:.1f}"
            lines.append(f"| {i} | {m.eta:.3g} | {m.n:.3g} | {m.sigma_y:.3g} | {r.setup} | {cond} | "
                         f"{c.get('C_Pa', float('nan')):.3g} | {angle} |")
        median = "-" if summary.median_angle_fd_deg is None else f"{summary.median_angle_fd_deg:.1f} deg"
        return "\n".join(lines + ["", f"{summary.pairs} pairs, {summary.simulations} simulations; median angle "
                                       f"between the FD loss normal and the matched Poiseuille normal: {median}", ""])

    def plots(self, records, summary) -> None:
        block = grid_offsets(self.study.grid, self.study.half_width)
        for k, rec in enumerate(records[: self.plot_count]):
            if rec.match is not None:
                plot_slices(self.out / f"landscape_{k:02d}.png", rec.pair_dict(), block, self.study.grid)

    def result(self, records, summary, wall_seconds) -> dict:
        config = self.study
        return {"format": FORMAT, "config": config.to_dict(),
                "offsets": grid_offsets(config.grid, config.half_width).tolist(),
                "fd_stencil": stencil(config.fd_step).tolist(), "pairs": [r.pair_dict() for r in records],
                "simulations": summary.simulations, "summary": summary.to_dict(), "wall_seconds": wall_seconds}


def _prepare(out: Path, config: StudyConfig, pairs: list) -> None:
    """study.json: the configuration and the pairs (a folder made with another configuration is refused)."""
    out.mkdir(parents=True, exist_ok=True)
    meta = {"format": FORMAT, "config": config.to_dict(),
            "pairs": [{"material": p.material.to_dict(), "setup": p.setup.to_dict()} for p in pairs]}
    path = out / STUDY_FILE
    if path.exists():
        old = json.loads(path.read_text())
        if old.get("config") != meta["config"]:
            raise ValueError(f"{out} holds a landscape study with another configuration; use another --out")
    else:
        write_json(path, meta)


def run(out, config: StudyConfig, *, forward, progress=None, plots: int = 3) -> dict:
    """Run (or resume, pair by pair) a landscape study in folder ``out``; returns the content of
    ``landscapes.json``."""
    config.check()
    pairs = sample_pairs(config)  # drawn once: study.json and the cases hold the same
    _prepare(Path(out), config, pairs)
    return LandscapeStudy(out, config, plots=plots, pairs=pairs).run(forward=forward, progress=progress)


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
