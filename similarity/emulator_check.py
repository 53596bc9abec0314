"""The loss emulator fitted, its error measured and its posterior checked against the simulator.

* Emulator error: the k-fold cross-validated RMSE on the training losses the likelihood reaches
  (:func:`emulator_error`); it enters the likelihood's noise variance (:mod:`similarity.likelihood`).
* Check: a batch of posterior draws is simulated.  Where the emulator promised them a better fit than the
  simulator gives (by more than ``CHECK_NATS`` on average, :func:`posterior_check`) they join the training set
  and the posterior is sampled again, up to ``CHECK_ROUNDS`` times (:func:`checked_posterior`): a minimum that
  the emulator invented between sparse training points draws the posterior there, and the draws' simulations
  take it away.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from similarity.mcmc import Posterior, sample
from similarity.posterior_summary import PosteriorCheck
from similarity.progress import Message
from similarity.trust_box import REACH_NATS

CHECK_ROUNDS = 4  # posterior checks per box: simulated draws join the training set while the emulator is optimistic
CHECK_NATS = 1.0  # the most the emulator may promise above the simulator on the posterior's draws (mean, eq. 1)
FOLDS = 5  # k of the k-fold cross-validation that measures the emulator's error
MIN_SCORED = 10  # the emulator's error is measured on at least this many of the lowest training losses


def box_log_posterior(noise, emu, lo, hi):
    """Vectorised log-posterior in the normalised space: eq. (1) of the likelihood on the emulated loss,
    uniform prior cut to the box [lo, hi]."""
    def log_prob(x):
        x = np.atleast_2d(x)
        inside = np.all((x >= lo) & (x <= hi), axis=1)
        out = np.full(len(x), -np.inf)
        if inside.any():
            out[inside] = noise.log_likelihood(emu.predict(x[inside]))
        return out

    return log_prob


def within_reach(y, noise) -> np.ndarray:
    """Mask of the losses ``y`` that the likelihood reaches: tau (L - L_min) <= ``REACH_NATS`` under eq. (1)
    without the emulator's term (``noise``'s s^2 less e_emul), and at least the ``MIN_SCORED`` lowest."""
    y = np.asarray(y, float)
    gap = noise.with_emulator(0.0).precision * (y - np.min(y))
    return (gap <= REACH_NATS) | (np.argsort(np.argsort(y)) < MIN_SCORED)


def emulator_error(X, y, noise, split, seed: int = 0, kernel=None):
    """e_emul, the emulator's error where the posterior can lie: the RMSE of the k-fold cross-validated
    predictions (``FOLDS``, folds drawn by ``split``) of the training losses :func:`within_reach` of the best.
    Far from the optimum the loss is steep and rough and the emulator's error large; counting it there would
    flatten the likelihood near the optimum, where the emulator is accurate.
    ``kernel``: the full fit's kernel, whose hyperparameters each fold keeps (None: each fold optimises its own).
    Returns a :class:`surrogate.emulator.Validation` (``n_test``: the losses scored)."""
    from surrogate.emulator import Validation, out_of_fold

    predicted = out_of_fold(X, y, FOLDS, split, seed=seed, kernel=kernel)
    near = within_reach(y, noise)
    return Validation.of(predicted[near], np.asarray(y)[near], len(y))


def posterior_check(noise, emu, X, y, rounds: int, groups=None) -> PosteriorCheck:
    """Emulated against simulated eq. (1) at posterior draws ``X`` (normalised) with simulated losses ``y``:
    ``optimism_nats`` is the mean of tau (L_simulated - L_emulated), positive where the emulator promises a
    better fit than the simulator gives, with tau without the emulator's term (``noise``'s e_emul is ignored):
    the emulator's error widens the likelihood, but it does not excuse a bias.  A draw whose simulation failed
    fails the check.

    ``groups`` (one label per draw: the special laws' faces) makes the check two-sided per group: a law's evidence
    is as wrong when the emulator is pessimistic on its face as when it is optimistic (a Bayes factor against the
    law grows either way), so each face's mean offset must lie within ``CHECK_NATS`` of zero;
    ``worst_face_nats`` is the offset farthest from it."""
    noise = noise.with_emulator(0.0)
    y = np.asarray(y, float)
    ok = np.isfinite(y)
    d = noise.precision * (y[ok] - emu.predict(X[ok])) if ok.any() else np.zeros(0)
    optimism = float(np.mean(d)) if d.size else float("inf")
    rms = float(np.sqrt(np.mean(d**2))) if d.size else float("inf")
    failed = int(np.count_nonzero(~ok))
    worst = None
    if groups is not None and d.size:
        g = np.asarray(groups)[ok]
        means = [float(np.mean(d[g == k])) for k in dict.fromkeys(g.tolist())]
        worst = max(means, key=abs)
    within = optimism <= CHECK_NATS if worst is None else abs(worst) <= CHECK_NATS
    return PosteriorCheck(draws=len(y), rounds=rounds, optimism_nats=optimism, rms_nats=rms, failed=failed,
                          passed=bool(failed == 0 and within), worst_face_nats=worst)


@dataclass
class CheckedFit:
    """One emulator fit, its noise model, the posterior sampled on it and that posterior's check."""

    emulator: object
    validation: object
    noise: object
    posterior: Posterior
    check: PosteriorCheck | None
    X: np.ndarray  # the training set the emulator was fitted on (normalised materials, mean losses)
    y: np.ndarray
    kernel: object  # the GP kernel as optimised (with its bounds), whose hyperparameters the emulator has


def checked_posterior(losses, X, y, x_hat, lo, hi, base_noise, *, draws: int, split, seed: int = 0, stage: int = 0,
                      nwalkers: int = 32, min_ess: float = 1000.0, max_steps: int = 20000, backend=None,
                      progress=None, too_few: str = "too few simulated candidates to fit the emulator",
                      rounds: int = CHECK_ROUNDS, kernel=None):
    """Fit the loss emulator on (X, y), sample the posterior in the box [lo, hi] and check it against the
    simulator: ``draws`` posterior draws are simulated (``losses``: normalised (k, 3) -> mean losses (k,));
    where the emulator was optimistic there (:func:`posterior_check`) they join the training set and the
    posterior is sampled again, at most ``rounds`` times.  ``split``: the generator of the cross-validation's
    folds (:func:`emulator_error`); the draws are chosen by ``seed``, ``stage`` (the box) and the round.
    ``kernel``: a fitted GP kernel (an earlier fit's, on part of this training set) where the hyperparameters' one
    optimisation starts (None: three starts); a retraining after a failed check keeps the first fit's hyperparameters
    (the draws it adds are few beside the training set: they move the fit where they lie, not its length scales).
    Returns the last :class:`CheckedFit` (its check describes its posterior; None with ``draws`` 0) and the
    training set grown by the checks' simulations."""
    from mpm.files import digest
    from surrogate.emulator import LossEmulator, min_training

    X, y = np.atleast_2d(np.asarray(X, float)), np.asarray(y, float)
    for round_ in range(rounds + 1):
        ok = np.isfinite(y)
        Xf, yf = X[ok], y[ok]
        largest_fold = -(-len(yf) // FOLDS)  # ceil: each fold's emulator trains on the rest
        if len(yf) - largest_fold < min_training(3):
            raise ValueError(too_few)
        if round_ == 0:
            emu = LossEmulator(seed=seed).fit(Xf, yf, kernel=kernel)
            kernel = emu.gp.kernel_
        else:
            emu = LossEmulator(seed=seed).fit(Xf, yf, theta=kernel.theta)
        validation = emulator_error(Xf, yf, base_noise, split, seed=seed, kernel=kernel)
        noise = base_noise.with_emulator(validation.rmse)
        if progress:
            progress(Message(f"emulator: {len(yf)} training losses, cross-validated RMSE "
                      f"{validation.rmse:.2e} on the {validation.n_test} within reach of the best (their range "
                      f"{validation.loss_range:.2e}); noise: N_eff {noise.n_eff:.0f}, s^2 {noise.variance:.2e}"))
        key = digest({"X": Xf.round(12).tolist(), "y": yf.tolist(), "noise": noise.to_dict(), "seed": seed,
                      "nwalkers": nwalkers, "box": [np.asarray(lo).tolist(), np.asarray(hi).tolist()]})[:16]
        post = sample(box_log_posterior(noise, emu, lo, hi), x_hat, nwalkers=nwalkers, seed=seed,
                      min_ess=min_ess, max_steps=max_steps, backend=backend, backend_name=f"mcmc-{key}",
                      progress=progress)
        if draws <= 0:
            return CheckedFit(emu, validation, noise, post, None, Xf, yf, kernel), X, y
        draw = np.random.default_rng([seed, stage, round_])
        pick = draw.choice(len(post.samples), size=min(draws, len(post.samples)), replace=False)
        X_chk = post.samples[pick]
        y_chk = np.asarray(losses(X_chk), float)
        check = posterior_check(noise, emu, X_chk, y_chk, rounds=round_ + 1)
        if progress:
            progress(Message(f"posterior check: {len(y_chk)} draws simulated, the emulator is "
                      f"{check.optimism_nats:+.2f} nats optimistic on them (RMS {check.rms_nats:.2f}), "
                      f"{check.failed} failed: {'trusted' if check.passed else 'retraining'}"))
        X, y = np.vstack([X, X_chk]), np.concatenate([y, y_chk])
        if check.passed or round_ == rounds:
            return CheckedFit(emu, validation, noise, post, check, Xf, yf, kernel), X, y
