"""Paper Fig. 6: MPM loss landscapes (top) vs the matched plane-Poiseuille landscapes (bottom).

Drawn from the landscapes study's output (``virheo study landscapes``, passed as ``--landscapes DIR``);
in quick mode without it, a tiny study is run through the store. Without data ``make`` raises
:class:`MissingData` naming the command that makes it.

One column per material-setup pair (at most four): a slice of the landscape through the ground truth
M (red dot) in the two material coordinates that carry most of the matched Poiseuille normal, with the
similarity set's trace (the plane normal to the FD loss normal, white, and to the matched Poiseuille
normal, red; section 5.2) dashed. The Poiseuille loss (eq. 26) is closed form and drawn on a fine grid.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from paper_figures._landscape_data import matched_pairs
from paper_figures._plot import Context, pyplot

NAMES = ("eta", "n", "sigma_Y")
MAX_PAIRS = 4


def slice_axes(q) -> tuple[int, int, int]:
    """(a, b, c): the slice spans coordinates a < b, and c (the smallest component of ``q``) is held at 0."""
    c = int(np.argmin(np.abs(np.asarray(q, dtype=float))))
    a, b = (i for i in range(3) if i != c)
    return a, b, c


def trace(ax, q, a: int, b: int, hw: float, color: str, label: str) -> None:
    """The line where the plane q . dM = 0 cuts the (a, b) slice."""
    d = np.array([-q[b], q[a]], dtype=float)
    if np.linalg.norm(d) < 1e-12:
        return
    d *= 1.5 * hw / np.linalg.norm(d)
    ax.plot([-d[0], d[0]], [-d[1], d[1]], "--", color=color, lw=1.4, label=label)
    ax.set_xlim(-hw, hw)
    ax.set_ylim(-hw, hw)


def make(out_dir, quick: bool = False, *, context: Context | None = None) -> list[Path]:
    from mpm.params import Material
    from similarity.normals import poiseuille_landscape

    context = context or Context()
    data, hw, pairs = matched_pairs(out_dir, quick, context, "fig06", MAX_PAIRS)
    grid = int(data["config"]["grid"])
    offsets = np.asarray(data["offsets"], dtype=float)
    plt = pyplot()
    fig, axes = plt.subplots(2, len(pairs), figsize=(3.0 * len(pairs) + 0.6, 6.2), dpi=100, squeeze=False)
    fine = 41
    axis = np.linspace(-hw, hw, fine)
    mid = grid // 2
    from matplotlib.colors import PowerNorm

    for col, rec in enumerate(pairs):
        m = Material(**rec["material"])
        q_pp = np.asarray(rec["match"]["q_pp"], dtype=float)
        q_fd = None if rec.get("q_max") is None else np.asarray(rec["q_max"], dtype=float)
        a, b, c = slice_axes(q_pp)
        cube = np.asarray(rec["losses"], dtype=float).reshape(grid, grid, grid)
        sl = [slice(None)] * 3
        sl[c] = mid
        top = axes[0, col]
        top.imshow(cube[tuple(sl)].T, origin="lower", extent=(-hw, hw, -hw, hw), cmap="viridis", interpolation="nearest",
                   norm=PowerNorm(0.25, vmin=0.0))
        pts = np.zeros((fine, fine, 3))
        pts[..., a], pts[..., b] = np.meshgrid(axis, axis, indexing="ij")
        pp = poiseuille_landscape(m, pts.reshape(-1, 3), rec["match"]["C_Pa"]).reshape(fine, fine)
        bottom = axes[1, col]
        bottom.imshow(pp.T, origin="lower", extent=(-hw, hw, -hw, hw), cmap="viridis", norm=PowerNorm(0.25, vmin=0.0))
        for ax in (top, bottom):
            if q_fd is not None:
                trace(ax, q_fd, a, b, hw, "w", "plane normal to FD loss normal")
            trace(ax, q_pp, a, b, hw, "r", "plane normal to matched Poiseuille normal")
            ax.plot([0], [0], "o", color="r", ms=5)
            ax.set_xlabel(f"d{NAMES[a]} (normalised)", fontsize=8)
            ax.set_ylabel(f"d{NAMES[b]}", fontsize=8)
            ax.tick_params(labelsize=7)
        s = rec["setup"]
        top.set_title(f"MPM, d{NAMES[c]} = 0\n({m.eta:.3g}, {m.n:.3g}, {m.sigma_y:.3g}); "
                      f"({s['width_mm']:g}, {s['height_mm']:g}) mm", fontsize=8)
        angle = rec["match"].get("angle_fd_deg")
        bottom.set_title(f"Poiseuille, C = {rec['match']['C_Pa']:.3g} Pa"
                         + (f"\nnormals {angle:.1f} deg apart" if angle is not None else ""), fontsize=8)
    axes[0, 0].legend(fontsize=6, loc="lower left", framealpha=0.7)
    fig.suptitle("Fig. 6: MPM loss (top), matched plane-Poiseuille loss (bottom); colour: loss to the power 1/4",
                 fontsize=9)
    fig.tight_layout()
    from studies.report import save_figure

    return [save_figure(fig, Path(out_dir) / "fig06_landscapes.png", dpi=100)]
