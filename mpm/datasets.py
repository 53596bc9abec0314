"""Where the shared (read-only) data live: ``$VIRHEO_DATA`` or ``../shared/data`` beside the repo.

The footage is CC BY-NC 4.0 by the paper's authors and is never copied into this repository.
"""
from __future__ import annotations

import csv
import os
from pathlib import Path

_REPO = Path(__file__).resolve().parent.parent


def data_dir() -> Path | None:
    """The shared data folder, or None when it is absent."""
    env = os.environ.get("VIRHEO_DATA")
    candidates = [Path(env)] if env else []
    candidates += [_REPO.parent / "shared" / "data", Path.cwd().parent / "shared" / "data"]
    for c in candidates:
        if (c / "real_world").is_dir():
            return c
    return None


def require_data_dir() -> Path:
    d = data_dir()
    if d is None:
        raise FileNotFoundError("shared data not found: set VIRHEO_DATA or place it at ../shared/data")
    return d


def real_world_dir() -> Path:
    return require_data_dir() / "real_world"


def _rows(path: Path) -> list[dict]:
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def manifest() -> list[dict]:
    """Rows of real_world/manifest.csv (folder, material, setup, density, the paper's Table-1 estimate in SI)."""
    return _rows(real_world_dir() / "manifest.csv")


def material_rows(material: str) -> list[dict]:
    """The manifest rows (:func:`manifest`) of one material (case-insensitive name), in setup order."""
    rows = [r for r in manifest() if r["material"].lower() == material.lower()]
    return sorted(rows, key=lambda r: int(r["setup_index"]))


def table1(row: dict):
    """The paper's Table-1 estimate of a manifest row (:func:`manifest`), as a :class:`mpm.params.Material` (SI)."""
    from mpm.params import Material

    return Material(float(row["paper_eta_Pa_s_n"]), float(row["paper_n"]), float(row["paper_sigma_y_Pa"]))


def first_estimates() -> list[dict]:
    """Rows of real_world/first_estimates.csv (estimate after setup 1 in SI, chosen second setup in cm)."""
    return _rows(real_world_dir() / "first_estimates.csv")
