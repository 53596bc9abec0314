"""Credible levels of a known truth under posterior samples, and the coverage they give over many cases.

The *credible level* of the truth is the smallest level whose region contains it; the truth lies in the
level-a region iff its credible level is <= a, so the empirical coverage at every level (the reliability
curve, :func:`coverage`) follows from one number per case and region.  Regions, all in the normalised space:

* ``hpd``: the highest-posterior-density region {x : p(x | footage) >= c_a}, c_a set so that it holds a
  fraction a of the samples; the truth's level is the fraction of samples denser than the truth.  This is the
  smallest region of posterior mass a, the one "the 90 % credible region" names; it follows the posterior's
  curved similarity valley.  Outside the emulator's trust region the posterior is zero, so a truth there lies
  in no region (level 1).
* ``ellipsoid``: the Mahalanobis ellipsoid of the samples' mean and covariance holding a fraction a of them
  (the shape of the ellipsoid ``virheo report`` draws).
* ``intervals``: per parameter, the central interval between the (1-a)/2 and (1+a)/2 quantiles; the joint
  level is the largest of the three (all three intervals hold the truth).

:func:`tempered_level` gives the HPD level had the likelihood been raised to a power k (N_eff of eq. (1) in
similarity/likelihood.py times k), from the same samples: how a calibrated count is predicted.
"""
from __future__ import annotations

import numpy as np

LEVELS = np.round(np.arange(0.1, 0.95, 0.1), 2)  # nominal levels of the reliability curve
NOMINAL = 0.9  # the level the acceptance test names
REGIONS = ("hpd", "ellipsoid", "intervals")
TEMPERING = (1.0, 2.0, 3.0, 4.0, 6.0, 8.0)  # N_eff times k: the likelihood of eq. (1) raised to the power k
PARAMETERS = ("eta", "n", "sigma_y")


def credible_levels(samples, truth, *, log_density=None) -> dict:
    """Credible level of ``truth`` (normalised, (3,)) under posterior ``samples`` (k, 3) for every region kind
    (module docstring) and per parameter.  ``log_density``: the unnormalised log-posterior, vectorised
    ((m, 3) -> (m,), -inf outside the support); without it the ``hpd`` level is not computed (None)."""
    X = np.asarray(samples, float)
    t = np.asarray(truth, float)
    if X.ndim != 2 or X.shape[1] != t.size or len(X) < 2:
        raise ValueError("need at least two samples (k, d) and a truth of d values")
    out: dict = {}
    if log_density is not None:
        lp = np.asarray(log_density(X), float)
        lt = float(np.asarray(log_density(t[None]), float)[0])
        out["hpd"] = 1.0 if not np.isfinite(lt) else float(np.mean(lp > lt))
    else:
        out["hpd"] = None
    d = X - X.mean(axis=0)
    prec = np.linalg.pinv(np.cov(X, rowvar=False))
    d2 = np.einsum("ij,jk,ik->i", d, prec, d)
    dt = t - X.mean(axis=0)
    out["ellipsoid"] = float(np.mean(d2 < dt @ prec @ dt))
    per = np.abs(2.0 * np.mean(X <= t, axis=0) - 1.0)  # central interval of level a holds t iff |2F - 1| <= a
    out["intervals"] = float(np.max(per))
    out["per_parameter"] = dict(zip(PARAMETERS, per.tolist()))
    return out


def coverage(levels_of_truth, nominal=LEVELS) -> np.ndarray:
    """Empirical coverage at each nominal level: the fraction of cases whose credible level is <= it."""
    v = np.asarray([1.0 if x is None else x for x in levels_of_truth], float)
    if v.size == 0:
        return np.full(np.shape(nominal), np.nan)
    return np.mean(v[:, None] <= np.asarray(nominal, float)[None, :] + 1e-12, axis=0)


def tempering_weights(log_prob, k: float) -> np.ndarray:
    """Weights that make samples of the posterior p (``log_prob``: each sample's log p, up to a constant) samples
    of p^k / Z, the posterior with N_eff of eq. (1) times ``k`` under the uniform prior: p^(k-1), scaled so that
    the densest sample weighs 1; a sample where p = 0 weighs 0."""
    lp = np.asarray(log_prob, float)
    ok = np.isfinite(lp)
    if not ok.any():
        raise ValueError("need samples with a finite log-posterior")
    w = np.zeros_like(lp)
    w[ok] = np.exp((float(k) - 1.0) * (lp[ok] - lp[ok].max()))
    return w


def tempered_level(log_prob, level: float, k: float) -> tuple[float, float]:
    """The truth's HPD credible level had N_eff been ``k`` times the one counted, from the samples as run.

    Eq. (1) with k N_eff is the likelihood raised to the power k, so under the uniform prior the posterior
    becomes p^k / Z: the same samples, weighted by p^(k-1).  Its HPD regions are p's (the same ordering), so the
    samples denser than the truth are still the top fraction ``level`` by ``log_prob`` (the sampled log-posterior,
    one per sample); the new level is their share of the weight.  Also returns the weights' effective sample
    size as a fraction of the samples (Kish), which says how far the reweighting can be trusted.  An
    approximation: the emulator's box and checks stay as they ran at k = 1."""
    lp = np.sort(np.asarray(log_prob, float))[::-1]
    w = tempering_weights(lp, k)
    m = int(round(float(level) * lp.size))
    return float(w[:m].sum() / w.sum()), kish_fraction(w)


def kish_fraction(weights) -> float:
    """Kish's effective sample size of weighted samples, (sum w)^2 / sum w^2, as a fraction of the samples."""
    w = np.asarray(weights, float)
    return float(w.sum() ** 2 / np.sum(w * w) / w.size)


def tempered_summary(per_case: list) -> dict | None:
    """Per k of :data:`TEMPERING`, over the cases' ``tempered`` levels: how many truths the 90 % HPD region
    holds, the median level (0.5 if calibrated), how many lie below 0.4 (40 % if calibrated) and the smallest
    weights' ESS fraction."""
    if not per_case:
        return None
    out = {}
    for k in per_case[0]:
        lv = np.array([t[k][0] for t in per_case])
        out[k] = {"cases": len(lv), "inside_90": int(round(len(lv) * coverage(lv, [NOMINAL])[0])),
                  "median_level": float(np.median(lv)), "below_0_4": int(np.sum(lv < 0.4)),
                  "min_ess_fraction": float(min(t[k][1] for t in per_case))}
    return out
