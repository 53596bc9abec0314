"""Condition numbers of the finite-difference loss Hessian of one material over a grid of setups
(Fig. 9): ``conditioning.json`` and ``conditioning.png``."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from mpm.params import DEFAULT_DENSITY_KG_M3, SETUP_RANGE_MM, Material, Setup
from similarity import estimate as E
from similarity.emulation import probe_losses
from similarity.fd_hessian import hessian_from_stencil, spectrum, stencil
from similarity.space import normalize
from similarity.progress import simulation_tick
from studies.report import save_figure, write_json


# setups whose footage is held in memory at once (8 frames of 960 x 540 each, about 4 MB per setup): the
# paper's 51 x 51 grid would otherwise need over 10 GB
CHUNK = 64


def _stencil_losses(material, setups, probes, preset, forward, density, tick) -> np.ndarray:
    """Losses (len(setups), len(probes)) of the FD stencil around ``material`` against its own footage."""
    shots = E.emulate(material, setups, density=density, preset=preset, forward=forward)
    return probe_losses([(material, e) for e in shots], probes, preset.final, forward, tick)


def conditioning(out, material: Material, *, steps: int = 3, fd_step: float = 0.05, preset="demo", forward,
                 progress=None, density: float = DEFAULT_DENSITY_KG_M3) -> dict:
    """Condition number of the FD Hessian of ``material``'s loss at each setup of a ``steps`` x ``steps``
    grid over the setup space; writes ``conditioning.json`` and ``conditioning.png`` into ``out``."""
    if steps < 2:
        raise ValueError(f"steps={steps}: the setup grid needs at least 2 points per axis")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    preset = E.get_preset(preset)
    u = normalize(material.as_array())
    if np.any(u - fd_step < 0) or np.any(u + fd_step > 1):
        raise ValueError(f"{material} lies within the finite-difference step {fd_step:g} of the material space's "
                         "boundary (normalised coordinates); choose a smaller --fd-step or another material")
    lo, hi = SETUP_RANGE_MM
    sizes = np.round(np.linspace(lo, hi, steps))
    setups = [Setup(float(w), float(h)) for h in sizes for w in sizes]
    probes = stencil(fd_step)
    tick = simulation_tick(progress)
    losses = np.concatenate([_stencil_losses(material, setups[k:k + CHUNK], probes, preset, forward, density, tick)
                             for k in range(0, len(setups), CHUNK)])
    cond = np.full(len(setups), np.nan)
    normals, eigen = [], []
    for k, row in enumerate(losses):
        if np.all(np.isfinite(row)):
            sp = spectrum(hessian_from_stencil(row, fd_step))
            cond[k] = sp.condition
            normals.append(sp.q_max.tolist())
            eigen.append(sp.eigenvalues.tolist())
        else:
            normals.append(None)
            eigen.append(None)
    grid = cond.reshape(steps, steps)  # rows = height, columns = width
    res = {"material": material.to_dict(), "fd_step": fd_step, "preset": preset.name, "widths_mm": sizes.tolist(),
           "heights_mm": sizes.tolist(), "condition": grid.tolist(), "q_max": normals, "eigenvalues": eigen,
           "setups": [str(s) for s in setups], "face_losses": losses[:, :6].tolist(),
           "min": float(np.nanmin(cond)), "median": float(np.nanmedian(cond)), "max": float(np.nanmax(cond)),
           "simulations": len(setups) * (len(probes) + 1), "wall_seconds": time.perf_counter() - t0}
    write_json(out / "conditioning.json", res)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.2, 4.4), dpi=110)
    half = (sizes[1] - sizes[0]) / 2
    im = ax.imshow(np.log10(grid), origin="lower", cmap="magma", interpolation="nearest",
                   extent=(sizes[0] - half, sizes[-1] + half, sizes[0] - half, sizes[-1] + half))
    fig.colorbar(im, ax=ax, label="log10 condition number")
    ax.set(xlabel="width W [mm]", ylabel="height H [mm]",
           title=f"eta={material.eta:.3g} Pa s^n, n={material.n:.3g}, sigma_y={material.sigma_y:.3g} Pa")
    save_figure(fig, out / "conditioning.png")
    return res
