"""The posterior summary of a run (``posterior.json``, written by :func:`similarity.posterior.analyse`) as typed
values, and reading it back.

The JSON is each dataclass's fields in order, the nested values as their own ``to_dict`` writes them: the file
:func:`similarity.posterior.analyse` wrote before these types existed has the same layout, so it loads too.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mpm.files import JsonRecord
from mpm.params import Material
from similarity.best_fit import BestFit
from similarity.ellipsoid import Ellipsoid
from similarity.evidence import EvidenceSummary
from similarity.flow_band import band_width
from similarity.likelihood import NoiseScale


def _material(d: dict) -> Material:
    return Material(**d)


@dataclass(kw_only=True)
class PosteriorStats(JsonRecord):
    """The emcee posterior in numbers (:meth:`similarity.mcmc.Posterior.summary`): SI mean and quantiles,
    normalised mean and covariance, and the sampler's convergence."""

    mean: Material
    quantiles: dict  # "5", "50", "95" -> Material
    mean_normalised: list
    cov_normalised: list  # 3 x 3
    ess: float  # effective sample size
    tau: list  # integrated autocorrelation time per parameter, steps
    iterations: int
    nwalkers: int
    burn: int
    converged: bool
    acceptance: float
    wall_seconds: float

    READERS = {"mean": _material, "quantiles": lambda d: {k: _material(v) for k, v in d.items()}}

    @property
    def cov(self) -> np.ndarray:
        return np.asarray(self.cov_normalised, float)


@dataclass(kw_only=True)
class PosteriorCheck(JsonRecord):
    """The emulated posterior against the simulator (:func:`similarity.emulator_check.posterior_check`): posterior draws
    simulated, and how much better the emulator's eq. (1) said they fit than the simulations did."""

    draws: int
    rounds: int  # fits of the emulator so far in its box (each after adding the previous round's draws)
    optimism_nats: float  # mean of tau (L_simulated - L_emulated) over the draws
    rms_nats: float
    failed: int  # draws whose simulation failed
    passed: bool
    worst_face_nats: float | None = None  # the laws' check: the face whose mean offset lies farthest from zero

    OMIT_IF_NONE = ("worst_face_nats",)


@dataclass(kw_only=True)
class EmulatorSummary(JsonRecord):
    """The loss emulator the posterior was sampled on: its held-out error and its trust region."""

    n_train: int
    n_test: int
    rmse: float  # held-out RMSE, loss units
    max_abs: float
    loss_range: float
    trust_region: list  # [lo, hi], normalised corners of the box the prior is cut to
    half_width: float | None = None  # of that box around the estimate, after growing it (None: older files)
    cut_fraction: float | None = None  # posterior fraction at an inner face of the box (None: older files)
    roughness_std: float
    check: PosteriorCheck | None = None  # the posterior checked on simulated draws (None: no new simulations, older files)
    laws_check: PosteriorCheck | None = None  # the same on the special laws' posteriors on their faces (None: none)

    OMIT_IF_NONE = ("check", "laws_check")
    READERS = {"check": PosteriorCheck.from_dict, "laws_check": PosteriorCheck.from_dict}


@dataclass(kw_only=True)
class PosteriorSummary(JsonRecord):
    """What ``posterior.json`` holds."""

    estimate: Material  # the CMA-ES estimate
    estimate_normalised: list
    setups: list  # "WxH" of the run's experiments
    noise: NoiseScale
    emulator: EmulatorSummary
    posterior: PosteriorStats
    truth: Material | None = None  # emulated footage: the ground truth
    truth_normalised: list | None = None
    ellipsoid_posterior: Ellipsoid  # 90 % ellipsoid of the samples' covariance
    ellipsoid_laplace: Ellipsoid | None  # 90 % Laplace ellipsoid (FD Hessian of the emulated log-likelihood)
    normals: dict  # setup -> {"normal", "alignment_thin_axis"} or None (no Poiseuille flow)
    flow_band: dict  # shear_rate, and the stress quantiles "5", "50", "95" per rate
    eig_grid: list | None = None  # EIG [nats] over the setup grid (rows: heights)
    next_setups_eig: list  # the ten best next setups: {"setup", "eig_nats"}
    next_setup_perpendicular: dict  # {"setup", "score", "eig_nats"}, or {"error"}
    # simulated information (similarity.simulated_design.rank_by_simulation with the posterior's covariance and noise):
    # {"setup", "eig_nats" (or "score" where no factor calibrates it), "preset", "top", "check"} ({"setup",
    # "log_det_gain", ...} in files written before the noise weighting), or {"error"}; None in files written before it
    next_setup_information: dict | None = None
    rheometer_band_coverage: float | None = None  # set by the HTML report when given a rheometer curve
    evidence: EvidenceSummary | None = None  # the laws' evidences and verdicts; None in files written before them
    best_fit: BestFit | None = None  # the best simulated fit against the estimate; None: none simulated, older files

    OMIT_IF_NONE = ("truth", "truth_normalised", "eig_grid", "rheometer_band_coverage", "next_setup_information",
                    "evidence", "best_fit")
    READERS = {"estimate": _material, "truth": _material, "noise": NoiseScale.from_dict,
               "emulator": EmulatorSummary.from_dict, "posterior": PosteriorStats.from_dict,
               "ellipsoid_posterior": Ellipsoid.from_dict, "ellipsoid_laplace": Ellipsoid.from_dict,
               "evidence": EvidenceSummary.from_dict, "best_fit": BestFit.from_dict}

    def band_width(self, shear_rate: float) -> float:
        """Width of the 90 % flow-curve band at ``shear_rate`` [1/s] (:func:`similarity.flow_band.band_width`)."""
        return band_width(self.flow_band, shear_rate)

    @property
    def again(self) -> str:
        """', a setup already filmed: film it again' when the simulated-information next setup is one of the setups
        run, else ''."""
        nxt = (self.next_setup_information or {}).get("setup")
        return ", a setup already filmed: film it again" if nxt and nxt in self.setups else ""


def read_posterior(folder) -> PosteriorSummary:
    """``folder/posterior.json`` written by :func:`similarity.posterior.analyse` (``virheo report``)."""
    path = Path(folder) / "posterior.json"
    if not path.is_file():
        raise ValueError(f"{folder}: no posterior.json; run `virheo report {folder}` first")
    try:
        s = PosteriorSummary.from_dict(json.loads(path.read_text()))
        cov = s.posterior.cov
    except (json.JSONDecodeError, UnicodeDecodeError, KeyError, TypeError, ValueError, AttributeError) as exc:
        raise ValueError(f"{path}: not a posterior summary ({exc})") from None
    if cov.shape != (3, 3):
        raise ValueError(f"{path}: covariance is not 3 x 3")
    return s


def information_gain(next_setup_information: dict) -> tuple[float, str]:
    """(gain, its unit in words) of a ``next_setup_information`` entry: expected information gain in nats, or the
    unitless log det gain of files written before the noise weighting."""
    if "eig_nats" in next_setup_information:
        return float(next_setup_information["eig_nats"]), "nats"
    if "score" in next_setup_information:  # weighted by the noise, but not calibrated to the posterior
        return float(next_setup_information["score"]), "a unitless score, not calibrated to the posterior"
    return float(next_setup_information["log_det_gain"]), "log det gain, a unitless score"
