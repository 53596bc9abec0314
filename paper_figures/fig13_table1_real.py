"""Paper Fig. 13 and Table 1: our estimates from the shared footage against the rheometer and the paper.

For every shared material (two setups each, ``manifest.csv``) Algorithm 1 runs on setup 1 (the one-setup
estimate, from the centre of the material space) and then on setups 1 + 2 (the two-setup estimate)
(``similarity.estimate.estimate``, store-backed and resumable). Table 1 lists our estimates next to the
paper's, each with its mean loss (eq. 3) over the two setups under the same forward model, and, where a
rheometer curve exists, the RMS of log10 stress against it over 1-100 1/s. Fig. 13 draws the flow curves
(eq. 1): rheometer dotted, one setup orange, two setups blue, the paper's Table 1 grey dashed.
Quick: the 5 mm preset with 2 generations per stage; full: the paper's preset (1.26 mm cells, 2 particles
per cell per axis, 100 generations per stage).
Usage: python -m paper_figures.fig13_table1_real [OUT_DIR] [--quick]
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from paper_figures._plot import Context, MissingData, flow_curves, pyplot
from paper_figures.fig04_flow_rules import rheometer_module
from paper_figures.fig10_setups_error import quick_preset_name
from studies.report import save_figure, write_json

QUICK_GENERATIONS = 2
SEED = 0


def _curves() -> dict:
    """material name -> rheometer FlowCurve, for the shared rheometer exports."""
    from mpm.datasets import data_dir

    rh = rheometer_module()
    d = data_dir()
    out = {}
    for f in sorted((d / "rheometer").glob("*.csv")) if d is not None else []:
        curve = rh.read_flow_curve(f)
        out[curve.material_name.lower()] = curve
    return out


def _pairs():
    """[(material, [experiments setup 1, setup 2], paper Material)] for every shared material, manifest order."""
    from mpm import experiment as xp
    from mpm.datasets import data_dir, manifest, real_world_dir
    from mpm.params import Material

    if data_dir() is None:
        raise MissingData("shared footage not found: set VIRHEO_DATA to the shared data folder")
    groups: dict[str, list[dict]] = {}
    for r in manifest():
        groups.setdefault(r["material"], []).append(r)
    out = []
    for name, rows in groups.items():
        rows.sort(key=lambda r: int(r["setup_index"]))
        r0 = rows[0]
        paper = Material(float(r0["paper_eta_Pa_s_n"]), float(r0["paper_n"]), float(r0["paper_sigma_y_Pa"]))
        out.append((name, [xp.load(real_world_dir() / r["folder"]) for r in rows], paper))
    return out


def mean_loss(material, experiments, preset, forward) -> float:
    """Mean video loss (eq. 3) of ``material`` over ``experiments`` with the preset's search model."""
    return float(np.mean(forward.losses([material], experiments, preset.search)))


def estimates(quick: bool, forward) -> list[dict]:
    """Table 1 rows: our one- and two-setup estimates, the paper's, losses and rheometer RMS."""
    from similarity import estimate as E

    preset = E.get_preset(quick_preset_name() if quick else "paper")
    generations = QUICK_GENERATIONS if quick else preset.generations
    curves = _curves()
    rh = rheometer_module()
    rows = []
    for name, exps, paper in _pairs():
        est = E.estimate(exps, preset=preset, seed=SEED, forward=forward, generations=generations, propose=None)
        one, two = est.stages[0].material, est.material
        row = {"material": name, "setups_mm": [f"{e.width_mm:g}x{e.height_mm:g}" for e in exps],
               "one_setup": one.to_dict(), "two_setups": two.to_dict(), "paper": paper.to_dict(),
               "loss_two_setups": mean_loss(two, exps, preset, forward),
               "loss_paper": mean_loss(paper, exps, preset, forward),
               "simulations": est.simulations, "preset": preset.name, "generations": generations}
        curve = curves.get(name.lower())
        if curve is not None:
            fit = rh.fit_herschel_bulkley(curve)
            row["rheometer_fit"] = fit.material.to_dict()
            for key, m in (("one_setup", one), ("two_setups", two), ("paper", paper)):
                row[f"rms_{key}"] = rh.log_stress_rms(m, curve)
        rows.append(row)
    return rows


def table_markdown(rows: list[dict]) -> str:
    f = lambda m: f"{m['eta']:.3g}, {m['n']:.3g}, {m['sigma_y']:.3g}"  # noqa: E731
    rms = lambda r, k: f"{r[k]:.3f}" if k in r else "-"  # noqa: E731
    lines = ["| material | setup #1 | setup #2 | ours, one setup (eta, n, sigma_y) | ours, two setups | loss ours | "
             "paper (Table 1) | loss paper | RMS one / two / paper |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        s1, s2 = (r["setups_mm"] + ["-"])[:2]
        lines.append(f"| {r['material']} | {s1} | {s2} | {f(r['one_setup'])} | {f(r['two_setups'])} | "
                     f"{r['loss_two_setups']:.4f} | {f(r['paper'])} | {r['loss_paper']:.4f} | "
                     f"{rms(r, 'rms_one_setup')} / {rms(r, 'rms_two_setups')} / {rms(r, 'rms_paper')} |")
    return "\n".join(lines) + "\n"


def make(out_dir, quick: bool = False, *, context: Context | None = None) -> list[Path]:
    from mpm.params import Material

    context = context or Context()
    forward = context.resolved_forward(out_dir)
    out_dir = Path(out_dir)
    rows = estimates(quick, forward)
    write_json(out_dir / "table1.json", {"rows": rows})
    table = out_dir / "table1.md"
    table.parent.mkdir(parents=True, exist_ok=True)
    table.write_text(table_markdown(rows))
    curves = _curves()
    with_curve = [r for r in rows if r["material"].lower() in curves]
    if not with_curve:
        raise MissingData("no rheometer curves found under the shared data's rheometer/ folder")
    plt = pyplot()
    cols = 2
    nrows = int(np.ceil(len(with_curve) / cols))
    fig, axes = plt.subplots(nrows, cols, figsize=(5.2 * cols, 3.8 * nrows), dpi=90, squeeze=False)
    for ax, r in zip(axes.ravel(), with_curve):
        c = curves[r["material"].lower()]
        m1, m2, mp = (Material(**{k: r[key][k] for k in ("eta", "n", "sigma_y")})
                      for key in ("one_setup", "two_setups", "paper"))
        flow_curves(ax, [(f"one setup (RMS {r['rms_one_setup']:.3f})", m1, {"color": "tab:orange", "lw": 2}),
                         (f"two setups (RMS {r['rms_two_setups']:.3f})", m2, {"color": "tab:blue", "lw": 2}),
                         (f"paper, Table 1 (RMS {r['rms_paper']:.3f})", mp, {"color": "grey", "ls": "--", "lw": 1})],
                    measured=("rheometer", c.shear_rate, c.shear_stress), title=r["material"])
        ax.legend(fontsize=6, loc="upper left")
    for ax in axes.ravel()[len(with_curve):]:
        ax.axis("off")
    g = with_curve[0]["generations"]
    fig.suptitle(f"Flow curves from the footage ({with_curve[0]['preset']} preset, {g} generations per stage) vs the "
                 f"rheometer; RMS of log10 stress over 1-100 1/s", fontsize=9)
    return [save_figure(fig, out_dir / "fig13_flow_curves.png"), table]
