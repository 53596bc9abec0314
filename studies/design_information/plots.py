"""Figures of `virheo study design-information` (:mod:`studies.design_information`): predicted against realised
information per criterion, and Fig. 10-style maps of realised information over the setups."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from mpm.params import Setup
from similarity.information import last_where_ruled_out
from studies.report import save_figure

COLOURS = {"eig": "tab:red", "perpendicularity-fitted": "tab:green", "perpendicularity-reference": "tab:blue",
           "information": "tab:purple", "random": "0.45", "largest": "tab:orange"}


def plot_predicted(path, recs: list) -> Path:
    """Per ranked criterion: predicted information (ranks within the material) against realised gain (ranks), over
    the :class:`studies.design_information.InformationRecord` ``recs``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy.stats import rankdata

    names = [n for n in recs[0].config["criteria"] if n != "random"]
    fig, axes = plt.subplots(1, len(names), figsize=(3.4 * len(names), 3.4), dpi=100, squeeze=False)
    for ax, n in zip(axes[0], names):
        xs, ys = [], []
        for r in recs:
            pred = r.predicted[n]
            if all(p is None for p in pred):
                continue
            g = r.realised()
            ok = np.isfinite(g)
            m = len(g[ok])
            xs += list((rankdata(last_where_ruled_out(pred)[ok]) - 0.5) / m)
            ys += list((rankdata(g[ok]) - 0.5) / m)
        med = np.nanmedian([r.scores()[n].spearman for r in recs])
        ax.plot(xs, ys, "o", ms=3, alpha=0.5, color=COLOURS.get(n))
        ax.plot([0, 1], [0, 1], ":", color="k", lw=1)
        ax.set(xlabel="predicted information (rank fraction)", ylabel="realised gain (rank fraction)",
               title=f"{n}\nmedian Spearman {med:.2f}")
        ax.title.set_fontsize(8)
    return save_figure(fig, path)


def plot_maps(path, maps: list, recs: list) -> Path:
    """Fig. 10-style maps (:class:`studies.design_information.checks.InformationMap`) of realised gain over the
    setup grid, first setup and picks marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(maps), figsize=(4.6 * len(maps), 4.6), dpi=100, squeeze=False)
    for ax, m in zip(axes[0], maps):
        r = recs[m.case]
        s = np.array(m.sizes_mm)
        half = (s[1] - s[0]) / 2
        im = ax.imshow(np.array(m.gain, float), origin="lower", cmap="viridis", interpolation="nearest",
                       extent=(s[0] - half, s[-1] + half, s[0] - half, s[-1] + half))
        fig.colorbar(im, ax=ax, label="realised gain log det")
        f = Setup.parse(r.first_setup)
        ax.plot(f.width_mm, f.height_mm, "X", color="w", mec="k", ms=11, label="setup 1")
        for k, (n, pick) in enumerate(r.picks.items()):  # shrinking markers: picks that coincide stay visible
            p = Setup.parse(pick)
            ax.plot(p.width_mm, p.height_mm, "o", color=COLOURS.get(n), mec="k", ms=14 - 2.5 * k, label=n,
                    clip_on=False)
        t = r.truth
        ax.set(xlabel="width W [mm]", ylabel="height H [mm]",
               title=f"eta={t.eta:.3g}, n={t.n:.3g}, sigma_y={t.sigma_y:.3g}")
        ax.title.set_fontsize(8)
        ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=3, frameon=False)
    return save_figure(fig, path)
