"""Paper Fig. 5: eq.-14 shear stress vs time in 3D simple shear (gamma_dot = 10 1/s), the paper's flow
rule (purple) against Yue et al. 2015 (red); dashed: eq. 7, dotted red: the Yue closed form
(mpm.shear.terminal_shear_stress). Same materials as Fig. 2.
Usage: python -m paper_figures.fig05_simple_shear [OUT.png]; ``make(out_dir)`` for ``virheo figures``.
"""

import sys
from pathlib import Path

import numpy as np

from mpm.shear import simple_shear, terminal_shear_stress, terminal_stress
from paper_figures.fig02_1d_model import PANELS, STRAIN_RATE, T_END
from paper_figures._plot import finish_stress_grid


def main(out: str = "docs/figures/fig05_simple_shear.png") -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    eta, n, sy = (np.array(v) for v in zip(*PANELS))
    paper = simple_shear(eta, n, sy, STRAIN_RATE, t_end=T_END, dt=2e-5)
    yue = simple_shear(eta, n, sy, STRAIN_RATE, t_end=T_END, dt=2e-5, flow_rule="yue2015")
    fig, axes = plt.subplots(2, 3, figsize=(11, 6), sharex=True)
    for i, ax in enumerate(axes.flat):
        ax.plot(paper.t, paper.shear_stress[:, i], color="purple", label="paper flow rule")
        ax.plot(yue.t, yue.shear_stress[:, i], color="red", label="Yue et al. 2015")
        ax.axhline(terminal_stress(eta[i], n[i], sy[i], STRAIN_RATE), ls="--", color="k", lw=0.8, label="eq. 7")
        ax.axhline(terminal_shear_stress(eta[i], n[i], sy[i], STRAIN_RATE, "yue2015"), ls=":", color="red", lw=0.8)
        ax.set_title(f"eta={eta[i]:g}, n={n[i]:g}, sigma_y={sy[i]:g}", fontsize=9)
        ax.set_ylim(bottom=0)
    return finish_stress_grid(fig, axes, out, "shear stress (Pa), eq. 14")


def make(out_dir, quick: bool = False, **_) -> list[Path]:
    """Write fig05_simple_shear.png into ``out_dir`` (no simulation: quick and full are the same)."""
    return [main(Path(out_dir) / "fig05_simple_shear.png")]


if __name__ == "__main__":
    print(main(*sys.argv[1:2]))
