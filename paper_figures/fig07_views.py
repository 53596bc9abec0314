"""Paper Fig. 7: loss landscapes and silhouettes for two camera views.

Drawn from the landscapes study's output (`landscapes` of `virheo study`); without it ``make`` raises
:class:`MissingData` naming the command that makes it.
"""
from __future__ import annotations

from pathlib import Path

from paper_figures._landscape_data import require
from paper_figures._plot import Context, MissingData


def make(out_dir, quick: bool = False, *, context: Context | None = None) -> list[Path]:
    context = context or Context()
    require("landscapes", context.landscapes, "fig07")
    raise MissingData("fig7: the landscapes study's output format is not wired up yet")
