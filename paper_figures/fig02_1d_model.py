"""Paper Fig. 2: stress vs time of the 1D elasto-viscoplastic Herschel-Bulkley model (eqs. 4-8).

Strain rate 10 1/s, mu = 1e3 Pa. Each panel changes the base material (top left); dashed lines mark
the terminal stress (eq. 7), the dotted line the yield time plus the transition time t_inf (eq. 8).
Usage: python -m paper_figures.fig02_1d_model [OUT.png]; ``make(out_dir)`` for ``virheo figures``.
"""

import sys
from pathlib import Path

import numpy as np

from mpm.scene import MU_PA
from mpm.shear import integrate_1d, terminal_stress, transition_time
from paper_figures._plot import finish_stress_grid

STRAIN_RATE = 10.0
# (eta Pa s^n, n, sigma_y Pa): the base material, then one or two parameters changed
PANELS = [(1.0, 0.6, 5.0), (5.0, 0.6, 5.0), (1.0, 1.0, 5.0), (1.0, 0.6, 20.0), (0.2, 0.3, 0.0), (5.0, 1.0, 20.0)]
T_END = 0.08


def main(out: str = "docs/figures/fig02_1d_model.png") -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(11, 6), sharex=True)
    for ax, (eta, n, sy) in zip(axes.flat, PANELS):
        t, sigma = integrate_1d(eta, n, sy, STRAIN_RATE, mu=MU_PA, t_end=T_END, dt=T_END / 4000)
        ax.plot(t, sigma, color="purple", label="1D model")
        ax.axhline(terminal_stress(eta, n, sy, STRAIN_RATE), ls="--", color="k", lw=0.8, label="eq. 7")
        t_yield = sy / (MU_PA * STRAIN_RATE)
        ax.axvline(t_yield + transition_time(eta, n, STRAIN_RATE, MU_PA), ls=":", color="k", lw=0.8,
                   label="yield + t_inf (eq. 8)")
        ax.set_title(f"eta={eta:g}, n={n:g}, sigma_y={sy:g}", fontsize=9)
        ax.set_ylim(bottom=0)
    return finish_stress_grid(fig, axes, out, "stress (Pa)")


def make(out_dir, quick: bool = False, **_) -> list[Path]:
    """Write fig02_1d_model.png into ``out_dir`` (no simulation: quick and full are the same)."""
    return [main(Path(out_dir) / "fig02_1d_model.png")]


if __name__ == "__main__":
    print(main(*sys.argv[1:2]))
