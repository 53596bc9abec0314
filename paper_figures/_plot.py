"""Shared plotting helpers of the paper-figure scripts."""
from __future__ import annotations

from pathlib import Path

from studies.report import save_figure


def finish_stress_grid(fig, axes, out, ylabel: str) -> Path:
    """Label a grid of stress-vs-time panels, save it to ``out`` (PNG) and close it."""
    for ax in axes[-1]:
        ax.set_xlabel("t (s)")
    for ax in axes[:, 0]:
        ax.set_ylabel(ylabel)
    axes.flat[0].legend(fontsize=7)
    return save_figure(fig, out, dpi=120)
