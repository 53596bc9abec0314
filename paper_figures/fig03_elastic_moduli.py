"""Paper Fig. 3: dam-break silhouettes with the elastic moduli (kappa, mu) at x1 and x10, and their differences.

The paper's moduli are kappa = 1e4 Pa, mu = 1e3 Pa (section 4.2, ``mpm.scene``). Each column scales one or
both by 10; the lower row of each material shows the difference to the x1/x1 silhouette at t = 1/3 s
(blue: x1 only, red: scaled only) with the fraction of differing pixels averaged over the 8 frames (eq. 3).
Simulations go through the store (``mpm.forward``) with forward models that carry the scaled moduli
(``ForwardModel(kappa_pa=..., mu_pa=...)``); stiffer moduli shorten the explicit time step by up to sqrt(10).
Usage: python -m paper_figures.fig03_elastic_moduli [OUT_DIR] [--quick]
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from mpm.forward import ForwardModel, blank_experiment
from mpm.scene import KAPPA_PA, MU_PA
from mpm.loss import frame_losses
from paper_figures._plot import Context, crop_box, difference_rgb, pyplot, show, silhouette_rgb
from studies.report import save_figure

# (label, eta Pa s^n, n, sigma_y Pa, density kg/m^3): two of Table 1's materials, a runny and a yield-stress one
MATERIALS = [("Worcestershire sauce (Table 1)", 0.55, 0.81, 1.95, 1200.0),
             ("moisturizing milk (Table 1)", 1.27, 0.87, 14.75, 1025.0)]
SETUP_MM = (40.0, 50.0)  # width x height
SCALES = [(1, 1), (10, 1), (1, 10), (10, 10)]  # (kappa factor, mu factor)
CELL_MM = {True: 5.0, False: None}  # quick: the demo preset's 5 mm cells; full: the solver's default (1.5 mm)

def make(out_dir, quick: bool = False, *, context: Context | None = None) -> list[Path]:
    from mpm.camera import Camera
    from mpm.params import Material, Setup

    context = context or Context()
    forward = context.resolved_forward(out_dir)
    camera = Camera.default()
    setup = Setup(*SETUP_MM)
    reqs, keys = [], []
    for label, eta, n, sy, rho in MATERIALS:
        shot = blank_experiment(setup, density=rho, camera=camera)
        for kf, mf in SCALES:
            model = ForwardModel(CELL_MM[quick], kappa_pa=KAPPA_PA * kf, mu_pa=MU_PA * mf)
            reqs.append(forward.request(Material(eta, n, sy), shot, model))
            keys.append((label, kf, mf))
    results = dict(zip(keys, forward.evaluate(reqs)))
    plt = pyplot()
    fig, axes = plt.subplots(2 * len(MATERIALS), len(SCALES), figsize=(2.6 * len(SCALES), 1.9 * 2 * len(MATERIALS)),
                             dpi=100)
    for i, (label, eta, n, sy, rho) in enumerate(MATERIALS):
        ref = results[(label, 1, 1)]
        frames = [results[(label, kf, mf)].silhouettes for kf, mf in SCALES]
        if any(f is None for f in frames):
            failed = [f"kappa x{kf}, mu x{mf}" for (kf, mf), f in zip(SCALES, frames) if f is None]
            raise RuntimeError(f"fig03: simulation failed for {label}: {', '.join(failed)}")
        rows, cols = crop_box([f[-1] for f in frames] + [f[0] for f in frames])
        for j, ((kf, mf), f) in enumerate(zip(SCALES, frames)):
            loss = float(np.mean(frame_losses(f, ref.silhouettes)))
            show(axes[2 * i, j], silhouette_rgb(f[-1][rows, cols]),
                 f"{label}\nkappa x{kf}, mu x{mf}" if j == 0 else f"kappa x{kf}, mu x{mf}")
            show(axes[2 * i + 1, j], difference_rgb(ref.silhouettes[-1][rows, cols], f[-1][rows, cols]),
                 f"difference to x1/x1: loss {loss:.4f}")
    fig.suptitle(f"Elastic moduli x1 / x10 (kappa = 1e4 Pa, mu = 1e3 Pa), setup {setup} mm, t = 1/3 s, "
                 f"{'5 mm cells (quick)' if quick else '1.5 mm cells'}", fontsize=9)
    return [save_figure(fig, Path(out_dir) / "fig03_elastic_moduli.png")]
