"""Likelihood of silhouette footage given a material: a Gaussian pixel-noise model with an estimated scale.

Model.  Every captured frame R_k is the simulated frame S_k(M) plus a residual field whose pixels have
variance s^2 and are correlated in patches (the residuals come in bands along the silhouette's edge,
not as salt-and-pepper noise).  Counting one independent value per patch, a video carries N_eff
independent residuals, and the squared residual sum is |P| F L(M) with L the video loss of eq. 3
(binary masks: squared difference = XOR; |P| pixels per frame, F frames).  So

    log p(footage | M) = -N_eff L(M) / (2 s^2) + const                                  (1)

with L the mean loss over all frames of all setups (the CMA-ES objective) and N_eff summed over them.

Scale.  Nothing is hand-set: at the estimate M^ the residual *is* the noise, and (1) there equals
-N_eff / 2, the expected chi-square of N_eff independent residuals.
* N_eff (``method="frames"``) counts one independent residual per frame: under model error the residual
  bands of one frame share one cause (the simulated material flows differently from the captured one)
  and move together when M changes, so a frame is one observation of the mismatch.
  ``method="components"`` counts the residual's connected components at M^ (8-connected,
  at least ``MIN_COMPONENT_PX`` pixels) over all frames: the pixels of one band share one cause (a front
  that ran too far, a top that sank too little) and count once.  ``method="autocorrelation"`` counts
  sum_k |P| / A_k instead, with A_k the product of the residual's integral correlation lengths along
  rows and columns; it treats the bands' width as the correlation scale and is far larger (and the
  posterior far narrower; docs/uncertainty.md compares them);
* s^2 is a variance budget in loss units, s^2 = L(M^) + delta_disc + e_emul, where L(M^) is the
  misfit at the optimum (measurement noise and model error), delta_disc the forward model's
  discretisation error (the loss between the estimate simulated at the preset's cell width and at
  half of it) and e_emul the emulator's error where the posterior can lie
  (:func:`similarity.emulator_check.emulator_error`) when the loss is emulated.  Each term is an independent source of silhouette mismatch and adds to the variance.

Assumptions, stated: residual patches are independent of each other and Gaussian (the binary
residual's variance is used, its discreteness ignored); the noise does not depend on M near M^;
the model error at M^ is as large as anywhere in the posterior's support.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from mpm.files import JsonRecord


MIN_COMPONENT_PX = 3
METHODS = ("frames", "components", "autocorrelation")


def components(residual: np.ndarray) -> int:
    """Connected components (8-connected) of a binary residual with at least ``MIN_COMPONENT_PX`` pixels."""
    from skimage.measure import label

    lab = label(np.asarray(residual, bool), connectivity=2)
    if lab.max() == 0:
        return 0
    sizes = np.bincount(lab.ravel())[1:]
    return int(np.count_nonzero(sizes >= MIN_COMPONENT_PX))


def integral_scale(residual: np.ndarray, axis: int) -> float:
    """Integral correlation length (pixels) of a residual image along ``axis``: 1 + 2 sum_k rho(k).

    rho is the autocorrelation of the centred residual averaged over the other axis; the sum stops at
    the first lag where rho <= 0 (initial positive sequence).  1 for a residual without variance.
    """
    r = np.asarray(residual, float)
    r = r - r.mean()
    var = float(np.sum(r * r))
    if var <= 0.0:
        return 1.0
    n = r.shape[axis]
    f = np.fft.rfft(r, n=2 * n, axis=axis)
    acf = np.fft.irfft(f * np.conj(f), n=2 * n, axis=axis)
    acf = np.sum(acf, axis=1 - axis)[:n] / var
    stop = np.flatnonzero(acf[1:] <= 0.0)
    end = (stop[0] + 1) if stop.size else n
    return float(1.0 + 2.0 * np.sum(acf[1:end]))


def correlation_area(residual: np.ndarray) -> float:
    """Pixels per independent residual value: product of the row and column integral scales (>= 1)."""
    return max(1.0, integral_scale(residual, 0) * integral_scale(residual, 1))


@dataclass(frozen=True)
class NoiseScale(JsonRecord):
    """The estimated noise model of eq. (1) (module docstring); variances in loss units."""

    n_pixels: int  # pixels over all frames of all setups
    n_eff: float  # independent residuals
    loss_at_optimum: float  # L(M^)
    discretisation: float  # delta_disc
    emulator: float  # e_emul
    frames: int

    @property
    def variance(self) -> float:
        """s^2 = L(M^) + delta_disc + e_emul (a floor of 1e-12 keeps a perfect fit finite)."""
        return max(self.loss_at_optimum + self.discretisation + self.emulator, 1e-12)

    @property
    def precision(self) -> float:
        """tau = N_eff / (2 s^2): log p = -tau L (eq. 1)."""
        return self.n_eff / (2.0 * self.variance)

    def log_likelihood(self, loss):
        """Eq. (1) for mean video losses ``loss`` (any shape); -inf where the loss is not finite."""
        loss = np.asarray(loss, float)
        return np.where(np.isfinite(loss), -self.precision * loss, -np.inf)

    def with_emulator(self, rmse: float) -> "NoiseScale":
        return NoiseScale(self.n_pixels, self.n_eff, self.loss_at_optimum, self.discretisation, float(rmse), self.frames)

    def for_new_setup(self, frames: int, discretisation: float) -> "NoiseScale":
        """The predicted noise model of a setup not filmed yet, with ``frames`` frames and its own ``discretisation``
        (delta_disc, simulated at the estimate): the same misfit per frame L(M^) (the model error, assumed the same in
        every setup), the same emulator error and the same independent residuals per frame as this one."""
        per_frame = self.n_eff / self.frames if self.frames else 1.0
        pixels = self.n_pixels // self.frames * int(frames) if self.frames else 0
        return NoiseScale(pixels, per_frame * int(frames), self.loss_at_optimum, float(discretisation), self.emulator,
                          int(frames))

    def to_dict(self) -> dict:
        return asdict(self) | {"variance": self.variance, "precision": self.precision}


def noise_scale(simulated, captured, *, discretisation: float = 0.0, emulator: float = 0.0,
                method: str = "components") -> NoiseScale:
    """Estimate the noise model from the estimate's silhouettes ``simulated`` and the footage ``captured``.

    Both are sequences (one per setup) of (F, H, W) boolean stacks.  ``discretisation`` and ``emulator``
    are delta_disc and e_emul of the module docstring, in loss units; ``method`` how N_eff is counted.
    At least one independent residual per frame is counted (a frame that fits perfectly still says so).
    """
    if method not in METHODS:
        raise ValueError(f"method='{method}' must be one of {', '.join(METHODS)}")
    n_pix = 0
    n_eff = 0.0
    misfit = 0.0
    frames = 0
    for sim, cap in zip(simulated, captured):
        sim, cap = np.asarray(sim, bool), np.asarray(cap, bool)
        if sim.shape != cap.shape or sim.ndim != 3:
            raise ValueError(f"simulated {sim.shape} and captured {cap.shape} silhouettes differ in shape")
        for s, c in zip(sim, cap):
            r = s ^ c
            n_pix += r.size
            misfit += float(np.count_nonzero(r))
            if method == "frames":
                n_eff += 1
            elif method == "components":
                n_eff += max(1, components(r))
            else:
                n_eff += r.size / correlation_area(r)
            frames += 1
    if frames == 0:
        raise ValueError("no frames to estimate the noise from")
    return NoiseScale(int(n_pix), float(n_eff), misfit / n_pix, float(max(discretisation, 0.0)),
                      float(max(emulator, 0.0)), frames)
