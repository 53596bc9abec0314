"""Report writers: result.json, Herschel-Bulkley flow-curve plots, silhouette overlays, progress bars."""
from __future__ import annotations

from contextlib import contextmanager
from pathlib import Path
from typing import Mapping

import numpy as np

from mpm.files import atomic_write, write_json  # noqa: F401 (write_json re-exported)
from similarity.progress import first_line

SHEAR_RATES = np.logspace(-2, 4, 200)  # 1/s, the range of the paper's flow-curve plots (Fig. 10)

# overlay colours (RGB): both, captured only, simulated only, background
_BOTH, _CAPTURED, _SIMULATED, _BACKGROUND = (70, 70, 70), (40, 110, 230), (230, 60, 40), (255, 255, 255)


def flow_curve_png(path, curves: Mapping[str, object], *, dashed: Mapping[str, object] | None = None,
                   title: str = "Herschel-Bulkley flow curves") -> Path:
    """Stress vs shear rate (eq. 1), log-log over 0.01..1e4 1/s. ``curves``: label -> Material.

    ``dashed``: further curves drawn dotted (e.g. the ground truth or the paper's estimate).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 4.2), dpi=120)
    for label, m in curves.items():
        ax.loglog(SHEAR_RATES, np.maximum(m.stress(SHEAR_RATES), 1e-6), lw=2,
                  label=f"{label}: eta={m.eta:.3g} Pa s^n, n={m.n:.3g}, sigma_y={m.sigma_y:.3g} Pa")
    for label, m in (dashed or {}).items():
        ax.loglog(SHEAR_RATES, np.maximum(m.stress(SHEAR_RATES), 1e-6), ":", lw=2, color="k",
                  label=f"{label}: eta={m.eta:.3g} Pa s^n, n={m.n:.3g}, sigma_y={m.sigma_y:.3g} Pa")
    ax.set_xlim(SHEAR_RATES[0], SHEAR_RATES[-1])
    ax.set_xlabel("shear rate [1/s]")
    ax.set_ylabel("shear stress [Pa]")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=6, loc="upper left")
    return save_figure(fig, path)


def figure_path(path) -> Path:
    """The file a figure saved at ``path`` ends up in: ``.png`` is added when the name has no suffix."""
    path = Path(path)
    return path if path.suffix else path.with_name(path.name + ".png")


def save_figure(fig, path, dpi=None) -> Path:
    """Lay out, save all or nothing (creating the folder) and close a matplotlib figure; returns the path
    written (see :func:`figure_path`).  dpi: the figure's own by default."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    path = figure_path(path)
    try:
        atomic_write(path, lambda fh: fig.savefig(fh, format=path.suffix[1:].lower(),
                                                  dpi=dpi if dpi is not None else "figure"))
    finally:
        plt.close(fig)
    return path


def overlay(simulated: np.ndarray, captured: np.ndarray) -> np.ndarray:
    """RGB image of one frame: grey where both show material, blue captured only, red simulated only."""
    s, c = np.asarray(simulated, bool), np.asarray(captured, bool)
    img = np.empty(s.shape + (3,), np.uint8)
    img[:] = _BACKGROUND
    img[s & c] = _BOTH
    img[c & ~s] = _CAPTURED
    img[s & ~c] = _SIMULATED
    return img


def overlay_pngs(folder, simulated: np.ndarray, captured: np.ndarray, *, prefix: str = "overlay") -> list[Path]:
    """One PNG per frame, ``<prefix>_01.png`` ...: simulated | captured | difference side by side."""
    from PIL import Image

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for k, (s, c) in enumerate(zip(simulated, captured), start=1):
        s, c = np.asarray(s, bool), np.asarray(c, bool)
        panels = [np.where(s[..., None], _SIMULATED, _BACKGROUND), np.where(c[..., None], _CAPTURED, _BACKGROUND),
                  overlay(s, c)]
        sep = np.full((s.shape[0], 4, 3), 0, np.uint8)
        row = np.concatenate([panels[0], sep, panels[1], sep, panels[2]], axis=1).astype(np.uint8)
        p = folder / f"{prefix}_{k:02d}.png"
        Image.fromarray(row).save(p, optimize=True)
        paths.append(p)
    return paths


@contextmanager
def progress_bars(enabled: bool = True):
    """Rich progress bars fed by the progress events (:mod:`similarity.progress`); yields the callback (or None)."""
    from similarity.progress import GenerationDone, Message, Simulation, StageStarted

    if not enabled:
        yield None
        return
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
               TextColumn("{task.fields[info]}"))
    with Progress(*columns, transient=False) as bars:
        tasks: dict = {}
        sims = bars.add_task("simulations run", total=None, info="")
        from_store = 0

        def callback(event):
            nonlocal from_store
            if isinstance(event, StageStarted):
                tasks[event.stage] = bars.add_task(f"stage {event.stage} ({' + '.join(event.setups)})",
                                                   total=event.generations, completed=event.generation, info="")
            elif isinstance(event, GenerationDone) and event.stage in tasks:
                bars.update(tasks[event.stage], completed=event.generation, info=f"best loss {event.best_loss:.5f}")
            elif isinstance(event, Simulation):
                if event.cached:
                    from_store += 1
                    bars.update(sims, info=f"{from_store} results from the store")
                else:
                    bars.advance(sims)
            elif isinstance(event, Message):
                bars.console.print(event.text)

        yield callback


def write_estimate_report(out, est, experiments, *, frames, truth=None, extra: Mapping | None = None) -> dict:
    """result.json, flow_curve.png and per-setup overlays for an :class:`similarity.estimate.Estimate`.

    ``frames``: the simulated silhouettes of the estimate, one (8, H, W) array (or None) per experiment.
    The pictures are optional: one that cannot be drawn is skipped with a line in ``notes`` (after the estimate's
    own).  Returns the result dictionary that was written.
    """
    from mpm.loss import frame_losses
    from similarity.space import e_rel

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    result = {"estimate": est.material.to_dict()}
    if truth is not None:
        result["truth"] = truth.to_dict()
        result["e_rel"] = e_rel(truth, est.material)
        result["e_rel_per_stage"] = [e_rel(truth, s.material) for s in est.stages]
    result.update({k: v for k, v in est.to_dict().items() if k != "estimate"})
    result.update(extra or {})
    notes = result.setdefault("notes", [])
    per_setup = []
    for e, sim in zip(experiments, frames):
        entry = {"name": e.name, "setup": f"{float(e.width_mm):g}x{float(e.height_mm):g}",
                 "density": float(e.density), "depth_mm": float(e.depth_mm)}
        if sim is not None:
            losses = frame_losses(sim, e.frames)
            entry["frame_losses"] = [float(v) for v in losses]
            entry["loss"] = float(np.mean(losses))
            try:  # optional: the estimate stands without its pictures
                entry["overlays"] = [str(p.relative_to(out)) for p in
                                     overlay_pngs(out / "overlays", sim, e.frames, prefix=f"{entry['setup']}")]
            except Exception as exc:
                notes.append(f"overlays of {entry['setup']} skipped: {first_line(exc)}")
        else:
            notes.append(f"overlays of {entry['setup']} skipped: the estimate's simulation in this setup failed")
        per_setup.append(entry)
    result["experiments"] = per_setup
    curves = {"estimate": est.material}
    curves.update({f"after stage {i}": s.material for i, s in enumerate(est.stages[:-1], start=1)})
    try:
        flow_curve_png(out / "flow_curve.png", curves, dashed={"truth": truth} if truth is not None else None)
        result["flow_curve"] = "flow_curve.png"
    except Exception as exc:
        notes.append(f"flow-curve plot skipped: {first_line(exc)}")
    write_json(out / "result.json", result)
    return result
