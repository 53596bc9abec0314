"""Condition numbers of the finite-difference loss Hessian of one material over a grid of setups
(Fig. 9): ``conditioning.json`` and ``conditioning.png``.

The study runs on the skeleton of :mod:`studies.study`: one case per setup (the footage emulated at the material,
the 18-point stencil around it, ``cases/WxH/case.json``), so a killed study resumes where it stopped.
``conditioning.json`` holds the grid of condition numbers, the top eigenvectors and eigenvalues per setup, and the
configuration and cases beside them.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mpm.files import JsonRecord
from mpm.params import DEFAULT_DENSITY_KG_M3, SETUP_RANGE_MM, Material, Setup
from similarity.fd_hessian import hessian_from_stencil, spectrum, stencil
from similarity.space import normalize
from studies.report import save_figure
from studies.study import Study


def grid_sizes(steps: int) -> np.ndarray:
    """``steps`` widths (and heights) in mm, evenly over the setup space, rounded to the 1 mm grid."""
    lo, hi = SETUP_RANGE_MM
    return np.round(np.linspace(lo, hi, steps))


@dataclass(frozen=True)
class ConditioningCase:
    setup: Setup
    folder: Path


@dataclass
class SetupSpectrum(JsonRecord):
    """One setup's stencil losses and the spectrum of their Hessian (None where a simulation failed)."""

    config: dict
    setup: str
    stencil_losses: list  # 18, :func:`similarity.fd_hessian.stencil` order (None: failed)
    condition: float | None
    q_max: list | None
    eigenvalues: list | None
    simulations: int
    wall_seconds: float


class Conditioning(Study):
    name = "conditioning"
    record = SetupSpectrum
    case_files = ("cases/*/case.json",)

    def cases(self):
        sizes = grid_sizes(self.config["steps"])
        for h in sizes:  # rows = height, columns = width
            for w in sizes:
                s = Setup(float(w), float(h))
                yield ConditioningCase(s, self.out / "cases" / str(s))

    def run_case(self, case, *, forward, progress=None):
        from similarity.emulation import emulate, probe_losses
        from similarity.presets import get_preset
        from similarity.progress import simulation_tick

        t0, before = time.perf_counter(), forward.simulations_run
        c = self.config
        material, preset, step = Material(**c["material"]), get_preset(c["preset"]), c["fd_step"]
        tick = simulation_tick(progress)
        try:
            shot = emulate(material, [case.setup], density=c["density"], preset=preset, forward=forward,
                           on_result=tick)[0]
            row = probe_losses([(material, shot)], stencil(step), preset.final, forward, tick)[0]
        except RuntimeError:  # the footage failed
            row = np.full(len(stencil(step)), np.nan)
        cond = q = eig = None
        if np.all(np.isfinite(row)):
            sp = spectrum(hessian_from_stencil(row, step))
            cond, q, eig = float(sp.condition), sp.q_max.tolist(), sp.eigenvalues.tolist()
        return SetupSpectrum(c, str(case.setup), [float(v) if np.isfinite(v) else None for v in row], cond, q, eig,
                             forward.simulations_run - before, time.perf_counter() - t0)

    def summary(self, records):
        return None

    def table(self, records, summary) -> str:
        return ""

    def result(self, records, summary, wall_seconds) -> dict:
        c = self.config
        sizes = grid_sizes(c["steps"])
        by = {r.setup: r for r in records}
        order = [str(Setup(float(w), float(h))) for h in sizes for w in sizes]
        cond = np.array([np.nan if by.get(s) is None or by[s].condition is None else by[s].condition for s in order])
        face = [[np.nan if v is None else v for v in by[s].stencil_losses[:6]] if s in by else None for s in order]
        return {"material": c["material"], "fd_step": c["fd_step"], "preset": c["preset"],
                "widths_mm": sizes.tolist(), "heights_mm": sizes.tolist(),
                "condition": cond.reshape(len(sizes), len(sizes)).tolist(),
                "q_max": [by[s].q_max if s in by else None for s in order],
                "eigenvalues": [by[s].eigenvalues if s in by else None for s in order],
                "setups": order, "face_losses": face,
                "min": float(np.nanmin(cond)), "median": float(np.nanmedian(cond)), "max": float(np.nanmax(cond)),
                "simulations": len(order) * (len(stencil(c["fd_step"])) + 1), "wall_seconds": wall_seconds,
                "config": c, "cases": [by[s].to_dict() for s in order if s in by]}  # in grid order

    def write(self, *, wall_seconds: float | None = None) -> dict:
        result = super().write(wall_seconds=wall_seconds)
        (self.out / f"{self.name}.md").unlink(missing_ok=True)  # the figure and the JSON are its outputs
        return result

    def plots(self, records, summary) -> None:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        res = self.result(records, summary, None)
        sizes, grid = np.array(res["widths_mm"]), np.array(res["condition"], float)
        m = Material(**self.config["material"])
        fig, ax = plt.subplots(figsize=(5.2, 4.4), dpi=110)
        half = (sizes[1] - sizes[0]) / 2
        im = ax.imshow(np.log10(grid), origin="lower", cmap="magma", interpolation="nearest",
                       extent=(sizes[0] - half, sizes[-1] + half, sizes[0] - half, sizes[-1] + half))
        fig.colorbar(im, ax=ax, label="log10 condition number")
        ax.set(xlabel="width W [mm]", ylabel="height H [mm]",
               title=f"eta={m.eta:.3g} Pa s^n, n={m.n:.3g}, sigma_y={m.sigma_y:.3g} Pa")
        save_figure(fig, self.out / "conditioning.png")


def conditioning(out, material: Material, *, steps: int = 3, fd_step: float = 0.05, preset="demo", forward,
                 progress=None, density: float = DEFAULT_DENSITY_KG_M3) -> dict:
    """Condition number of the FD Hessian of ``material``'s loss at each setup of a ``steps`` x ``steps``
    grid over the setup space, resumable per setup; writes ``conditioning.json`` and ``conditioning.png`` into
    ``out`` and returns what the JSON holds."""
    from similarity.presets import get_preset

    if steps < 2:
        raise ValueError(f"steps={steps}: the setup grid needs at least 2 points per axis")
    u = normalize(material.as_array())
    if np.any(u - fd_step < 0) or np.any(u + fd_step > 1):
        raise ValueError(f"{material} lies within the finite-difference step {fd_step:g} of the material space's "
                         "boundary (normalised coordinates); choose a smaller --fd-step or another material")
    config = {"material": material.to_dict(), "steps": int(steps), "fd_step": float(fd_step),
              "preset": get_preset(preset).name, "density": float(density), "simulator": forward.simulator}
    return Conditioning(Path(out), config).run(forward=forward, progress=progress)
