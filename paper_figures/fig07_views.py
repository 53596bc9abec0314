"""Paper Fig. 7: the loss landscapes seen from two directions (top and bottom rows).

Drawn from the landscapes study's output (``virheo study landscapes``, passed as ``--landscapes DIR``);
in quick mode without it, a tiny study is run through the store. Without data ``make`` raises
:class:`MissingData` naming the command that makes it.

The paper's Fig. 7 shows that changing the *camera* view leaves the loss structure nearly unchanged;
the landscape study renders one camera, so this figure shows the other half of that argument: each
landscape's probe block in the normalised material space, coloured by loss, from two viewing
directions, with the FD loss normal (black) and the matched Poiseuille normal (red). From the second
direction, looking along the similarity set's plane, the low-loss points line up in a thin band.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from paper_figures._landscape_data import landscapes
from paper_figures._plot import Context, MissingData, pyplot

NAMES = ("d eta", "d n", "d sigma_Y")
MAX_PAIRS = 3
VIEWS = ((25.0, -60.0), None)  # (elevation, azimuth) in degrees; None: along the similarity set's plane


def edge_on_view(q) -> tuple[float, float]:
    """(elevation, azimuth) in degrees of a viewing direction lying in the plane normal to ``q``."""
    q = np.asarray(q, dtype=float) / np.linalg.norm(q)
    helper = np.array([0.0, 0.0, 1.0]) if abs(q[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    v = np.cross(q, helper)
    v /= np.linalg.norm(v)
    return float(np.degrees(np.arcsin(np.clip(v[2], -1, 1)))), float(np.degrees(np.arctan2(v[1], v[0])))


def make(out_dir, quick: bool = False, *, context: Context | None = None) -> list[Path]:

    context = context or Context()
    data = landscapes(out_dir, quick, context, "fig07")
    offsets = np.asarray(data["offsets"], dtype=float)
    hw = float(np.max(np.abs(offsets)))
    pairs = [p for p in data["pairs"] if p.get("match")][:MAX_PAIRS]
    if not pairs:
        raise MissingData("the landscape study has no matched landscape; run `virheo study landscapes --out DIR`")
    plt = pyplot()
    fig = plt.figure(figsize=(3.4 * len(pairs) + 0.8, 6.6), dpi=100)
    for col, rec in enumerate(pairs):
        loss = np.asarray(rec["losses"], dtype=float)
        top = np.nanmax(loss) if np.any(np.isfinite(loss)) and np.nanmax(loss) > 0 else 1.0
        loss = loss / top  # each landscape relative to its largest loss
        q_pp = np.asarray(rec["match"]["q_pp"], dtype=float)
        q_fd = None if rec.get("q_max") is None else np.asarray(rec["q_max"], dtype=float)
        for row, view in enumerate(VIEWS):
            ax = fig.add_subplot(2, len(pairs), row * len(pairs) + col + 1, projection="3d")
            size = 8 + 60 * (1 - np.nan_to_num(loss, nan=1.0))  # low loss: large points
            sc = ax.scatter(offsets[:, 0], offsets[:, 1], offsets[:, 2], c=loss, s=size, cmap="viridis",
                            vmin=0, vmax=1, depthshade=False)
            ax.set_box_aspect((1, 1, 1))
            for q, color, label in ((q_fd, "k", "FD loss normal"), (q_pp, "r", "matched Poiseuille normal")):
                if q is not None:
                    v = hw * q / np.linalg.norm(q)
                    ax.quiver(0, 0, 0, *v, color=color, lw=2, arrow_length_ratio=0.2, label=label)
            elev, azim = view if view is not None else edge_on_view(q_fd if q_fd is not None else q_pp)
            ax.view_init(elev=elev, azim=azim)
            ax.set_xlabel(NAMES[0], fontsize=7)
            ax.set_ylabel(NAMES[1], fontsize=7)
            ax.set_zlabel(NAMES[2], fontsize=7)
            ax.tick_params(labelsize=6)
            for lim in (ax.set_xlim, ax.set_ylim, ax.set_zlim):
                lim(-hw, hw)
            s = rec["setup"]
            where = "oblique view" if view is not None else "along the similarity plane"
            ax.set_title(f"{where}\nsetup ({s['width_mm']:g}, {s['height_mm']:g}) mm", fontsize=8)
            if row == 0 and col == 0:
                ax.legend(fontsize=6, loc="upper left")
    fig.subplots_adjust(left=0.02, right=0.88, bottom=0.03, top=0.88, wspace=0.15, hspace=0.25)
    fig.colorbar(sc, cax=fig.add_axes((0.91, 0.25, 0.015, 0.5)), label="loss (eq. 3) / largest loss of the landscape")
    fig.suptitle("Fig. 7: MPM loss landscapes (normalised material space) from two directions", fontsize=9)
    path = Path(out_dir) / "fig07_views.png"
    from mpm.store import atomic_write
    from studies.report import figure_path

    # 3D axes and colorbars do not take tight_layout; save directly
    path = figure_path(path)
    try:
        atomic_write(path, lambda fh: fig.savefig(fh, format="png", dpi=100))
    finally:
        plt.close(fig)
    return [path]
