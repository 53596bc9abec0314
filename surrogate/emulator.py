"""Emulator of the video loss near an estimate: quadratic trend + Gaussian process (scikit-learn).

The dam-break loss (eq. 3) near its minimum is, to first order, a quadratic bowl whose long axis is
the similarity valley (section 5); on top of that the MPM's discretisation makes it slightly rough.
The emulator therefore models

    L(x) = q(x) + g(x),   q: least-squares quadratic in the normalised coordinates x in [0, 1]^3,
                          g: GP with an anisotropic RBF kernel plus a white-noise term,

so it extrapolates like a bowl (not back to a constant mean, as a bare GP would) and its white-noise
level estimates the loss's roughness.  Inputs are normalised material coordinates (see
:mod:`similarity.space`); this module knows nothing about materials or simulations.

:func:`space_filling` draws a scrambled Sobol batch in a box around a centre (``scipy.stats.qmc``)
for the new simulations the emulator is trained on.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from scipy.spatial.distance import cdist
from scipy.stats import qmc
from sklearn.exceptions import ConvergenceWarning
from sklearn.gaussian_process import GaussianProcessRegressor
from sklearn.gaussian_process.kernels import RBF, ConstantKernel, WhiteKernel
from sklearn.linear_model import Ridge
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import PolynomialFeatures


def min_training(d: int) -> int:
    """Fewest training losses for the quadratic trend in ``d`` dimensions: its (d+1)(d+2)/2 terms, plus one."""
    return (d + 1) * (d + 2) // 2 + 1


def box(center, half_width, lower=0.0, upper=1.0) -> tuple[np.ndarray, np.ndarray]:
    """Corners (lo, hi) of the box ``center +- half_width`` clipped to [lower, upper]^d."""
    center = np.asarray(center, float)
    half = np.broadcast_to(np.asarray(half_width, float), center.shape)
    return np.clip(center - half, lower, upper), np.clip(center + half, lower, upper)


def space_filling(center, half_width, n: int, seed: int = 0, lower=0.0, upper=1.0) -> np.ndarray:
    """``n`` scrambled-Sobol points in :func:`box` ``(center, half_width, lower, upper)``."""
    center = np.asarray(center, float)
    lo, hi = box(center, half_width, lower, upper)
    if np.any(hi <= lo):
        raise ValueError("space_filling: the box around the centre is empty")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # Sobol' balance wants n = 2^k; any n is space-filling enough
        u = qmc.Sobol(d=center.size, scramble=True, seed=seed).random(int(n))
    return qmc.scale(u, lo, hi)


@dataclass(frozen=True)
class Validation:
    """Held-out error of an emulator: RMSE and the largest absolute error, in loss units."""

    n_train: int
    n_test: int
    rmse: float
    max_abs: float
    loss_range: float  # max - min of the held-out losses, for scale

    @classmethod
    def of(cls, predicted, y, n_train: int) -> "Validation":
        """The error of ``predicted`` against the held-out losses ``y`` (finite ones) of an emulator trained on
        ``n_train`` losses."""
        predicted, y = np.asarray(predicted, float), np.asarray(y, float)
        ok = np.isfinite(y)
        err = predicted[ok] - y[ok]
        return cls(int(n_train), int(ok.sum()), float(np.sqrt(np.mean(err**2))), float(np.max(np.abs(err))),
                   float(np.ptp(y[ok])))

    def to_dict(self) -> dict:
        return {"n_train": self.n_train, "n_test": self.n_test, "rmse": self.rmse, "max_abs": self.max_abs,
                "loss_range": self.loss_range}


def out_of_fold(X, y, folds: int, rng, seed: int = 0, kernel=None) -> np.ndarray:
    """k-fold cross-validation: every loss of (X, y) predicted by an emulator fitted on the other ``folds`` - 1
    folds (drawn by the generator ``rng``), so each prediction is held out.  ``kernel``: hyperparameters every fold
    keeps (e.g. the full fit's ``gp.kernel_``), so that a fold refits the trend and conditions the GP but optimises
    nothing; None: each fold optimises its own (three starts)."""
    X, y = np.atleast_2d(np.asarray(X, float)), np.asarray(y, float)
    fold = rng.permutation(len(y)) % folds
    predicted = np.empty(len(y))
    kept = None if kernel is None else frozen(kernel)
    for k in range(folds):
        test = fold == k
        if test.any():
            predicted[test] = LossEmulator(seed=seed).fit(X[~test], y[~test], kernel=kept).predict(X[test])
    return predicted


def frozen(kernel):
    """A copy of the scikit-learn ``kernel`` with every hyperparameter fixed at its value."""
    return kernel.clone_with_theta(kernel.theta).set_params(
        **{name: "fixed" for name in kernel.get_params() if name.endswith("_bounds")})


def quadratic_features(X) -> np.ndarray:
    """1, x_i, x_i x_j (i <= j) per row of X (n, d), in the order of scikit-learn's ``PolynomialFeatures(2)``
    (which the trend is fitted with), without its input checks: they cost most of a prediction in MCMC."""
    X = np.asarray(X, float)
    d = X.shape[1]
    cols = [np.ones(len(X))] + [X[:, i] for i in range(d)] + [X[:, i] * X[:, j] for i in range(d) for j in range(i, d)]
    return np.column_stack(cols)


SEARCH_SUBSET = 120  # losses the hyperparameters' three starts search on (LossEmulator.fit)


class LossEmulator:
    """Quadratic trend + GP regression of a scalar loss over normalised inputs (n, d)."""

    def __init__(self, seed: int = 0, ridge: float = 1e-8):
        self.seed = int(seed)
        self.ridge = float(ridge)
        self.trend = None
        self.gp = None
        self.validation: Validation | None = None

    def fit(self, X, y, kernel=None, theta=None) -> "LossEmulator":
        """Fit the trend and the GP.  ``kernel``: a fitted kernel (with its bounds) to start the hyperparameters'
        one optimisation from (:func:`frozen`: none), instead of the default start and two random restarts (on a
        random ``SEARCH_SUBSET`` of the losses where there are more, then one optimisation on all from their best).
        ``theta``: an earlier fit's hyperparameters (its ``gp.kernel_.theta``), kept: that fit again, nothing
        optimised."""
        X, y = np.atleast_2d(np.asarray(X, float)), np.asarray(y, float)
        ok = np.isfinite(y) & np.all(np.isfinite(X), axis=1)
        X, y = X[ok], y[ok]
        if len(y) < min_training(X.shape[1]):
            raise ValueError(f"the emulator needs at least {min_training(X.shape[1])} finite losses, got {len(y)}")
        self.trend = make_pipeline(PolynomialFeatures(2), Ridge(alpha=self.ridge)).fit(X, y)
        resid = y - self.trend.predict(X)
        scale = float(np.var(resid)) or 1e-12
        span = np.maximum(X.max(axis=0) - X.min(axis=0), 1e-3)
        default = (ConstantKernel(scale, (1e-6 * scale, 1e3 * scale))
                  * RBF(length_scale=0.3 * span, length_scale_bounds=(1e-3, 10.0))
                  + WhiteKernel(0.1 * scale, (1e-8 * scale + 1e-18, 10 * scale)))
        if theta is not None:
            kernel = frozen(default.clone_with_theta(np.asarray(theta, float)))
        if kernel is None and len(y) > SEARCH_SUBSET:
            # the three starts search on a random subset, the one optimisation on every loss starts from their best:
            # each step of the search costs (SEARCH_SUBSET / n)^2 of one on everything
            part = np.random.default_rng(self.seed).choice(len(y), SEARCH_SUBSET, replace=False)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", ConvergenceWarning)
                kernel = GaussianProcessRegressor(default, n_restarts_optimizer=2, random_state=self.seed).fit(
                    X[part], resid[part]).kernel_
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ConvergenceWarning)  # a length scale at its bound is a fine answer
            self.gp = GaussianProcessRegressor(default if kernel is None else kernel, normalize_y=False,
                                               n_restarts_optimizer=2 if kernel is None else 0,
                                               random_state=self.seed).fit(X, resid)
        ridge = self.trend[1]
        self._coef, self._intercept = ridge.coef_, ridge.intercept_
        signal = self.gp.kernel_.k1  # ConstantKernel * RBF; the WhiteKernel adds nothing between distinct points
        self._scale, self._length = signal.k1.constant_value, np.asarray(signal.k2.length_scale, float)
        self._X_scaled = self.gp.X_train_ / self._length
        return self

    @property
    def noise_std(self) -> float:
        """Standard deviation of the fitted white-noise term: the loss's roughness below the GP's scale."""
        k = self.gp.kernel_
        return float(np.sqrt(k.k2.noise_level))

    def predict(self, X, return_std: bool = False):
        """Loss at X (n, d); with ``return_std`` also the GP's predictive std (without the white noise)."""
        X = np.atleast_2d(np.asarray(X, float))
        if not return_std:  # the posterior mean written out, bit for bit scikit-learn's, without its overheads (MCMC)
            return quadratic_features(X) @ self._coef + self._intercept + self._signal(X) @ self.gp.alpha_
        mean_trend = self.trend.predict(X)
        g, sd = self.gp.predict(X, return_std=True)
        sd2 = np.maximum(sd**2 - self.noise_std**2, 0.0)
        return mean_trend + g, np.sqrt(sd2)

    def _signal(self, X) -> np.ndarray:
        """The fitted signal kernel k1(X, X_train) = c exp(-|x - x'|^2_l / 2), computed as scikit-learn's RBF and
        ConstantKernel compute it (the same operations in the same order), with X_train / l kept from the fit."""
        return np.full((len(X), len(self._X_scaled)), self._scale) * np.exp(
            -0.5 * cdist(X / self._length, self._X_scaled, metric="sqeuclidean"))

    def validate(self, X_train, y_train, X_test, y_test) -> Validation:
        """Fit on the training part, measure on the held-out part, then refit on everything."""
        X_test, y_test = np.atleast_2d(np.asarray(X_test, float)), np.asarray(y_test, float)
        self.fit(X_train, y_train)
        v = Validation.of(self.predict(X_test), y_test, np.isfinite(y_train).sum())
        self.fit(np.vstack([X_train, X_test]), np.concatenate([y_train, y_test]))
        self.validation = v
        return v
