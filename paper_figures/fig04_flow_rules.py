"""Paper Fig. 4: moisturizing-milk footage vs our flow rule vs Yue et al. 2015 at the rheometer's parameters.

The material is the Herschel-Bulkley fit of the shared rheometer curve (Nyueki, 1-100 1/s,
``fit_herschel_bulkley``); both shared milk setups are simulated with the paper's flow rule (eqs. 14-18) and
with Yue et al. 2015's (``flow_rule="yue2015"``) through the simulation store, in each experiment's calibrated
camera. Columns as in the paper: (a) footage, (b) ours, (c) (a) vs (b), (d) Yue 2015, (e) (a) vs (d), at
t = 1/3 s; differences: blue = footage only, red = simulation only; losses (eq. 3) over all 8 frames.
Quick: 5 mm cells; full: the paper's discretisation (1.26 mm cells, 2 particles per cell per axis).
Usage: python -m paper_figures.fig04_flow_rules [OUT_DIR] [--quick]
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from mpm.forward import ForwardModel
from mpm.loss import frame_losses
from paper_figures._plot import Context, MissingData, crop_box, difference_rgb, pyplot, show, silhouette_rgb
from studies.report import save_figure

RHEOMETER_FILE = "Nyueki"  # moisturizing milk
MATERIAL = "moisturizing milk"
DISCRETISATION = {True: (5.0, None), False: (1.26, 2)}  # quick / full: (cell mm, particles per cell per axis)


def rheometer_module():
    """The rheometer reader and Herschel-Bulkley fit (``fit_herschel_bulkley``, ``read_flow_curve``, ...)."""
    from surrogate import rheometer

    return rheometer


def rheometer_fit(name: str = RHEOMETER_FILE):
    """(flow curve, Herschel-Bulkley fit) of the shared rheometer export whose file name starts with ``name``."""
    from mpm.datasets import data_dir

    d = data_dir()
    files = sorted((d / "rheometer").glob(f"{name}_*.csv")) if d is not None else []
    if not files:
        raise MissingData(f"rheometer curve {name}_*.csv not found: set VIRHEO_DATA to the shared data folder")
    rh = rheometer_module()
    curve = rh.read_flow_curve(files[0])
    return curve, rh.fit_herschel_bulkley(curve)


def shared_experiments(material: str):
    """The shared experiments of ``material`` (manifest spelling), setup 1 first, and the paper's Table-1 row."""
    from mpm import experiment as xp
    from mpm.datasets import data_dir, manifest, real_world_dir

    if data_dir() is None:
        raise MissingData("shared footage not found: set VIRHEO_DATA to the shared data folder")
    rows = sorted((r for r in manifest() if r["material"].lower() == material.lower()),
                  key=lambda r: int(r["setup_index"]))
    if not rows:
        raise MissingData(f"no shared footage of {material} in manifest.csv")
    return [xp.load(real_world_dir() / r["folder"]) for r in rows], rows


def make(out_dir, quick: bool = False, *, context: Context | None = None) -> list[Path]:
    context = context or Context()
    forward = context.resolved_forward(out_dir)
    _, fit = rheometer_fit()
    material = fit.material
    exps, _ = shared_experiments(MATERIAL)
    cell_mm, ppc = DISCRETISATION[quick]
    rules = ("paper", "yue2015")
    reqs = [forward.request(material, e, ForwardModel(cell_mm, ppc, flow_rule=rule)) for e in exps for rule in rules]
    results = forward.evaluate(reqs)
    plt = pyplot()
    fig, axes = plt.subplots(len(exps), 5, figsize=(15, 2.5 * len(exps)), dpi=80, squeeze=False)
    for i, e in enumerate(exps):
        ours, yue = results[2 * i].silhouettes, results[2 * i + 1].silhouettes
        if ours is None or yue is None:
            raise RuntimeError(f"fig04: simulation failed for {e.name}")
        rows, cols = crop_box([e.frames[-1], ours[-1], yue[-1]])
        loss_ours, loss_yue = (float(np.mean(frame_losses(s, e.frames))) for s in (ours, yue))
        setup = f"{e.width_mm:g}x{e.height_mm:g} mm"
        show(axes[i, 0], silhouette_rgb(e.frames[-1][rows, cols]), f"(a) footage, {setup}")
        show(axes[i, 1], silhouette_rgb(ours[-1][rows, cols]), "(b) our flow rule")
        show(axes[i, 2], difference_rgb(e.frames[-1][rows, cols], ours[-1][rows, cols]),
             f"(c) (a) vs (b): loss {loss_ours:.4f}")
        show(axes[i, 3], silhouette_rgb(yue[-1][rows, cols]), "(d) Yue et al. 2015")
        show(axes[i, 4], difference_rgb(e.frames[-1][rows, cols], yue[-1][rows, cols]),
             f"(e) (a) vs (d): loss {loss_yue:.4f}")
    m = material
    disc = f"{cell_mm:g} mm cells" + (f", {ppc} particles per cell per axis" if ppc else "")
    fig.suptitle(f"Moisturizing milk, t = 1/3 s, rheometer fit eta={m.eta:.3g} Pa s^n, n={m.n:.3g}, "
                 f"sigma_y={m.sigma_y:.3g} Pa; {disc}; blue: footage only, red: simulation only", fontsize=9)
    return [save_figure(fig, Path(out_dir) / "fig04_flow_rules.png")]
