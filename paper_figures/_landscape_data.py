"""Where Figs. 6, 7 and 9 find the landscape study's output, and the one-line message when it is missing.

``virheo figures --landscapes DIR`` names a folder written by ``virheo study landscapes`` (its
``landscapes.json``); Fig. 9 reads ``conditioning.json`` from DIR or from DIR/conditioning (written by
``virheo study conditioning``). In quick mode without a folder, a tiny study is run through the store
into ``OUT/landscape-study``: 2 materials x 1 setup on a 3^3 block (demo preset) and the condition
numbers of the first material over a 2 x 2 setup grid.
"""
from __future__ import annotations

import importlib.util
import json
from pathlib import Path

from paper_figures._plot import MissingData

COMMANDS = {"landscapes": "virheo study landscapes --out DIR", "conditioning": "virheo study conditioning --out DIR"}
QUICK_FOLDER = "landscape-study"
CONDITIONING_FILE = "conditioning.json"


def require(study: str, folder, figure: str) -> Path:
    """The study's output folder; MissingData naming the command that makes it when absent."""
    how = f"run `{COMMANDS[study]}`, then `virheo figures --only {figure} --landscapes DIR`"
    if importlib.util.find_spec("studies.landscapes") is None:
        raise MissingData(f"needs the {study} study, which this version does not have yet ({how})")
    if folder is None or not Path(folder).is_dir():
        raise MissingData(f"needs the {study} study's output: {how}")
    return Path(folder)


def quick_study(out_dir, context) -> Path:
    """Run (or reuse) the tiny quick-mode landscape study in ``out_dir/landscape-study``."""
    from studies import landscapes as LS

    folder = Path(out_dir) / QUICK_FOLDER
    if not (folder / LS.RESULT_FILE).is_file():
        config = LS.StudyConfig(materials=2, setups_per_material=1, grid=3, half_width=0.05, fd_step=0.05, preset="demo")
        LS.run(folder, config, forward=context.resolved_forward(out_dir).with_simulator(context.simulator), plots=0)
    return folder


def landscapes(out_dir, quick: bool, context, figure: str) -> dict:
    """The landscape study's ``landscapes.json`` (the quick study's when quick and no folder is given)."""
    if context.landscapes is None and quick and importlib.util.find_spec("studies.landscapes") is not None:
        folder = quick_study(out_dir, context)
    else:
        folder = require("landscapes", context.landscapes, figure)
    from studies import landscapes as LS

    try:
        return LS.load(folder)
    except (OSError, ValueError) as exc:
        raise MissingData(f"{exc}; run `{COMMANDS['landscapes']}`") from None


def conditioning(out_dir, quick: bool, context, figure: str) -> dict:
    """The conditioning study's ``conditioning.json`` (quick: computed for the quick study's first material)."""
    if context.landscapes is None and quick and importlib.util.find_spec("studies.landscapes") is not None:
        from mpm.params import Material
        from studies import landscapes as LS

        data = landscapes(out_dir, quick, context, figure)
        folder = Path(out_dir) / QUICK_FOLDER / "conditioning"
        if not (folder / CONDITIONING_FILE).is_file():
            material = Material(**data["pairs"][0]["material"])
            LS.conditioning(folder, material, steps=2, fd_step=data["config"]["fd_step"], preset="demo",
                            forward=context.resolved_forward(out_dir).with_simulator(context.simulator))
    else:
        base = require("conditioning", context.landscapes, figure)
        folder = next((f for f in (base, base / "conditioning") if (f / CONDITIONING_FILE).is_file()), None)
        if folder is None:
            raise MissingData(f"no {CONDITIONING_FILE} in {base} or {base / 'conditioning'}: run "
                              f"`virheo study conditioning --material ETA,N,SIGMA_Y --out {base / 'conditioning'}`")
    try:
        data = json.loads((folder / CONDITIONING_FILE).read_text())
    except (OSError, ValueError) as exc:
        raise MissingData(f"{folder / CONDITIONING_FILE} is unreadable ({exc}); run `{COMMANDS['conditioning']}`") from None
    if not isinstance(data, dict) or "condition" not in data:
        raise MissingData(f"{folder / CONDITIONING_FILE} is not a conditioning study; run `{COMMANDS['conditioning']}`")
    return data


def matched_pairs(out_dir, quick: bool, context, figure: str, count: int) -> tuple[dict, float, list[dict]]:
    """(study data, half-width of its landscape block, up to ``count`` matched landscapes) for ``figure``."""
    import numpy as np

    data = landscapes(out_dir, quick, context, figure)
    hw = float(np.max(np.abs(np.asarray(data["offsets"], dtype=float))))
    pairs = pick_pairs(data["pairs"], count)
    if not pairs:
        raise MissingData("the landscape study has no matched landscape; run `virheo study landscapes --out DIR`")
    return data, hw, pairs


def pick_pairs(records, count: int) -> list[dict]:
    """Up to ``count`` matched landscapes, one per material first (the study lists a material's setups together)."""
    matched = [r for r in records if r.get("match")]
    seen, first, rest = set(), [], []
    for r in matched:
        key = tuple(sorted(r["material"].items()))
        (rest if key in seen else first).append(r)
        seen.add(key)
    return (first + rest)[:count]
