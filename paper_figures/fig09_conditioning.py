"""Paper Fig. 9: condition number of the finite-difference loss Hessian over the setup grid.

Drawn from the conditioning study's output (``virheo study conditioning``: ``conditioning.json`` in the
``--landscapes DIR`` folder or its ``conditioning`` subfolder); in quick mode without it, the first
material of a tiny landscape study is run on a 2 x 2 setup grid through the store. Without data
``make`` raises :class:`MissingData` naming the command that makes it.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from paper_figures._landscape_data import conditioning
from paper_figures._plot import Context, MissingData, pyplot


def make(out_dir, quick: bool = False, *, context: Context | None = None) -> list[Path]:
    from studies.report import save_figure

    context = context or Context()
    data = conditioning(out_dir, quick, context, "fig09")
    cond = np.array(data["condition"], dtype=float)  # rows: heights, columns: widths
    widths, heights = np.asarray(data["widths_mm"], float), np.asarray(data["heights_mm"], float)
    if cond.shape != (len(heights), len(widths)) or not np.any(np.isfinite(cond)):
        raise MissingData("conditioning.json holds no condition number; run `virheo study conditioning --out DIR`")
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5.6, 4.4), dpi=100)
    hw = (widths[1] - widths[0]) / 2 if len(widths) > 1 else 1.0
    hh = (heights[1] - heights[0]) / 2 if len(heights) > 1 else 1.0
    im = ax.imshow(cond, origin="lower", cmap="viridis", interpolation="nearest", aspect="auto",
                   extent=(widths[0] - hw, widths[-1] + hw, heights[0] - hh, heights[-1] + hh))
    fig.colorbar(im, ax=ax, label="condition number |lambda|max / |lambda|min")
    if cond.size <= 64:  # label each cell of a coarse grid with its value
        mid = np.nanmean(cond)
        for i, h in enumerate(heights):
            for j, w in enumerate(widths):
                if np.isfinite(cond[i, j]):
                    ax.text(w, h, f"{cond[i, j]:.1f}", ha="center", va="center", fontsize=9,
                            color="k" if cond[i, j] > mid else "w")
    m = data["material"]
    def ticks(sizes):  # every setup of a coarse grid, every 10 mm of a fine one
        return sizes if len(sizes) <= 12 else sizes[np.isclose(sizes % 10, 0)]

    ax.set(xlabel="width W (mm)", ylabel="height H (mm)", xticks=ticks(widths), yticks=ticks(heights))
    ax.set_title(f"Fig. 9: FD Hessian condition number (step {data['fd_step']:g}, {data['preset']} preset)\n"
                 f"eta={m['eta']:.3g} Pa s^n, n={m['n']:.3g}, sigma_Y={m['sigma_y']:.3g} Pa", fontsize=8)
    return [save_figure(fig, Path(out_dir) / "fig09_conditioning.png", dpi=100)]
