"""Realised information of a setup: what filming it adds, measured in the simulator at the true material.

A design criterion *predicts* which setup pins the material down best (:mod:`similarity.design`). Whether it
did is measured here, without the optimiser's noise, on emulated footage of a known material M:

* the loss Hessian of each setup s filmed, H_s, is the finite-difference Hessian of the video loss at M
  (:mod:`similarity.fd_hessian`, the 18-point stencil) with one pinned step ``STEP`` in the normalised
  material space, projected onto the positive semi-definite cone (:func:`similarity.belief.psd_projection`:
  a direction of negative curvature pins nothing);
* the loss of several setups is their mean, and its Hessian the mean of theirs; information adds, so the
  information after setups 1..k is the sum H_1 + ... + H_k (a constant factor changes no ranking);
* the realised information gain of a candidate c after the setups done is the log-volume by which it shrinks
  the Laplace ellipsoid, ``log det(H_done + H_c + eps I) - log det(H_done + eps I)`` (:func:`log_det_gain`),
  with a ridge eps = ``RIDGE`` x the largest eigenvalue of H_done: a direction pinned less than 1 % as well
  as the best-pinned one counts as unknown, as the prior would leave it.

Why one pinned step: the loss grows about linearly with the distance from M (silhouette pixels; a cone, not
a paraboloid), so FD eigenvalues scale with 1/h and mean nothing absolute; at one step for every setup and
material they compare.  h = 0.05 is the step docs/landscapes.md measured to move every probe's silhouettes by
tens to hundreds of pixels in every setup while keeping the normal stable.  Two other measures are checked
beside it: the smallest eigenvalue of the sum (:func:`min_eig_gain`, E-optimality), and the log det gain of the
candidate's direction alone, its Hessian scaled to the trace of H_done (:func:`shape_gain`): a larger setup moves
more silhouette pixels per step, so its Hessian is larger whatever its direction.

Scoring a criterion against a set of candidates (:func:`normalised_score`, :func:`sign_test`,
:func:`rank_agreement`): the normalised score (pick - candidate mean) / (best - candidate mean) is 1 for the best
candidate and 0 for an average one; the one-sided sign test asks whether picks beat the candidate mean more
often than a coin would.

Measured in the simulator (:func:`stencil_losses`, :func:`setup_hessians`, :func:`realised_gains`): each setup's
18 stencil losses around the true material against its own emulated footage, their Hessians, and the gain of
each candidate by one of :data:`MEASURES`.

Predicted in the simulator (:func:`predicted_gains`, the ``information`` criterion of :mod:`similarity.design`):
the same log det gain computed at the current *estimate* instead of the unknown truth, on footage emulated there,
for the setups of :func:`grid_setups`.  This is sequential D-optimal design: it is what the realised gain would be
if the estimate were the truth, so it sees the size of a setup's information as well as its direction.
"""
from __future__ import annotations

import warnings

import numpy as np

from similarity.belief import psd_projection
from similarity.fd_hessian import hessian_from_stencil

STEP = 0.05  # the FD step in the normalised material space (docs/landscapes.md, step study)
GRID_MM = (20.0, 37.0, 53.0, 70.0)  # widths and heights of the setups the ``information`` criterion simulates
SIMULATIONS_PER_SETUP = 1 + 18  # the emulated footage and the 18-point stencil (similarity.fd_hessian.stencil)
RIDGE = 1e-2  # eps = RIDGE x lambda_max(H_done)


def setup_hessian(stencil_losses, step: float = STEP, center: float = 0.0) -> np.ndarray:
    """The PSD-projected FD Hessian (3, 3) of one setup's loss from its 18 stencil losses
    (:func:`similarity.fd_hessian.stencil` order); ``center`` is the loss at the material itself (0 on its own
    footage)."""
    return psd_projection(hessian_from_stencil(stencil_losses, step, center))[0]


def ridge(h_done) -> float:
    """eps = RIDGE x the largest eigenvalue of the information of the setups done (> 0)."""
    top = float(np.linalg.eigvalsh(np.asarray(h_done, float))[-1])
    if not top > 0:
        raise ValueError("the setups done carry no information (their Hessian has no positive eigenvalue)")
    return RIDGE * top


def candidates_ridge(hessians) -> float | None:
    """eps = RIDGE x the largest eigenvalue of the candidates' Hessians (None entries skipped), for when the setups
    done carry no information: each candidate is then scored by what it pins down on its own; None when no candidate
    has a positive eigenvalue either."""
    tops = [float(np.linalg.eigvalsh(np.asarray(h, float))[-1]) for h in hessians if h is not None]
    return RIDGE * max(tops) if tops and max(tops) > 0 else None


def log_det_gain(h_done, h_new, eps: float | None = None) -> np.ndarray:
    """log det(H_done + H_new + eps I) - log det(H_done + eps I): minus twice the change of the Laplace ellipsoid's
    log-volume, for one H_done (3, 3) and candidates H_new (..., 3, 3); eps None: :func:`ridge`."""
    h_done = np.asarray(h_done, float)
    eps = ridge(h_done) if eps is None else float(eps)
    base = h_done + eps * np.eye(h_done.shape[-1])
    after = np.linalg.slogdet(base + np.asarray(h_new, float))[1]
    return after - np.linalg.slogdet(base)[1]


def shape_gain(h_done, h_new, eps: float | None = None) -> np.ndarray:
    """:func:`log_det_gain` with each candidate scaled to the trace of H_done: what its *direction* adds if it were
    as informative as the setups done (the question the perpendicularity criterion answers), its size left out."""
    h_done, h_new = np.asarray(h_done, float), np.asarray(h_new, float)
    tr = np.trace(h_new, axis1=-2, axis2=-1)[..., None, None]
    return log_det_gain(h_done, h_new * np.trace(h_done) / np.where(tr > 0, tr, np.nan), eps)


def min_eig_gain(h_done, h_new) -> np.ndarray:
    """lambda_min(H_done + H_new) - lambda_min(H_done) (E-optimality), candidates H_new (..., 3, 3)."""
    h_done = np.asarray(h_done, float)
    return np.linalg.eigvalsh(h_done + np.asarray(h_new, float))[..., 0] - np.linalg.eigvalsh(h_done)[0]


def normalised_score(pick: float, candidates, best: float | None = None) -> float:
    """(pick - mean) / (best - mean) with the mean of the candidates' realised gains: 1 = as good as the best,
    0 = as good as their mean, negative = worse.  ``best``: the best gain of a larger set (the candidates with
    the criteria's picks), else the candidates' largest.  NaN when the best does not exceed the mean."""
    c = np.asarray(candidates, float)
    c = c[np.isfinite(c)]
    mean = float(np.mean(c))
    best = float(np.max(c)) if best is None else float(best)
    return float((pick - mean) / (best - mean)) if best > mean and np.isfinite(pick) else float("nan")


def sign_test(scores) -> tuple[int, int, float]:
    """(materials where the pick beats the candidate mean, materials with a decision, one-sided p): the
    binomial probability of at least that many wins out of the decided ones under a fair coin."""
    from scipy.stats import binomtest

    s = np.asarray(scores, float)
    s = s[np.isfinite(s) & (s != 0)]
    wins = int(np.sum(s > 0))
    p = float(binomtest(wins, len(s), 0.5, alternative="greater").pvalue) if len(s) else float("nan")
    return wins, int(len(s)), p


def last_where_ruled_out(predicted) -> np.ndarray:
    """A criterion's predicted information of the candidates (higher = better) as numbers: a candidate it rules out
    (None) ranks last, one below the lowest prediction."""
    known = [float(p) for p in predicted if p is not None]
    worst = min(known) - 1.0 if known else 0.0
    return np.array([worst if p is None else float(p) for p in predicted], float)


def rank_agreement(predicted, realised) -> float:
    """Spearman's rank correlation between a criterion's predicted information (higher = better) of the
    candidates and their realised gains; NaN where either is constant or fewer than 3 are finite."""
    from scipy.stats import spearmanr

    p, r = np.asarray(predicted, float), np.asarray(realised, float)
    ok = np.isfinite(p) & np.isfinite(r)
    if ok.sum() < 3 or np.ptp(p[ok]) == 0 or np.ptp(r[ok]) == 0:
        return float("nan")
    return float(spearmanr(p[ok], r[ok]).statistic)


# the realised-information measures: name -> gain(H_done, H_new); the first is the study's
MEASURES = {"gain": log_det_gain, "gain_min_eig": min_eig_gain, "gain_shape": shape_gain}


def stencil_losses(truth, setups, *, preset, fd_step: float, forward, tick=None) -> np.ndarray:
    """Losses (len(setups), 18) of the FD stencil around ``truth`` (a Material) in each setup against its own
    emulated footage (the preset's final model; NaN where a simulation failed): 1 + 18 simulations per setup.
    ``tick``: called per simulation, as ``on_result`` of :meth:`mpm.forward.Forward.pair_losses`."""
    from similarity.emulation import emulate, probe_losses
    from similarity.fd_hessian import stencil

    shots = emulate(truth, setups, preset=preset, forward=forward, on_result=tick)
    return probe_losses([(truth, e) for e in shots], stencil(fd_step), preset.final, forward, tick)


def setup_hessians(losses, step: float = STEP) -> list:
    """:func:`setup_hessian` of each row of stencil losses; None where a row is not finite (a failed simulation)."""
    return [setup_hessian(row, step) if np.all(np.isfinite(row)) else None for row in np.asarray(losses, float)]


def realised_gains(h_done, hessians, measure: str = "gain", eps: float | None = None) -> np.ndarray:
    """The gain by ``measure`` (:data:`MEASURES`) of each candidate Hessian after ``h_done``; NaN where None.
    ``eps``: the ridge of the log det measures (None: :func:`ridge` of ``h_done``)."""
    ok = np.array([h is not None for h in hessians])
    stack = np.array([h if h is not None else np.eye(3) for h in hessians], float).reshape(-1, 3, 3)
    ridge_arg = {} if eps is None else {"eps": eps}
    return np.where(ok, MEASURES[measure](np.asarray(h_done, float), stack, **ridge_arg), np.nan)


def grid_setups(values_mm=GRID_MM) -> list:
    """The setups the ``information`` criterion chooses from: every (width, height) of ``values_mm``, height outer
    and width inner (the order of :func:`similarity.space.candidate_setups`)."""
    from mpm.params import Setup

    return [Setup(float(w), float(h)) for h in values_mm for w in values_mm]


def interior(material, fd_step: float = STEP):
    """``material`` moved inward to ``fd_step`` from every face of the normalised space, so that every probe of the
    FD stencil around it is a material of the space (the material the gains are computed at)."""
    from mpm.params import Material
    from similarity.space import denormalize, normalize

    return Material.from_array(denormalize(np.clip(normalize(material.as_array()), fd_step, 1.0 - fd_step)))


def predicted_hessians(estimate, done, setups, *, preset, forward, fd_step: float = STEP, tick=None
                       ) -> tuple[np.ndarray, list, float | None]:
    """(H_done, the Hessian of each of ``setups`` or None where its simulations failed, the ridge eps or None for
    :func:`ridge`): the FD Hessians at ``estimate`` on footage emulated there (module docstring), 19 simulations per
    setup, done ones included.  ValueError when a done setup's simulations failed.  When nothing moves measurably
    around the estimate in the setups done (their Hessians have no positive eigenvalue: a stiff material in a small
    box), the ridge comes from the candidates instead (RIDGE x their largest eigenvalue), so that each candidate is
    scored by what it pins down on its own, with a warning; ValueError when no setup carries information."""
    done, setups = list(done), list(setups)
    estimate = interior(estimate, fd_step)
    try:
        losses = stencil_losses(estimate, done + setups, preset=preset, fd_step=fd_step, forward=forward, tick=tick)
    except RuntimeError as exc:  # the footage emulated at the estimate failed in some setup
        raise ValueError(f"cannot score setups at {estimate}: {str(exc).splitlines()[0]}") from None
    hessians = setup_hessians(losses, fd_step)
    if any(h is None for h in hessians[:len(done)]):
        raise ValueError(f"a simulation of a done setup's stencil around {estimate} failed, so its information is "
                         "unknown")
    h_done, candidates = np.sum(hessians[:len(done)], axis=0), hessians[len(done):]
    eps = None
    if not np.linalg.eigvalsh(h_done)[-1] > 0:
        eps = candidates_ridge(candidates)
        if eps is None:
            raise ValueError(f"the loss does not change around {estimate} in any setup, done or candidate: no setup "
                             "adds information at this estimate")
        warnings.warn(f"the setups done carry no information at {estimate} (their loss does not change around it): "
                      "each candidate is scored by what it pins down on its own")
    return h_done, candidates, eps


def predicted_gains(estimate, done, setups, *, preset, forward, fd_step: float = STEP, tick=None) -> np.ndarray:
    """The log det gain (:func:`log_det_gain`) of each of ``setups`` after the setups ``done``, from
    :func:`predicted_hessians`; NaN for a setup whose simulations failed."""
    h_done, candidates, eps = predicted_hessians(estimate, done, setups, preset=preset, forward=forward,
                                                 fd_step=fd_step, tick=tick)
    return realised_gains(h_done, candidates, eps=eps)


def fisher_information(hessian, noise) -> np.ndarray:
    """F = tau H: the Hessian of -log p (eq. 1 of :mod:`similarity.likelihood`, log p = -tau L) for the Hessian H of a
    setup's mean video loss and that setup's noise model ``noise`` (a :class:`similarity.likelihood.NoiseScale`)."""
    return noise.precision * np.asarray(hessian, float)


def candidate_noise(estimate, setups, noise, *, preset, forward, fd_step: float = STEP, tick=None) -> list:
    """The predicted noise model (:meth:`similarity.likelihood.NoiseScale.for_new_setup`) of each of ``setups`` at
    ``estimate``, from ``noise`` (the run's) with the setup's own frames and discretisation error (its footage at the
    estimate with the preset's final model against half its cell width: one more simulation per setup); None where
    a simulation failed.  Where the run's noise counts no discretisation term (`virheo report --no-discretisation`),
    neither do the candidates', and nothing more is simulated."""
    from similarity.emulation import emulate

    center = interior(estimate, fd_step)
    shells = emulate(center, list(setups), preset=preset, forward=forward, on_result=tick)  # the stencil's footage
    deltas = (discretisation_losses(center, shells, preset.final, forward) if noise.discretisation > 0
              else [0.0] * len(shells))
    return [None if d is None else noise.for_new_setup(len(e.frames), d) for e, d in zip(shells, deltas)]


def discretisation_losses(material, experiments, model, forward) -> list:
    """delta_disc of :mod:`similarity.likelihood` per experiment: the video loss (eq. 3) between ``material``
    simulated with ``model`` and with half its cell width (None where either simulation failed)."""
    from dataclasses import replace

    from mpm.loss import video_loss

    model = model.resolved()
    fine = replace(model, cell_mm=model.cell_mm / 2.0)
    coarse, refined = (forward.silhouettes(material, experiments, m) for m in (model, fine))
    return [video_loss(a, b) if a is not None and b is not None else None for a, b in zip(coarse, refined)]
