"""A finished ``virheo estimate`` / ``virheo demo`` folder: its ``result.json`` and the experiments it was fitted
to (experiment folders, or emulated footage rebuilt from the store); its ``posterior.json``:
:mod:`similarity.posterior_summary`.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

from mpm.files import read_json
from mpm.forward import Forward, ForwardModel
from mpm.params import DEFAULT_DENSITY_KG_M3, Material


@dataclass
class Run:
    """A finished ``virheo estimate`` / ``virheo demo`` folder, its experiments and the forward model's store and
    executor (with the run's own simulating function)."""

    folder: Path
    result: dict
    estimate: Material
    experiments: list
    preset: object
    forward: Forward
    truth: Material | None = None
    setups: list = field(default_factory=list)


def read_result(folder) -> tuple[dict, Material]:
    """``folder/result.json`` and its estimate; FileNotFoundError / one-line ValueError otherwise."""
    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"run folder {folder} not found")
    path = folder / "result.json"
    if not path.is_file():
        raise ValueError(f"{folder}: no result.json (not a folder written by virheo estimate or virheo demo)")
    result = read_json(path)
    est = result.get("estimate") if isinstance(result, dict) else None
    if not isinstance(est, dict) or set(est) != {"eta", "n", "sigma_y"}:
        raise ValueError(f"{path} holds no estimate (eta, n, sigma_y)")
    try:
        return result, Material(float(est["eta"]), float(est["n"]), float(est["sigma_y"]))
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{path}: bad estimate ({exc})") from None


def model_of(result: dict) -> ForwardModel:
    """The forward model of a run's loss, from its ``result.json`` (new or old layout, :meth:`ForwardModel.of_record`;
    runs that do not say had sticking walls); one-line ValueError when it is not a model."""
    try:
        return ForwardModel.of_record(result)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"result.json: bad forward model ({str(exc).splitlines()[0]})") from None


def load_run(folder, *, forward: Forward | None = None) -> Run:
    """Read ``folder/result.json`` and rebuild its experiments (folders, or emulated footage from the store).

    ``forward``: the store and executor to simulate with (default: ``folder/store``, in this process); the run
    simulates with the simulating function its result.json names."""
    from similarity.estimate import emulate, get_preset
    from mpm.params import Setup

    folder = Path(folder)
    result, estimate = read_result(folder)
    path = folder / "result.json"
    preset = get_preset(result.get("preset", "demo"))
    # its own walls and solver, whatever the preset's now
    model = model_of(result)
    preset = replace(preset, slip_length_m=model.slip_length_m or 0.0, density_correction=model.density_correction)
    forward = (forward if forward is not None else Forward(folder / "store")).with_simulator(result.get("simulator"))
    setups = [Setup.parse(s) for s in result.get("setups", [])]
    truth = None
    if result.get("folders"):
        from mpm.experiment import load

        experiments = [load(d) for d in result["folders"]]
    elif result.get("truth"):
        t = result["truth"]
        truth = Material(float(t["eta"]), float(t["n"]), float(t["sigma_y"]))
        info = result.get("experiments") or []
        experiments = []
        for i, s in enumerate(setups):
            density = float(info[i]["density"]) if i < len(info) else DEFAULT_DENSITY_KG_M3
            experiments += emulate(truth, [s], density=density, preset=preset, forward=forward)
    else:
        raise ValueError(f"{path}: names neither experiment folders nor a ground truth; cannot rebuild the footage")
    if not experiments:
        raise ValueError(f"{path}: no setups")
    return Run(folder, result, estimate, experiments, preset, forward, truth,
               setups or [Setup(e.width_mm, e.height_mm) for e in experiments])
