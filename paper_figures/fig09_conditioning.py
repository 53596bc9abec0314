"""Paper Fig. 9: condition number of the finite-difference loss Hessian over the setup grid.

Drawn from the conditioning study's output (`conditioning` of `virheo study`); without it ``make`` raises
:class:`MissingData` naming the command that makes it.
"""
from __future__ import annotations

from pathlib import Path

from paper_figures._landscape_data import require
from paper_figures._plot import Context, MissingData


def make(out_dir, quick: bool = False, *, context: Context | None = None) -> list[Path]:
    context = context or Context()
    require("conditioning", context.landscapes, "fig09")
    raise MissingData("fig9: the conditioning study's output format is not wired up yet")
