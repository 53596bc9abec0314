"""Fig. 6-style plots of a landscape study: central slices of the MPM loss landscape beside the matched
plane-Poiseuille landscape, with the traces of the FD and matched loss normals."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from mpm.params import Material
from similarity.normals import poiseuille_landscape
from studies.report import save_figure


def plot_slices(path, rec: dict, offsets, grid: int) -> Path:
    """Fig. 6 style: the three central slices of the MPM landscape (top) beside the matched Poiseuille
    landscape (bottom), with the similarity set's trace (the plane normal to q) drawn as a line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    m = Material(**rec["material"])
    offsets = np.asarray(offsets, dtype=float)
    mpm = np.asarray(rec["losses"], dtype=float).reshape(grid, grid, grid)
    # a finer Poiseuille grid over the same block: cheap and closed-form
    hw = float(np.max(np.abs(offsets)))
    fine = 41
    axis = np.linspace(-hw, hw, fine)
    names = ("eta", "n", "sigma_y")
    fig, axes = plt.subplots(2, 3, figsize=(10, 6.4), dpi=100)
    q_pp = np.asarray(rec["match"]["q_pp"])
    q_fd = None if rec.get("q_max") is None else np.asarray(rec["q_max"])
    mid = grid // 2
    for col, (a, b) in enumerate(((0, 1), (0, 2), (1, 2))):
        c = 3 - a - b
        sl = [slice(None)] * 3
        sl[c] = mid
        img = mpm[tuple(sl)]  # axes (a, b)
        ax = axes[0, col]
        ax.imshow(img.T, origin="lower", extent=(-hw, hw, -hw, hw), cmap="viridis", interpolation="bicubic" if grid > 3 else "nearest")
        if q_fd is not None:
            _trace(ax, q_fd, a, b, hw, "w", "FD normal")
        _trace(ax, q_pp, a, b, hw, "r", "matched PP")
        ax.set(xlabel=f"d{names[a]} (normalised)", ylabel=f"d{names[b]}", title=f"MPM loss, d{names[c]} = 0")
        pts = np.zeros((fine, fine, 3))
        pts[..., a], pts[..., b] = np.meshgrid(axis, axis, indexing="ij")
        pp = poiseuille_landscape(m, pts.reshape(-1, 3), rec["match"]["C_Pa"]).reshape(fine, fine)
        ax = axes[1, col]
        ax.imshow(pp.T, origin="lower", extent=(-hw, hw, -hw, hw), cmap="viridis")
        _trace(ax, q_pp, a, b, hw, "r", "matched PP")
        ax.set(xlabel=f"d{names[a]} (normalised)", ylabel=f"d{names[b]}", title=f"Poiseuille loss, C = {rec['match']['C_Pa']:.3g} Pa")
    axes[0, 0].legend(fontsize=7, loc="lower left")
    s = rec["setup"]
    fig.suptitle(f"eta={m.eta:.3g} Pa s^n, n={m.n:.3g}, sigma_y={m.sigma_y:.3g} Pa; setup {s['width_mm']:g}x{s['height_mm']:g} mm")
    return save_figure(fig, path)


def _trace(ax, q, a, b, hw, color, label):
    """The line where the plane q . dM = 0 cuts the (a, b) slice: direction (-q_b, q_a)."""
    d = np.array([-q[b], q[a]])
    if np.linalg.norm(d) < 1e-12:
        return
    d = d / np.linalg.norm(d) * hw * 1.5
    ax.plot([-d[0], d[0]], [-d[1], d[1]], "--", color=color, lw=1.5, label=label)
    ax.set_xlim(-hw, hw)
    ax.set_ylim(-hw, hw)
