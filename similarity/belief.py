"""The belief after a CMA-ES stage, from the losses the stage already evaluated (no further simulation).

Approximation (Laplace, on the stage's own evaluations).  Near the estimate the mean video loss is
quadratic in the normalised material coordinates x,

    L(x) ~= L0 + g.(x - x*) + 1/2 (x - x*)^T H (x - x*),

and with the likelihood's convention log p(footage | x) = -tau L(x) (similarity/likelihood.py, eq. 1) the
posterior under the uniform prior on [0, 1]^3 is approximately Gaussian with precision

    Sigma^-1 = tau H_+ + 12 I.

* H is the Hessian of a least-squares quadratic (10 coefficients) fitted to the best evaluations of the
  stage's archive (the lowest losses, at least ``MIN_POINTS`` and ``FRACTION`` of the archive), in
  coordinates centred on the best point and scaled per axis by the spread of the fitted points.
* H_+ is H projected onto the positive semi-definite matrices (the nearest one in the Frobenius norm:
  negative eigenvalues set to zero).  A direction without measured curvature (along a similarity valley,
  or where the fit is noise) keeps the prior's variance; ``projected`` says when that happened.
* 12 I is the precision of the uniform prior on the unit box (variance 1/12 per axis); it keeps Sigma
  positive definite.
* tau = N_eff / (2 s^2) is the likelihood's precision (:class:`similarity.likelihood.NoiseScale`) with
  N_eff one independent residual per frame and s^2 = L(x*), the stage's best loss.  The discretisation
  and emulator terms of s^2 are left out, since estimating them costs simulations; tau is then an
  upper bound and the belief a little narrow.  The expected information gain of
  :func:`similarity.design.rank_setups` fits its information scale to Sigma, so its ranking depends on
  the belief's shape and on tau only through the prior's share of Sigma^-1.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

PRIOR_PRECISION = 12.0  # 1 / variance of the uniform distribution on [0, 1], per axis
MIN_POINTS = 30  # evaluations the quadratic fit uses at least (it has 10 coefficients)
FRACTION = 0.25  # share of the archive, best first, that the quadratic fit uses


@dataclass(frozen=True)
class Belief:
    """Gaussian belief N(center, covariance) in the normalised material space."""

    center: np.ndarray  # (3,) the best evaluated point
    hessian: np.ndarray  # (3, 3) fitted loss Hessian H (before projection)
    covariance: np.ndarray  # (3, 3) (tau H_+ + prior I)^-1
    precision: float  # tau
    points: int  # evaluations the fit used
    projected: bool  # H had an eigenvalue <= 0 that was set to zero

    def to_dict(self) -> dict:
        return {"center": self.center.tolist(), "hessian": self.hessian.tolist(),
                "covariance": self.covariance.tolist(), "precision": self.precision, "points": self.points,
                "projected": self.projected}


def quadratic_hessian(X, loss) -> np.ndarray:
    """Hessian (d, d) of the least-squares quadratic through points X (k, d) with values ``loss`` (k,).

    ValueError when the points do not determine a quadratic (fewer than 1 + d + d(d+1)/2, or degenerate).
    """
    X = np.asarray(X, float)
    f = np.asarray(loss, float)
    k, d = X.shape
    pairs = [(i, j) for i in range(d) for j in range(i, d)]
    n_coef = 1 + d + len(pairs)
    if k < n_coef:
        raise ValueError(f"{k} points cannot determine a quadratic in {d} variables ({n_coef} coefficients)")
    centre = X[np.argmin(f)]
    scale = X.std(axis=0)
    if np.any(scale <= 0):
        raise ValueError("the points do not spread along every axis: no quadratic fit")
    Z = (X - centre) / scale
    A = np.column_stack([np.ones(k), Z] + [Z[:, i] * Z[:, j] for i, j in pairs])
    coef, _, rank, _ = np.linalg.lstsq(A, f, rcond=None)
    if rank < n_coef:
        raise ValueError("the points are degenerate: no unique quadratic fit")
    hz = np.zeros((d, d))
    for c, (i, j) in zip(coef[1 + d:], pairs):
        if i == j:
            hz[i, i] = 2.0 * c  # d^2/dz_i^2 of c z_i^2
        else:
            hz[i, j] = hz[j, i] = c
    return hz / np.outer(scale, scale)  # back to x = centre + scale * z


def psd_projection(h) -> tuple[np.ndarray, bool]:
    """Nearest symmetric positive semi-definite matrix (Frobenius norm) and whether any eigenvalue was <= 0."""
    sym = 0.5 * (np.asarray(h, float) + np.asarray(h, float).T)
    lam, vec = np.linalg.eigh(sym)
    return (vec * np.clip(lam, 0.0, None)) @ vec.T, bool(np.any(lam <= 0.0))


def frames_precision(loss_at_optimum: float, frames: int) -> float:
    """tau of eq. (1) with one independent residual per frame and s^2 = L(x*) (module docstring)."""
    from similarity.likelihood import NoiseScale

    return NoiseScale(n_pixels=0, n_eff=float(frames), loss_at_optimum=float(loss_at_optimum), discretisation=0.0,
                      emulator=0.0, frames=int(frames)).precision


def archive_belief(archive, precision: float, *, prior_precision: float = PRIOR_PRECISION, min_points: int = MIN_POINTS,
                   fraction: float = FRACTION) -> Belief:
    """The Laplace belief (module docstring) from rows [x0, x1, x2, loss] of a CMA-ES archive (normalised x)."""
    rows = np.asarray([r for r in archive if np.isfinite(r[3])], float).reshape(-1, 4)
    if not precision > 0:
        raise ValueError(f"precision={precision} must be > 0")
    use = max(int(min_points), int(np.ceil(fraction * len(rows))))
    if len(rows) < use:
        raise ValueError(f"the archive holds {len(rows)} finite evaluations; the belief needs at least {use}")
    best = rows[np.argsort(rows[:, 3], kind="stable")[:use]]
    h = quadratic_hessian(best[:, :3], best[:, 3])
    h_plus, projected = psd_projection(h)
    cov = np.linalg.inv(float(precision) * h_plus + float(prior_precision) * np.eye(3))
    return Belief(best[0, :3].copy(), h, 0.5 * (cov + cov.T), float(precision), use, projected)


def stage_belief(stage, frames_per_setup: int, **kw) -> Belief:
    """:func:`archive_belief` of a finished :class:`similarity.cma_stage.Stage` (its archive and warm-start
    rows) with tau from its best loss and ``frames_per_setup`` frames in each of its setups."""
    tau = frames_precision(stage.loss, frames_per_setup * len(stage.setups))
    return archive_belief(list(stage.archive) + list(stage.screened), tau, **kw)
