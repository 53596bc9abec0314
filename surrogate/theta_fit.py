"""Learning the conversion map Theta (section 5.5): matching score (eq. 43), the 1D search over P L,
and the reciprocal-polynomial fit as a scikit-learn ``Pipeline``.

* :func:`matching_score` weighs the dam-break loss values of a landscape by their closeness to the
  plane through M whose normal is a candidate plane-Poiseuille loss normal (eq. 43); low = good match.
* :func:`best_match` evaluates it for a set of candidate normals (one per wall stress C = P L of the
  1D search; the caller computes them from the Poiseuille Hessian) and returns the best.
* :func:`make_pipeline`: ten reciprocal features -> ``PolynomialFeatures(degree=2)`` ->
  :class:`DomainScaler` -> ``Ridge``. The target is the rate r = (C - C_lo) / (C_hi - C_lo) of
  :mod:`surrogate.theta`. :func:`fit` chooses the ridge's regularisation by leave-one-group-out
  cross-validation, a group being the landscapes of one material, so the chosen alpha is the one
  that predicts *unseen materials* best.
* :class:`DomainScaler` standardises each monomial by its spread over the whole input domain (the
  material space times the setup range), not over the training landscapes: the ridge penalty then
  charges a term for what it contributes wherever the map is used. Monomials such as
  1/sigma_y^2, whose values explode near sigma_y = 0 outside the sampled materials, are held small;
  with training-set scaling they are cheap and the map extrapolates wildly.
* :func:`to_theta_map` folds a fitted pipeline into the 66 coefficients of the published layout,
  :func:`pipeline_from_map` does the reverse, so a fitted map is saved with ``ThetaMap.save`` and
  read by ``surrogate.theta.load(path)`` unchanged.

Inputs of the pipeline are rows [eta, n, sigma_y, H, W] (SI, lengths in metres, height before width),
the order of the published map.
"""
from __future__ import annotations

import numpy as np
from sklearn.linear_model import Ridge
from sklearn.model_selection import LeaveOneGroupOut, cross_val_predict
from sklearn.pipeline import Pipeline
from sklearn.preprocessing import FunctionTransformer, PolynomialFeatures, StandardScaler

from surrogate.theta import N_COEFFS, ThetaMap, base_features, monomial_powers, monomial_weights

D0 = 0.025  # eq. 43
ALPHAS = np.logspace(-4, 4, 33)
DOMAIN_SAMPLES = 20000
MAX_INVALID = 0.002  # most of the input domain where a fitted map may leave its C extent


# -- eq. 43 --------------------------------------------------------------------------------------------
def matching_score(offsets, losses, normals, d0: float = D0) -> np.ndarray:
    """Eq. 43 for landscape points ``offsets`` (k, 3) = M~ - M (normalised space) with ``losses`` (k,),
    against candidate loss normals (..., 3): the exp(-d/d0)-weighted mean loss, d = |q . (M~ - M)|.

    Points with a NaN loss (failed simulations) are left out.
    """
    offsets = np.asarray(offsets, dtype=float)
    losses = np.asarray(losses, dtype=float)
    ok = np.isfinite(losses)
    if not np.any(ok):
        raise ValueError("every loss value of the landscape is NaN")
    q = np.asarray(normals, dtype=float)
    d = np.abs(q @ offsets[ok].T)  # (..., k)
    w = np.exp(-d / d0)
    return np.sum(w * losses[ok], axis=-1) / np.sum(w, axis=-1)


def refined_landscape(losses, grid: int, half_width: float, d0: float = D0) -> tuple[np.ndarray, np.ndarray]:
    """A ``grid``^3 landscape (losses in the index order of a regular block, ``half_width`` either side)
    interpolated trilinearly onto a block of spacing at most d0 / 2: (offsets (k, 3), losses (k,)).

    Eq. 43 weighs each point by exp(-d/d0); on a coarse block (3^3 at spacing 2 d0) a handful of points
    decide the score, which then jumps between plateaus as the candidate plane tilts. The silhouette
    loss grows about linearly away from M (a cone), so linear interpolation keeps its shape; the
    refined block gives the score the resolution of a dense landscape such as the paper's 8^3.
    """
    from scipy.interpolate import RegularGridInterpolator

    values = np.asarray(losses, dtype=float).reshape(grid, grid, grid)
    axis = half_width * np.linspace(-1.0, 1.0, grid)
    fine = max(grid, int(np.ceil(2.0 * half_width / (0.5 * d0) - 1e-9)) + 1)
    t = half_width * np.linspace(-1.0, 1.0, fine)
    pts = np.stack(np.meshgrid(t, t, t, indexing="ij"), axis=-1).reshape(-1, 3)
    return pts, RegularGridInterpolator((axis, axis, axis), values, method="linear")(pts)


def best_match(offsets, losses, candidate_normals, d0: float = D0) -> tuple[int, np.ndarray]:
    """(index of the best candidate, all scores) of the 1D search; NaN normals (no flow) never win."""
    q = np.asarray(candidate_normals, dtype=float)
    scores = np.full(q.shape[0], np.inf)
    valid = np.all(np.isfinite(q), axis=-1)
    if not np.any(valid):
        raise ValueError("no candidate Poiseuille setup gives a loss normal")
    scores[valid] = matching_score(offsets, losses, q[valid], d0)
    return int(np.argmin(scores)), scores


# -- the fit -------------------------------------------------------------------------------------------
def features(x, sigma_eps: float = 1e-4) -> np.ndarray:
    """The ten features of rows [eta, n, sigma_y, H, W] (SI): the five inputs and their reciprocals."""
    x = np.atleast_2d(np.asarray(x, dtype=float))
    if x.shape[-1] != 5:
        raise ValueError(f"Theta inputs must be rows [eta, n, sigma_y, H, W], got shape {x.shape}")
    return base_features(x[:, 0], x[:, 1], x[:, 2], x[:, 3], x[:, 4], sigma_eps)


def inputs(params, width_mm, height_mm) -> np.ndarray:
    """Rows [eta, n, sigma_y, H, W] (SI, metres) from materials (k, 3) and setups in mm."""
    p = np.atleast_2d(np.asarray(params, dtype=float))
    return np.column_stack([p, np.asarray(height_mm, float) * 1e-3, np.asarray(width_mm, float) * 1e-3])


def domain_sample(domain, samples: int = DOMAIN_SAMPLES, seed: int = 0) -> np.ndarray:
    """A fixed uniform sample of rows [eta, n, sigma_y, H, W] in the box ``domain`` = (lower, upper)."""
    lo, hi = (np.asarray(v, dtype=float) for v in domain)
    if lo.shape != (5,) or hi.shape != (5,) or np.any(hi <= lo):
        raise ValueError("the input domain needs lower < upper for each of eta, n, sigma_y, H, W")
    return lo + (hi - lo) * np.random.default_rng(seed).random((samples, 5))


class DomainScaler(StandardScaler):
    """``StandardScaler`` whose mean and spread are those of the monomials over the input domain,
    rows [eta, n, sigma_y, H, W] uniform in the box ``lower`` .. ``upper`` (a fixed sample), whatever
    the training rows are."""

    def __init__(self, lower=None, upper=None, sigma_eps: float = 1e-4, samples: int = DOMAIN_SAMPLES, seed: int = 0):
        super().__init__()
        self.lower, self.upper, self.sigma_eps, self.samples, self.seed = lower, upper, sigma_eps, samples, seed

    def fit(self, X, y=None, sample_weight=None):
        x = domain_sample((self.lower, self.upper), self.samples, self.seed)
        z = PolynomialFeatures(degree=2).fit_transform(features(x, self.sigma_eps))
        if z.shape[1] != np.shape(X)[1]:
            raise ValueError(f"DomainScaler expects the {z.shape[1]} degree-2 monomials, got {np.shape(X)[1]} columns")
        return super().fit(z)


def make_pipeline(domain, sigma_eps: float = 1e-4, alpha: float = 1.0) -> Pipeline:
    """Reciprocal features -> degree-2 monomials -> standardisation over ``domain`` = (lower, upper)
    rows [eta, n, sigma_y, H, W] -> ridge with regularisation ``alpha``."""
    return Pipeline([
        ("reciprocal", FunctionTransformer(features, kw_args={"sigma_eps": sigma_eps})),
        ("poly", PolynomialFeatures(degree=2)),
        ("scale", DomainScaler(lower=domain[0], upper=domain[1], sigma_eps=sigma_eps)),
        ("ridge", Ridge(alpha=alpha)),
    ])


def _permutation(poly: PolynomialFeatures) -> np.ndarray:
    cols = {tuple(p): i for i, p in enumerate(poly.powers_)}
    return np.array([cols[tuple(p)] for p in monomial_powers()])


def to_theta_map(pipe: Pipeline, name: str = "fitted", attribution: str = "", c_extent_pa=(5.0, 500.0),
                 p_pa_per_m: float = 2500.0, prior: ThetaMap | None = None) -> ThetaMap:
    """The 66 published-layout coefficients of a fitted pipeline (scaler folded into the linear model),
    plus those of ``prior`` when the pipeline was fitted to the correction of a prior map."""
    poly, scale, lin = pipe.named_steps["poly"], pipe.named_steps["scale"], pipe.named_steps["ridge"]
    coef = np.asarray(lin.coef_, dtype=float).ravel() / scale.scale_
    intercept = float(lin.intercept_) - float(coef @ scale.mean_)
    perm = _permutation(poly)
    theta = coef[perm] / monomial_weights()  # stored monomials carry weight 1/(e_i! e_j!)
    theta[0] += intercept  # monomial 0 is the constant 1
    if prior is not None:
        theta = theta + prior.theta
    eps = pipe.named_steps["reciprocal"].kw_args["sigma_eps"]
    return ThetaMap(theta, name=name, attribution=attribution, sigma_eps=eps, c_extent_pa=tuple(c_extent_pa),
                    p_pa_per_m=p_pa_per_m)


def pipeline_from_map(theta: ThetaMap) -> Pipeline:
    """A fitted-looking pipeline whose predictions are ``theta.rate`` (identity scaler, fixed coefficients)."""
    pipe = Pipeline([
        ("reciprocal", FunctionTransformer(features, kw_args={"sigma_eps": theta.sigma_eps})),
        ("poly", PolynomialFeatures(degree=2)),
        ("scale", StandardScaler()),
        ("ridge", Ridge()),
    ])
    poly = pipe.named_steps["poly"].fit(np.ones((1, 10)))
    scale = pipe.named_steps["scale"]
    scale.mean_, scale.scale_, scale.var_ = np.zeros(N_COEFFS), np.ones(N_COEFFS), np.ones(N_COEFFS)
    scale.n_features_in_, scale.n_samples_seen_ = N_COEFFS, 1
    coef = np.empty(N_COEFFS)
    coef[_permutation(poly)] = np.asarray(theta.theta) * monomial_weights()
    lin = pipe.named_steps["ridge"]
    lin.coef_, lin.intercept_, lin.n_features_in_ = coef, 0.0, N_COEFFS
    pipe.named_steps["reciprocal"].fit(np.ones((1, 5)))
    return pipe


def rate_of_stress(c_pa, c_extent_pa=(5.0, 500.0)) -> np.ndarray:
    """r = (C - C_lo) / (C_hi - C_lo): the target of the fit for wall shear stresses C = P L [Pa]."""
    lo, hi = c_extent_pa
    return (np.asarray(c_pa, dtype=float) - lo) / (hi - lo)


def fit(x, c_pa, groups=None, *, domain, sigma_eps: float = 1e-4, c_extent_pa=(5.0, 500.0),
        alphas=ALPHAS, prior: ThetaMap | None = None, max_invalid: float = MAX_INVALID) -> tuple[Pipeline, dict]:
    """Fit Theta to inputs ``x`` (k, 5) and best-matching wall stresses ``c_pa`` (k,).

    ``groups`` (k,) labels the landscapes of one material (default: each landscape its own); alpha is
    the one of ``alphas`` with the smallest leave-one-group-out RMS error of C among those whose map
    predicts a C outside ``c_extent_pa`` on at most ``max_invalid`` of the input domain (a uniform
    sample): cross-validation only sees materials like the training ones, and a weakly regularised
    map can be exact there and negative for thin materials no landscape can sample (the published map
    leaves its extent on 0.18 % of the domain; with a ``prior`` its own fraction is allowed on top).
    ``domain`` = (lower, upper) bounds of [eta, n, sigma_y, H, W] (SI, metres) over which the monomials
    are standardised.
    With a ``prior`` map the pipeline fits the correction r - r_prior, so the ridge shrinks the map
    towards the prior instead of towards zero (:func:`to_theta_map` with the same prior adds it back).
    Returns the pipeline and a summary: alpha, the leave-one-group-out RMS error of the rate and of C [Pa].
    """
    x = np.atleast_2d(np.asarray(x, dtype=float))
    y = rate_of_stress(c_pa, c_extent_pa)
    if prior is not None:
        if prior.sigma_eps != sigma_eps or tuple(prior.c_extent_pa) != tuple(c_extent_pa):
            raise ValueError(f"the prior map '{prior.name}' uses another sigma_eps or C extent")
        y = y - prior.rate(x[:, 0], x[:, 1], x[:, 2], x[:, 4] * 1e3, x[:, 3] * 1e3)
    groups = np.arange(len(y)) if groups is None else np.asarray(groups)
    if len(x) != len(y) or len(groups) != len(y):
        raise ValueError(f"inputs, targets and groups differ in length ({len(x)}, {len(y)}, {len(groups)})")
    labels = np.unique(groups)
    if len(labels) < 3:
        raise ValueError(f"need matched landscapes of at least 3 materials, got {len(labels)}")
    pipe = make_pipeline(domain, sigma_eps)
    z = pipe[:3].fit_transform(x)  # the scaler does not depend on the training rows
    alphas = np.asarray(alphas, dtype=float)
    sq = np.array([np.sum((cross_val_predict(Ridge(alpha=a), z, y, groups=groups, cv=LeaveOneGroupOut()) - y) ** 2)
                   for a in alphas])
    xd = domain_sample(domain, seed=1)  # not the scaler's own sample
    zd = pipe[:3].transform(xd)
    base = np.zeros(len(xd)) if prior is None else prior.rate(xd[:, 0], xd[:, 1], xd[:, 2], xd[:, 4] * 1e3,
                                                              xd[:, 3] * 1e3)

    def outside(rate) -> float:  # fraction of the domain sample whose C leaves c_extent_pa (rate outside [0, 1])
        return float(np.mean((rate < 0) | (rate > 1)))

    invalid = np.array([outside(Ridge(alpha=a).fit(z, y).predict(zd) + base) for a in alphas])
    limit = max_invalid + outside(base)  # a prior's own misses are not the fit's
    allowed = invalid <= limit
    if not allowed.any():
        raise ValueError(f"no regularisation keeps the map's C inside {c_extent_pa} Pa on all but {limit:.2%} "
                         f"of the input domain (best {invalid.min():.2%}); fit more landscapes")
    best = int(np.argmin(np.where(allowed, sq, np.inf)))
    pipe.set_params(ridge__alpha=float(alphas[best]))
    pipe.fit(x, y)
    rms_rate = float(np.sqrt(sq[best] / len(y)))
    span = c_extent_pa[1] - c_extent_pa[0]
    return pipe, {"alpha": float(alphas[best]), "cv_rms_rate": rms_rate, "cv_rms_C_Pa": rms_rate * span,
                  "invalid_domain_fraction": float(invalid[best]),
                  "alpha_unconstrained": float(alphas[int(np.argmin(sq))]),
                  "cv": "leave one material out", "samples": int(len(y)), "materials": int(len(labels)),
                  "target_rms_C_Pa": float(np.std(y) * span)}
