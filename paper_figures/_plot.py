"""Shared plotting helpers of the paper-figure scripts."""
from __future__ import annotations

from pathlib import Path


def finish_stress_grid(fig, axes, out, ylabel: str) -> Path:
    """Label a grid of stress-vs-time panels, save it to ``out`` (PNG) and close it."""
    import matplotlib.pyplot as plt

    for ax in axes[-1]:
        ax.set_xlabel("t (s)")
    for ax in axes[:, 0]:
        ax.set_ylabel(ylabel)
    axes.flat[0].legend(fontsize=7)
    fig.tight_layout()
    path = Path(out)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
