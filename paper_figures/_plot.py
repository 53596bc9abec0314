"""Shared helpers of the paper-figure scripts: saving, silhouette panels, the run context of a figure."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from studies.report import save_figure

# silhouette colours (RGB 0-1): material, background; differences: only in the first, only in the second
_MATERIAL, _BACKGROUND = (0.15, 0.15, 0.15), (1.0, 1.0, 1.0)
_ONLY_FIRST, _ONLY_SECOND = (0.16, 0.43, 0.90), (0.90, 0.24, 0.16)


class MissingData(Exception):
    """A figure's input data (e.g. a study's output) are absent; the message names the command that makes them."""


@dataclass
class Context:
    """What a figure that simulates needs: the forward model's store and executor (:class:`mpm.forward.Forward`;
    None: a store in the output folder, simulating in this process)."""

    forward: object = None
    landscapes: object = None  # folder of the landscape study (Figs. 6, 7, 9)
    estimates: object = None  # folders of bench/bench_real_estimates.py, one per seed (Fig. 13)
    simulator: str | None = None  # the studies' simulate function as the command line chose it (None: their default)

    def resolved_forward(self, out_dir):
        from mpm.forward import Forward

        if self.forward is None:
            self.forward = Forward(Path(out_dir) / "store")
        return self.forward


def finish_stress_grid(fig, axes, out, ylabel: str) -> Path:
    """Label a grid of stress-vs-time panels, save it to ``out`` (PNG) and close it."""
    for ax in axes[-1]:
        ax.set_xlabel("t (s)")
    for ax in axes[:, 0]:
        ax.set_ylabel(ylabel)
    axes.flat[0].legend(fontsize=7)
    return save_figure(fig, out, dpi=120)


def pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def crop_box(masks, pad: int = 12) -> tuple[slice, slice]:
    """Rows and columns that hold material in any of ``masks`` (bool images of one size), padded."""
    any_mask = np.zeros(np.asarray(masks[0]).shape, bool)
    for m in masks:
        if m is not None:
            any_mask |= np.asarray(m, bool)
    rows, cols = np.flatnonzero(any_mask.any(axis=1)), np.flatnonzero(any_mask.any(axis=0))
    if rows.size == 0:
        return slice(None), slice(None)
    h, w = any_mask.shape
    return (slice(max(0, rows[0] - pad), min(h, rows[-1] + pad + 1)),
            slice(max(0, cols[0] - pad), min(w, cols[-1] + pad + 1)))


def silhouette_rgb(mask) -> np.ndarray:
    m = np.asarray(mask, bool)[..., None]
    return np.where(m, _MATERIAL, _BACKGROUND)


def difference_rgb(first, second) -> np.ndarray:
    """Pixels in ``first`` only (blue), in ``second`` only (red), in both (light grey), neither (white)."""
    a, b = np.asarray(first, bool), np.asarray(second, bool)
    img = np.ones(a.shape + (3,))
    img[a & b] = (0.85, 0.85, 0.85)
    img[a & ~b] = _ONLY_FIRST
    img[~a & b] = _ONLY_SECOND
    return img


def show(ax, image, title: str = "") -> None:
    ax.imshow(image, interpolation="nearest")
    ax.set_xticks([])
    ax.set_yticks([])
    if title:
        ax.set_title(title, fontsize=8)


def flow_curves(ax, curves, *, measured=None, title: str = "") -> None:
    """Log-log Herschel-Bulkley flow curves (eq. 1) over the paper's 1e-2..1e4 1/s.

    ``curves``: (label, Material, matplotlib style dict); ``measured``: (label, rates, stresses) drawn dotted.
    """
    from studies.report import SHEAR_RATES

    for label, m, style in curves:
        ax.loglog(SHEAR_RATES, np.maximum(m.stress(SHEAR_RATES), 1e-6), label=label, **style)
    if measured is not None:
        label, rate, stress = measured
        ax.loglog(rate, stress, ":", color="k", lw=2, marker=".", ms=4, label=label)
    ax.set_xlim(SHEAR_RATES[0], SHEAR_RATES[-1])
    ax.set_xlabel("shear rate (1/s)", fontsize=8)
    ax.set_ylabel("shear stress (Pa)", fontsize=8)
    ax.grid(True, which="major", alpha=0.3)
    ax.tick_params(labelsize=7)
    if title:
        ax.set_title(title, fontsize=8)
