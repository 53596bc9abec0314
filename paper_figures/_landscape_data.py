"""Where Figs. 6, 7 and 9 find the landscape study's output, and the one-line message when it is missing."""
from __future__ import annotations

import importlib.util
from pathlib import Path

from paper_figures._plot import MissingData

COMMANDS = {"landscapes": "virheo study landscapes --out DIR", "conditioning": "virheo study conditioning --out DIR"}


def require(study: str, folder, figure: str) -> Path:
    """The study's output folder; MissingData naming the command that makes it when absent."""
    how = f"run `{COMMANDS[study]}`, then `virheo figures --only {figure} --landscapes DIR`"
    if importlib.util.find_spec("studies.landscapes") is None:
        raise MissingData(f"needs the {study} study, which this version does not have yet ({how})")
    if folder is None or not Path(folder).is_dir():
        raise MissingData(f"needs the {study} study's output: {how}")
    return Path(folder)
