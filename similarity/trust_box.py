"""The emulator's trust region: the box in the normalised material space inside which the emulated likelihood is
used, and whether a posterior's samples reach one of its inner faces (where the box, not the footage, would end the
posterior; :mod:`similarity.posterior` then grows it)."""
from __future__ import annotations

import numpy as np
from scipy.stats import chi2

EDGE = 0.05  # the outer fraction of the box's width next to a face in which a sample counts as at that face
REACH_NATS = float(0.5 * chi2.ppf(0.999, 3))  # 8.1: -log p (eq. 1) within which a 3-D Gaussian holds 99.9 % of its mass
WHOLE_FROM = 0.8  # a box this wide (half-width, normalised) or wider is the whole space: it leaves out at most a fifth
# of any coordinate's range (nothing for a centre between 0.2 and 0.8), and growing it there would cost a full round


def box_widths(half_width: float) -> list[float]:
    """The emulator box's half-widths, smallest first: ``half_width`` doubling until it reaches ``WHOLE_FROM``; that
    last one is 1, the whole space whatever the centre."""
    widths = [float(half_width)]
    while widths[-1] < WHOLE_FROM:
        widths.append(2.0 * widths[-1])
    widths[-1] = 1.0
    return widths


def at_inner_face(samples, lo, hi) -> np.ndarray:
    """Mask of the samples in the outer ``EDGE`` of the box [lo, hi] next to a face inside (0, 1)^d."""
    samples, lo, hi = np.atleast_2d(samples), np.asarray(lo, float), np.asarray(hi, float)
    band = EDGE * (hi - lo)
    at_lo = (samples < lo + band) & (lo > 1e-9)
    at_hi = (samples > hi - band) & (hi < 1 - 1e-9)
    return np.any(at_lo | at_hi, axis=1)


def cut_fraction(samples, lo, hi) -> float:
    """Fraction of samples at an inner face of the box [lo, hi] (:func:`at_inner_face`): where the box, not the
    likelihood, ends the posterior."""
    return float(np.mean(at_inner_face(samples, lo, hi))) if len(np.atleast_2d(samples)) else 0.0


def reaches_a_face(samples, log_prob, lo, hi) -> bool:
    """Whether the posterior reaches an inner face of the box [lo, hi]: a sample at one (:func:`at_inner_face`)
    whose log-posterior ``log_prob`` (one per sample) is within ``REACH_NATS`` of the samples' best.  Then the
    likelihood has not fallen off before the face, and the posterior goes on beyond it: the box is too small,
    however few samples lie there (a valley that leaves the box through a saddle puts few there)."""
    log_prob = np.asarray(log_prob, float)
    face = at_inner_face(samples, lo, hi)
    return bool(face.any() and np.max(log_prob[face]) >= np.max(log_prob) - REACH_NATS)


def first_box(center, widths, laws) -> int:
    """Index of the first of ``widths`` (increasing half-widths) whose box around ``center`` reaches the face of every
    one of ``laws`` (:class:`similarity.evidence.Law`): a smaller box cannot give their evidence, so the loop starts
    there (the last width when none reaches them all)."""
    from surrogate.emulator import box

    for k, width in enumerate(widths):
        lo, hi = box(center, width)
        if all(law.on_face(lo, hi) for law in laws):
            return k
    return len(widths) - 1
