"""Paper Fig. 13 and Table 1: our estimates from the shared footage against the rheometer and the paper.

Drawn from the estimate folders that ``python bench/bench_real_estimates.py --root DIR`` writes (one
``virheo estimate --out DIR/<material>`` folder per material, and ``DIR/real_estimates.json`` with the
paper's loss under the same forward model), passed as ``virheo figures --only fig13 --estimates DIR [DIR ...]``
(one folder per seed; default: the bench's default root). Per material: the one-setup estimate (stage 1 of
Algorithm 1), the two-setup estimate, the paper's Table 1, their mean losses (eq. 3) over the two setups under the
run's final forward model, and, where a rheometer curve exists, the RMS of log10 stress against it over
1-100 1/s. Fig. 13 draws the flow curves (eq. 1): rheometer dotted, one setup orange, two setups blue (the first
folder solid, further seeds thin), the paper's Table 1 grey dashed.
``--quick`` runs a smoke test instead: Algorithm 1 on the 5 mm preset with 2 generations per stage for every
shared material (store-backed).
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
DEFAULT_ESTIMATES = Path.home() / ".cache" / "virheometry" / "real_estimates"  # the bench's default root


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
    from mpm.datasets import data_dir, manifest, real_world_dir, table1

    if data_dir() is None:
        raise MissingData("shared footage not found: set VIRHEO_DATA to the shared data folder")
    groups: dict[str, list[dict]] = {}
    for r in manifest():
        groups.setdefault(r["material"], []).append(r)
    out = []
    for name, rows in groups.items():
        rows.sort(key=lambda r: int(r["setup_index"]))
        out.append((name, [xp.load(real_world_dir() / r["folder"]) for r in rows], table1(rows[0])))
    return out


def mean_loss(material, experiments, preset, forward) -> float:
    """Mean video loss (eq. 3) of ``material`` over ``experiments`` with the preset's search model."""
    return float(np.mean(forward.losses([material], experiments, preset.search)))


def _add_rms(row: dict, curves: dict) -> dict:
    """``row`` with the rheometer fit and the RMS of each estimate where the material has a rheometer curve."""
    from mpm.params import Material

    curve = curves.get(row["material"].lower())
    if curve is not None:
        rh = rheometer_module()
        row["rheometer_fit"] = rh.fit_herschel_bulkley(curve).material.to_dict()
        for key in ("one_setup", "two_setups", "paper"):
            row[f"rms_{key}"] = rh.log_stress_rms(Material(**row[key]), curve)
    return row


def quick_estimates(forward) -> list[dict]:
    """Table 1 rows of the smoke test: Algorithm 1 on the quick preset for every shared material."""
    from similarity import estimate as E

    preset = E.get_preset(quick_preset_name())
    curves = _curves()
    rows = []
    for name, exps, paper in _pairs():
        est = E.estimate(exps, preset=preset, seed=SEED, forward=forward, generations=QUICK_GENERATIONS,
                         propose=None)
        one, two = est.stages[0].material, est.material
        rows.append(_add_rms({
            "material": name, "setups_mm": [f"{e.width_mm:g}x{e.height_mm:g}" for e in exps],
            "one_setup": one.to_dict(), "two_setups": two.to_dict(), "paper": paper.to_dict(),
            "loss_two_setups": mean_loss(two, exps, preset, forward), "loss_paper": mean_loss(paper, exps, preset, forward),
            "simulations": est.simulations, "preset": preset.name, "seed": SEED,
            "about": f"{preset.name} preset, {QUICK_GENERATIONS} generations per stage, seed {SEED}"}, curves))
    return rows


def folder_estimates(roots) -> list[dict]:
    """Table 1 rows from bench estimate folders (``ROOT/<material>/result.json``, ``ROOT/real_estimates.json``),
    one row per material and folder, in the manifest's order, then the folders' order."""
    from mpm.datasets import data_dir, manifest, table1
    from mpm.files import read_json
    from similarity.run_folder import read_result

    if data_dir() is None:
        raise MissingData("shared footage not found: set VIRHEO_DATA to the shared data folder")
    materials = {r["folder"]: (r["material"], table1(r)) for r in manifest()}
    order = list(dict.fromkeys(name for name, _ in materials.values()))
    curves = _curves()
    rows = []
    for root in map(Path, roots):
        summary_path = root / "real_estimates.json"
        summary = read_json(summary_path) if summary_path.is_file() else {}
        paper_loss = {v.get("material"): v.get("loss_paper") for v in summary.values() if isinstance(v, dict)}
        for path in sorted(root.glob("*/result.json")):
            result, two = read_result(path.parent)  # one-line ValueError for a malformed result.json
            names = [e.get("name") for e in result.get("experiments", [])]
            found = materials.get(names[0]) if names else None  # (material, Table 1) of shared footage
            if found is None or not result.get("stages"):
                continue
            name, paper = found
            model = result.get("model", {})
            rows.append(_add_rms({
                "material": name, "setups_mm": list(result.get("setups", [])), "folder": str(path.parent),
                "one_setup": dict(result["stages"][0]["material"]), "two_setups": two.to_dict(),
                "paper": paper.to_dict(), "loss_two_setups": result.get("loss"), "loss_paper": paper_loss.get(name),
                "simulations": result.get("simulations"), "preset": result.get("preset"), "seed": result.get("seed"),
                "wall_seconds": result.get("wall_seconds"),
                "about": f"{result.get('preset')} preset, losses at {model.get('cell_mm')} mm cells with "
                         f"{model.get('ppc')} particles per axis"}, curves))
    if not rows:
        raise MissingData(f"no estimate folders of the shared footage under {', '.join(map(str, roots))}: run "
                          f"`python bench/bench_real_estimates.py --root DIR` and pass --estimates DIR")
    return sorted(rows, key=lambda r: order.index(r["material"]))  # stable: folders keep their order


def table_markdown(rows: list[dict]) -> str:
    f = lambda m: f"{m['eta']:.3g}, {m['n']:.3g}, {m['sigma_y']:.3g}"  # noqa: E731
    rms = lambda r, k: f"{r[k]:.3f}" if k in r else "-"  # noqa: E731
    loss = lambda v: "-" if v is None else f"{v:.5f}"  # noqa: E731
    lines = ["| material | seed | setup #1 | setup #2 | ours, one setup (eta, n, sigma_y) | ours, two setups | loss ours | "
             "paper (Table 1) | loss paper | RMS one / two / paper |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        s1, s2 = (r["setups_mm"] + ["-"])[:2]
        lines.append(f"| {r['material']} | {r['seed']} | {s1} | {s2} | {f(r['one_setup'])} | {f(r['two_setups'])} | "
                     f"{loss(r['loss_two_setups'])} | {f(r['paper'])} | {loss(r['loss_paper'])} | "
                     f"{rms(r, 'rms_one_setup')} / {rms(r, 'rms_two_setups')} / {rms(r, 'rms_paper')} |")
    return "\n".join(lines) + "\n"


def make(out_dir, quick: bool = False, *, context: Context | None = None) -> list[Path]:
    from mpm.params import Material

    context = context or Context()
    out_dir = Path(out_dir)
    if quick:
        rows = quick_estimates(context.resolved_forward(out_dir))
    else:
        rows = folder_estimates(context.estimates or [DEFAULT_ESTIMATES])
    write_json(out_dir / "table1.json", {"rows": rows})
    table = out_dir / "table1.md"
    table.parent.mkdir(parents=True, exist_ok=True)
    table.write_text(table_markdown(rows))
    curves = _curves()
    names = list(dict.fromkeys(r["material"] for r in rows if r["material"].lower() in curves))
    if not names:
        raise MissingData("no rheometer curves found under the shared data's rheometer/ folder")
    plt = pyplot()
    cols = 2
    nrows = int(np.ceil(len(names) / cols))
    fig, axes = plt.subplots(nrows, cols, figsize=(5.2 * cols, 3.8 * nrows), dpi=90, squeeze=False)
    for ax, name in zip(axes.ravel(), names):
        mine = [r for r in rows if r["material"] == name]
        lines = []
        for i, r in enumerate(mine):
            style = {"lw": 2} if i == 0 else {"lw": 1, "alpha": 0.7}
            seed = f"seed {r['seed']}, " if len(mine) > 1 else ""
            lines += [(f"one setup ({seed}RMS {r['rms_one_setup']:.3f})", Material(**r["one_setup"]),
                       {"color": "tab:orange", **style}),
                      (f"two setups ({seed}RMS {r['rms_two_setups']:.3f})", Material(**r["two_setups"]),
                       {"color": "tab:blue", **style})]
        lines.append((f"paper, Table 1 (RMS {mine[0]['rms_paper']:.3f})", Material(**mine[0]["paper"]),
                      {"color": "grey", "ls": "--", "lw": 1}))
        c = curves[name.lower()]
        flow_curves(ax, lines, measured=("rheometer", c.shear_rate, c.shear_stress), title=name)
        ax.legend(fontsize=6, loc="upper left")
    for ax in axes.ravel()[len(names):]:
        ax.axis("off")
    fig.suptitle(f"Flow curves from the footage ({rows[0]['about']}) vs the rheometer; RMS of log10 stress over "
                 f"1-100 1/s", fontsize=9)
    return [save_figure(fig, out_dir / "fig13_flow_curves.png"), table]
