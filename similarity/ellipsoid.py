"""Similarity ellipsoids: the region of materials the footage cannot tell apart, in the normalised space.

A covariance C (posterior samples, or the inverse of the finite-difference Hessian of the negative
log-posterior, the Laplace approximation) defines the credible ellipsoid
{x : (x - m)^T C^-1 (x - m) <= chi2_3(level)}.  Its axes are C's eigenvectors and its semi-axis
lengths sqrt(lambda_i chi2_3(level)).  The *thin* axis (smallest length) is the direction the footage
pins down; section 5 predicts it to be the loss normal of the plane-Poiseuille Hessian
(similarity/normals.py), which :func:`alignment` checks. The Laplace approximation's Hessian is the one
finite-difference Hessian, :func:`similarity.fd_hessian.fd_hessian`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from .fd_hessian import abs_cos, canonical_sign


@dataclass(frozen=True)
class Ellipsoid:
    """Credible ellipsoid: centre (3,), axes as unit columns (3, 3) sorted thin -> long, semi-axis lengths."""

    center: np.ndarray
    axes: np.ndarray
    lengths: np.ndarray
    level: float

    @property
    def thin(self) -> np.ndarray:
        return self.axes[:, 0]

    def to_dict(self) -> dict:
        return {"center": self.center.tolist(), "axes": self.axes.T.tolist(), "lengths": self.lengths.tolist(),
                "level": self.level}

    @classmethod
    def from_dict(cls, d: dict) -> "Ellipsoid":
        """The inverse of :meth:`to_dict` (which writes the axes as rows)."""
        return cls(np.asarray(d["center"], float), np.asarray(d["axes"], float).T, np.asarray(d["lengths"], float),
                   float(d["level"]))


def ellipsoid(center, cov, level: float = 0.9) -> Ellipsoid:
    """Credible ellipsoid of a Gaussian with covariance ``cov`` (normalised space) at ``level``."""
    cov = np.asarray(cov, float)
    if cov.shape != (3, 3) or not np.all(np.isfinite(cov)):
        raise ValueError("the covariance must be a finite 3 x 3 matrix")
    lam, vec = np.linalg.eigh(0.5 * (cov + cov.T))
    if lam[0] <= 0:
        raise ValueError("the covariance is not positive definite")
    axes = canonical_sign(vec.T).T
    return Ellipsoid(np.asarray(center, float), axes, np.sqrt(lam * chi2.ppf(level, 3)), float(level))


def alignment(thin_direction, normal) -> float:
    """|cos| of the angle between the thin axis and a loss normal (1: the normal predicts it exactly)."""
    return float(abs_cos(thin_direction, normal))
