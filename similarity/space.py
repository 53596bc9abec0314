"""Material and setup spaces of the paper (sections 3.1-3.3), in SI units (setups in mm).

``Material``, ``Setup`` and the ranges live in ``mpm.params`` (import them from there). The material
space box (eta 1e-4..30 Pa s^n, n 0.3..1, sigma_y 0..40 Pa) is linearly mapped onto the normalised space
[0, 1]^3 used by CMA-ES and the loss normals; the candidate setups cover 20..70 mm in 1 mm steps.
"""
from __future__ import annotations

import numpy as np

from mpm import params

__all__ = ["LOWER", "UPPER", "EXTENT", "SEARCH_SPACES", "normalize", "denormalize", "to_search", "from_search", "center",
           "candidate_setups", "e_rel"]

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


# Coordinates CMA-ES samples in (Algorithm 1). "linear": the normalised space itself, as in the paper. "log-eta":
# log(eta) mapped onto [0, 1] over the same range, n and sigma_y unchanged: runny materials (eta ~ 1 Pa s^n) then lie
# in a valley of ordinary width instead of a sliver at the lower bound of eta (docs/decisions.md#presets).
SEARCH_SPACES = ("linear", "log-eta")
_LOG_ETA_SPAN = np.log(UPPER[0] / LOWER[0])


def _check_space(space: str) -> None:
    if space not in SEARCH_SPACES:
        raise ValueError(f"unknown search space {space!r}: choose one of {', '.join(SEARCH_SPACES)}")


def to_search(x, space: str) -> np.ndarray:
    """Normalised material space (..., 3) -> the search coordinates ``space`` (:data:`SEARCH_SPACES`)."""
    _check_space(space)
    u = np.array(x, dtype=float)
    if space == "log-eta":
        u[..., 0] = np.log((LOWER[0] + u[..., 0] * EXTENT[0]) / LOWER[0]) / _LOG_ETA_SPAN
    return u


def from_search(u, space: str) -> np.ndarray:
    """Search coordinates ``space`` (..., 3) -> normalised material space (the inverse of :func:`to_search`)."""
    _check_space(space)
    x = np.array(u, dtype=float)
    if space == "log-eta":
        x[..., 0] = (LOWER[0] * np.exp(x[..., 0] * _LOG_ETA_SPAN) - LOWER[0]) / EXTENT[0]
    return x


def center() -> params.Material:
    """Centre of the material space (initial CMA-ES mean for the first setup)."""
    return params.Material.from_array(denormalize([0.5, 0.5, 0.5]))


def candidate_setups() -> tuple[np.ndarray, np.ndarray]:
    """All 51 x 51 = 2601 candidate setups: (width_mm, height_mm) arrays, height outer, width inner."""
    lo, hi = params.SETUP_RANGE_MM
    sizes = np.arange(lo, hi + 1, dtype=float)
    h, w = np.meshgrid(sizes, sizes, indexing="ij")
    return w.ravel(), h.ravel()


FLOW_ERROR_RATES = (1.0, 100.0, 50)  # shear rates of flow_curve_error: 1..100 1/s, 50 log-spaced points


def flow_curve_error(truth, estimate, rates=FLOW_ERROR_RATES) -> float:
    """RMS over log-spaced shear rates (lo, hi, count) of log10(stress of the estimate) - log10(stress of the truth),
    stress by eq. 1: the error a user of the flow curve sees, the same anywhere along a similarity valley."""
    gamma = np.geomspace(*rates[:2], int(rates[2]))
    a, b = params.Material.of(truth), params.Material.of(estimate)
    r = np.log10(b.stress(gamma)) - np.log10(a.stress(gamma))
    return float(np.sqrt(np.mean(r * r)))


def e_rel(truth, estimate) -> float:
    """Relative error E_rel between two materials, normalised by the material-space extents (eq. 44)."""
    a, b = params.material_array(truth), params.material_array(estimate)
    return float(np.sqrt(np.sum(((b - a) / EXTENT) ** 2)))
