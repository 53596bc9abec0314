"""Material and setup spaces of the paper (sections 3.1-3.3), in SI units (setups in mm).

``Material``, ``Setup`` and the ranges live in ``mpm.params`` (import them from there). The material
space box (eta 1e-4..30 Pa s^n, n 0.3..1, sigma_y 0..40 Pa) is linearly mapped onto the normalised space
[0, 1]^3 used by CMA-ES and the loss normals; the candidate setups cover 20..70 mm in 1 mm steps.
"""
from __future__ import annotations

import numpy as np

from mpm import params

__all__ = ["LOWER", "UPPER", "EXTENT", "normalize", "denormalize", "center", "candidate_setups", "e_rel"]

# Bounds of the paper's material space (SI), in the order (eta, n, sigma_y).
LOWER = np.array([params.ETA_RANGE[0], params.N_RANGE[0], params.SIGMA_Y_RANGE[0]])
UPPER = np.array([params.ETA_RANGE[1], params.N_RANGE[1], params.SIGMA_Y_RANGE[1]])
EXTENT = UPPER - LOWER


def normalize(x) -> np.ndarray:
    """Material parameters (..., 3) in SI -> normalised material space [0, 1]^3."""
    return (np.asarray(x, dtype=float) - LOWER) / EXTENT


def denormalize(u) -> np.ndarray:
    """Normalised material space (..., 3) -> SI parameters (eta, n, sigma_y)."""
    return LOWER + np.asarray(u, dtype=float) * EXTENT


def center() -> params.Material:
    """Centre of the material space (initial CMA-ES mean for the first setup)."""
    return params.Material.from_array(denormalize([0.5, 0.5, 0.5]))


def candidate_setups() -> tuple[np.ndarray, np.ndarray]:
    """All 51 x 51 = 2601 candidate setups: (width_mm, height_mm) arrays, height outer, width inner."""
    lo, hi = params.SETUP_RANGE_MM
    sizes = np.arange(lo, hi + 1, dtype=float)
    h, w = np.meshgrid(sizes, sizes, indexing="ij")
    return w.ravel(), h.ravel()


def e_rel(truth, estimate) -> float:
    """Relative error E_rel between two materials, normalised by the material-space extents (eq. 44)."""
    a, b = params.material_array(truth), params.material_array(estimate)
    return float(np.sqrt(np.sum(((b - a) / EXTENT) ** 2)))
