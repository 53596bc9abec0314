"""Finite-difference Hessian of a loss landscape, its eigenvalues, loss normal and condition number (section 5.2).

The dam-break loss L(M~, M; S) is the fraction of differing silhouette pixels (eq. 3). It is zero at
M~ = M and, because a boundary displaced by a small distance changes a number of pixels proportional
to that distance, it grows roughly like |Delta M| rather than |Delta M|^2; on top of that the pixel
grid quantises it. A second difference with a tiny step therefore measures pixel noise, not the
valley. The stencil here is the 3 x 3 x 3 block around M minus its eight corners (the centre, 6 face
and 12 edge points) with one step h in the normalised material space:

    H_ii = (f(+h e_i) - 2 f(0) + f(-h e_i)) / h^2
    H_ij = (f(+h e_i + h e_j) - f(+h e_i - h e_j) - f(-h e_i + h e_j) + f(-h e_i - h e_j)) / (4 h^2)

18 simulations besides the reference. Because every point uses the same step, the Hessian's
eigenvectors, hence the loss normal q_max (the eigenvector of the largest eigenvalue, section 5.2), do
not depend on how the loss grows with distance, only on the shape of its valley; the step must be
large enough that each probe moves the silhouettes by several pixels (docs/landscapes.md studies it).

Everything here works in the normalised material space, so normals are comparable to
:func:`similarity.normals.normals_at`. This is the one finite-difference Hessian of the project: the Laplace
approximation of the posterior (similarity/posterior.py) takes it too. The eigenvector sign rule
(:func:`canonical_sign`) and the sign-blind comparison of normals (:func:`abs_cos`, :func:`angle_deg`) live
here as well.
"""
from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np


def stencil(step: float) -> np.ndarray:
    """Offsets (18, 3) of the stencil: +-h e_i (6), then the 12 diagonal pairs +-h e_i +-h e_j."""
    if not step > 0:
        raise ValueError(f"finite-difference step {step} must be > 0")
    e = np.eye(3)
    rows = [s * e[i] for i in range(3) for s in (1.0, -1.0)]
    for i, j in combinations(range(3), 2):
        for si, sj in ((1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)):
            rows.append(si * e[i] + sj * e[j])
    return step * np.array(rows)


def hessian_from_stencil(values, step: float, center: float = 0.0) -> np.ndarray:
    """The central-difference Hessian (3, 3) from the 18 loss values at :func:`stencil` (same order)."""
    f = np.asarray(values, dtype=float)
    if f.shape != (18,):
        raise ValueError(f"need the 18 stencil values, got shape {f.shape}")
    h = np.empty((3, 3))
    for i in range(3):
        h[i, i] = (f[2 * i] - 2.0 * center + f[2 * i + 1]) / step**2
    k = 6
    for i, j in combinations(range(3), 2):
        pp, pm, mp, mm = f[k:k + 4]
        h[i, j] = h[j, i] = (pp - pm - mp + mm) / (4.0 * step**2)
        k += 4
    return h


def fd_hessian(loss, x0, step: float) -> np.ndarray:
    """Hessian of ``loss`` (a callable taking points (k, 3), returning (k,) values) at ``x0``."""
    x0 = np.asarray(x0, dtype=float)
    offsets = stencil(step)
    values = np.asarray(loss(x0 + offsets), dtype=float)
    center = float(np.asarray(loss(x0[None, :]), dtype=float).ravel()[0])
    return hessian_from_stencil(values, step, center)


@dataclass(frozen=True)
class Spectrum:
    """Eigen-analysis of a loss Hessian (section 5.2)."""

    eigenvalues: np.ndarray  # ascending
    eigenvectors: np.ndarray  # columns, matching ``eigenvalues``
    q_max: np.ndarray  # unit eigenvector of the largest eigenvalue, largest-magnitude component > 0

    @property
    def condition(self) -> float:
        """|lambda_max| / |lambda_min| (inf when the smallest eigenvalue is 0)."""
        lo = abs(float(self.eigenvalues[np.argmin(np.abs(self.eigenvalues))]))
        hi = float(np.max(np.abs(self.eigenvalues)))
        return float("inf") if lo == 0 else hi / lo

    def to_dict(self) -> dict:
        return {"eigenvalues": self.eigenvalues.tolist(), "q_max": self.q_max.tolist(), "condition": self.condition}


def spectrum(h) -> Spectrum:
    """Eigenvalues, eigenvectors and the loss normal q_max of a symmetric 3 x 3 Hessian."""
    h = np.asarray(h, dtype=float)
    if h.shape != (3, 3) or not np.all(np.isfinite(h)):
        raise ValueError("the Hessian must be a finite 3 x 3 matrix (a simulation of its stencil failed?)")
    vals, vecs = np.linalg.eigh(0.5 * (h + h.T))
    return Spectrum(vals, vecs, canonical_sign(vecs[:, -1]))


def canonical_sign(v) -> np.ndarray:
    """Vectors (..., k) whose sign is arbitrary (eigenvectors), each flipped so that its largest-magnitude
    component is positive; NaN stays NaN."""
    v = np.asarray(v, dtype=float)
    big = np.take_along_axis(v, np.argmax(np.abs(v), axis=-1)[..., None], axis=-1)
    return v * np.sign(big)


def abs_cos(a, b) -> np.ndarray:
    """|cos| of the angle between directions (..., k), sign-blind (a normal and its negative agree): 0..1."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    return np.abs(np.sum(a * b, axis=-1)) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))


def angle_deg(a, b) -> np.ndarray:
    """Angle in degrees between loss normals (..., 3), sign-blind (a normal and its negative agree): 0..90."""
    return np.degrees(np.arccos(np.clip(abs_cos(a, b), 0.0, 1.0)))
