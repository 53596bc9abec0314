"""The ``information`` criterion of `virheo design`: setups ranked by their loss Hessians simulated at the estimate
(sequential D-optimal design, :mod:`similarity.information`), in a unitless log det gain, or, with a posterior, in
nats calibrated to it; and what those simulations say about each setup (its cost, its flow at the estimate).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mpm.files import JsonRecord
from mpm.params import Material, Setup

from .belief import PRIOR_PRECISION
from .design import Ranking, _material, _setups, expected_information_gain
from .progress import first_line

MIN_RUNOUT_MM = 5.0  # flow at the estimate that advances less than this over the footage is flagged: it hardly moves
SIMULATION_PRESET = "demo"  # whose final model rank_by_simulation simulates by default (5 mm cells)


@dataclass(frozen=True)
class SetupFacts:
    """What the ``information`` criterion's own simulations at the estimate say about one setup."""

    cpu_seconds: float  # per simulation at the criterion's model: its footage's at the estimate, as measured
    runout_mm: float  # advance of the flow front from the first to the last frame of the footage at the estimate
    leaves_view: bool  # that footage's material reaches the image's side edge by the last frame (not in the first)
    particle_steps: float | None = None  # that simulation's particles x time steps (mpm.store.SimResult.particle_steps)

    def flags(self) -> list[str]:
        """Why the setup may not be worth filming, in words (empty: none)."""
        out = []
        if self.leaves_view:
            out.append("leaves the camera's view before the last frame")
        if self.runout_mm < MIN_RUNOUT_MM:
            out.append(f"moves {self.runout_mm:.1f} mm (< {MIN_RUNOUT_MM:g} mm)")
        return out


@dataclass(frozen=True)
class InformationCheck(JsonRecord):
    """How well the simulated Hessians explain a posterior: the information of the setups done in nats, by their FD
    Hessians with the run's noise scale and by the posterior itself (both against the uniform prior)."""

    hessian_nats: float  # 1/2 log det(I + Sigma_prior F_done), F_done = tau H_done (similarity.information)
    posterior_nats: float  # 1/2 log det(Sigma_prior Sigma^-1)
    # c: the one factor on every Fisher information with which the setups done carry the posterior's nats; the
    # candidates' nats are calibrated with it (None: no such factor, e.g. a posterior no narrower than the prior)
    scale: float | None = None


def information_check(h_done_mean, noise, covariance) -> InformationCheck:
    """:class:`InformationCheck` from the Hessian of the run's mean loss over its setups, its noise model and the
    posterior covariance (normalised space); its ``scale`` c solves 1/2 log det(I + Sigma_prior c F_done) =
    the posterior's nats (increasing in c)."""
    from scipy.optimize import brentq

    from similarity.information import fisher_information

    prior = np.eye(3) / PRIOR_PRECISION
    f_done = fisher_information(h_done_mean, noise)
    fd = float(expected_information_gain(prior, f_done))
    post = 0.5 * float(np.linalg.slogdet(prior)[1] - np.linalg.slogdet(np.asarray(covariance, float))[1])

    def excess(log_c):
        return float(expected_information_gain(prior, np.exp(log_c) * f_done)) - post

    lo, hi = np.log(1e-8), np.log(1e8)
    scale = None
    if post > 0 and np.isfinite(fd) and excess(lo) < 0 < excess(hi):
        scale = float(np.exp(brentq(excess, lo, hi, xtol=1e-10)))
    return InformationCheck(fd, post, scale)


def rank_by_simulation(material, done, *, preset=SIMULATION_PRESET, forward, fd_step: float | None = None, tick=None,
                       setups=None, covariance=None, noise=None) -> Ranking:
    """Score ``setups`` (default: :func:`similarity.information.grid_setups`) by their simulated FD loss Hessians at
    ``material`` after the setups ``done`` (module docstring), simulated by ``forward`` with the preset's final model;
    higher is better.  Without a posterior the score is the unitless log det gain.  With a posterior's ``covariance``
    (normalised space) and its ``noise`` (:class:`similarity.likelihood.NoiseScale`) it is the expected information
    gain in nats, 1/2 log det(I + Sigma c F_c), each candidate's Fisher information F_c = tau_c H_c weighted by its
    own noise (:func:`similarity.information.candidate_noise`: one more simulation per setup, at half the cell width)
    and calibrated by the factor c with which the Hessians of the setups done carry the posterior's nats
    (:func:`information_check`, ``Ranking.check``; without such a factor, c = 1 and the score is unitless).  A setup
    whose simulations failed is left out.  The ranking's ``facts`` hold each setup's measured CPU seconds per simulation
    and the flow of its footage at the estimate."""
    from similarity.information import (STEP, candidate_noise, fisher_information, grid_setups, interior,
                                        predicted_hessians, realised_gains)
    from similarity.presets import get_preset

    if (covariance is None) != (noise is None):
        raise ValueError("the information in nats needs both the posterior's covariance and its noise model")
    material, done = _material(material), _setups(done)
    setups = grid_setups() if setups is None else list(setups)
    if not setups:
        raise ValueError("no candidate setup to score")
    step = STEP if fd_step is None else fd_step
    preset = get_preset(preset)
    seen = _FactCollector(interior(material, step), tick)
    h_done, hessians, eps = predicted_hessians(material, done, setups, preset=preset, forward=forward, fd_step=step,
                                               tick=seen)
    check = None
    if covariance is None:
        gains = realised_gains(h_done, hessians, eps=eps)
    else:
        covariance = np.asarray(covariance, float)
        if covariance.shape != (3, 3) or not np.all(np.isfinite(covariance)):
            raise ValueError("covariance must be a finite 3 x 3 matrix (normalised material space)")
        try:
            noises = candidate_noise(material, setups, noise, preset=preset, forward=forward, fd_step=step, tick=tick)
        except RuntimeError as exc:
            raise ValueError(f"cannot weigh the setups by their noise: {first_line(exc)}") from None
        check = information_check(h_done / len(done), noise, covariance)
        c = 1.0 if check.scale is None else check.scale
        gains = np.array([np.nan if h is None or z is None else
                          float(expected_information_gain(covariance, c * fisher_information(h, z)))
                          for h, z in zip(hessians, noises)])
    ok = np.isfinite(gains)
    if not ok.any():
        raise ValueError(f"every simulation of the candidate setups around {material} failed")
    w = np.array([s.width_mm for s in setups])[ok]
    h = np.array([s.height_mm for s in setups])[ok]
    none = np.empty((int(ok.sum()), 3))
    return Ranking(material, done, w, h, gains[ok], none, np.empty((len(done), 3)), "information",
                   facts=seen.facts(), check=check)


def _touches_side(frame) -> bool:
    return bool(frame[:, 0].any() or frame[:, -1].any())


class _FactCollector:
    """A ``Forward`` ``on_result`` callback that keeps, per setup, the footage simulated at ``center`` (its flow and its
    CPU seconds); passes every call on to ``tick``."""

    def __init__(self, center: Material, tick=None):
        self.center, self.tick = np.asarray(center.as_array(), float), tick
        self.footage: dict[str, object] = {}

    def __call__(self, request, result, cached):
        if result is not None and np.allclose([request.eta, request.n, request.sigma_y], self.center, rtol=1e-12,
                                              atol=0):
            self.footage[str(Setup(request.width_mm, request.height_mm))] = result
        if self.tick:
            self.tick(request, result, cached)

    def facts(self) -> dict:
        out = {}
        for key, res in self.footage.items():
            front, sil = res.front_m, res.silhouettes
            runout = float((front[-1] - front[0]) * 1e3) if front is not None and len(front) else float("nan")
            leaves = sil is not None and len(sil) > 0 and _touches_side(sil[-1]) and not _touches_side(sil[0])
            cpu = res.stats.get("cpu_s") if res.stats else None  # as measured when it ran, also when stored
            out[key] = SetupFacts(float(cpu if cpu is not None else res.wall_seconds), runout, bool(leaves),
                                  res.particle_steps)
        return out
