"""Paper Fig. 7: the loss landscapes seen from two directions (top and bottom rows).

Drawn from the landscapes study's output (``virheo study landscapes``, passed as ``--landscapes DIR``);
in quick mode without it, a tiny study is run through the store. Without data ``make`` raises
:class:`MissingData` naming the command that makes it.

The paper's Fig. 7 shows that changing the *camera* view leaves the loss structure nearly unchanged;
the landscape study renders one camera, so this figure shows the landscapes themselves from two
directions: top, each probe block in the normalised material space, coloured by loss (relative to the
landscape's largest), with the FD loss normal (black) and the matched Poiseuille normal (red); bottom,
the same points seen along the similarity set's plane (x: signed distance dM . q_FD, y: the in-plane
direction nearest to d sigma_Y), where the low-loss points line up in a band at x = 0 and the matched
Poiseuille plane is the red dashed line.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from paper_figures._landscape_data import matched_pairs
from paper_figures._plot import Context, pyplot

NAMES = ("d eta", "d n", "d sigma_Y")
MAX_PAIRS = 3


def in_plane_axis(q) -> np.ndarray:
    """Unit vector orthogonal to the unit normal ``q`` nearest to the d sigma_Y axis (or d eta if q is along it)."""
    axis = np.array([0.0, 0.0, 1.0]) if abs(q[2]) < 0.95 else np.array([1.0, 0.0, 0.0])
    u = axis - (axis @ q) * q
    return u / np.linalg.norm(u)


def make(out_dir, quick: bool = False, *, context: Context | None = None) -> list[Path]:

    context = context or Context()
    data, hw, pairs = matched_pairs(out_dir, quick, context, "fig07", MAX_PAIRS)
    offsets = np.asarray(data["offsets"], dtype=float)
    plt = pyplot()
    fig = plt.figure(figsize=(3.4 * len(pairs) + 0.8, 6.6), dpi=100)
    for col, rec in enumerate(pairs):
        loss = np.asarray(rec["losses"], dtype=float)
        top = np.nanmax(loss) if np.any(np.isfinite(loss)) and np.nanmax(loss) > 0 else 1.0
        loss = loss / top  # each landscape relative to its largest loss
        q_pp = np.asarray(rec["match"]["q_pp"], dtype=float)
        q_fd = None if rec.get("q_max") is None else np.asarray(rec["q_max"], dtype=float)
        size = 8 + 60 * (1 - np.nan_to_num(loss, nan=1.0))  # low loss: large points
        ax = fig.add_subplot(2, len(pairs), col + 1, projection="3d")
        sc = ax.scatter(offsets[:, 0], offsets[:, 1], offsets[:, 2], c=loss, s=size, cmap="viridis",
                        vmin=0, vmax=1, depthshade=False)
        ax.set_box_aspect((1, 1, 1))
        for q, color, label in ((q_fd, "k", "FD loss normal"), (q_pp, "r", "matched Poiseuille normal")):
            if q is not None:
                ax.quiver(0, 0, 0, *(hw * q / np.linalg.norm(q)), color=color, lw=2, arrow_length_ratio=0.2, label=label)
        ax.view_init(elev=25.0, azim=-60.0)
        ax.set_xlabel(NAMES[0], fontsize=7)
        ax.set_ylabel(NAMES[1], fontsize=7)
        ax.set_zlabel(NAMES[2], fontsize=7)
        ax.tick_params(labelsize=6)
        for lim in (ax.set_xlim, ax.set_ylim, ax.set_zlim):
            lim(-hw, hw)
        s = rec["setup"]
        ax.set_title(f"oblique view\nsetup ({s['width_mm']:g}, {s['height_mm']:g}) mm", fontsize=8)
        if col == 0:
            ax.legend(fontsize=6, loc="upper left")
        # along the similarity plane: distance to the FD plane (x) against the in-plane direction nearest
        # to d sigma_Y (y); the matched Poiseuille plane cuts this view along the red line
        q = q_fd if q_fd is not None else q_pp
        q = q / np.linalg.norm(q)
        u = in_plane_axis(q)
        ax = fig.add_subplot(2, len(pairs), len(pairs) + col + 1)
        ax.scatter(offsets @ q, offsets @ u, c=loss, s=size, cmap="viridis", vmin=0, vmax=1)
        r = 1.8 * hw
        a_, b_ = float(q_pp @ q), float(q_pp @ u)  # the line a x + b y = 0
        d = np.array([-b_, a_]) / np.hypot(a_, b_) * r
        ax.plot([-d[0], d[0]], [-d[1], d[1]], "--", color="r", lw=1.4)
        ax.axvline(0, color="k", ls=":", lw=1)
        ax.set(xlim=(-r, r), ylim=(-r, r), aspect="equal")
        ax.set_xlabel("dM . q_FD (distance to the plane)", fontsize=7)
        ax.set_ylabel("in-plane, towards d sigma_Y", fontsize=7)
        ax.tick_params(labelsize=6)
        ax.set_title("seen along the similarity plane", fontsize=8)
    fig.subplots_adjust(left=0.05, right=0.88, bottom=0.03, top=0.88, wspace=0.15, hspace=0.25)
    fig.colorbar(sc, cax=fig.add_axes((0.91, 0.25, 0.015, 0.5)), label="loss (eq. 3) / largest loss of the landscape")
    fig.suptitle("Fig. 7: MPM loss landscapes (normalised material space) from two directions", fontsize=9)
    path = Path(out_dir) / "fig07_views.png"
    from mpm.files import atomic_write
    from studies.report import figure_path

    # 3D axes and colorbars do not take tight_layout; save directly
    path = figure_path(path)
    try:
        atomic_write(path, lambda fh: fig.savefig(fh, format="png", dpi=100))
    finally:
        plt.close(fig)
    return [path]
