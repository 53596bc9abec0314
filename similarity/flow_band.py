"""The 90 % flow-curve band of a posterior: Herschel-Bulkley stress quantiles over the samples at each shear rate,
its width, and how many rheometer points it holds.

A band is a dict, as ``posterior.json`` stores it: ``shear_rate`` (1/s) and the stress quantiles ``"5"``, ``"50"``,
``"95"`` (Pa) per rate.
"""
from __future__ import annotations

import numpy as np

from mpm.params import Material
from similarity.mcmc import QUANTILES

FLOW_RATES = np.logspace(-2, 4, 121)  # 1/s, the range of the flow-curve plots
MAX_CURVES = 2000  # the band is taken over at most about this many samples (evenly thinned)


def flow_band(si_samples, weights=None) -> dict:
    """The band over posterior samples in SI ((k, 3): eta, n, sigma_y), thinned evenly to about ``MAX_CURVES``.
    ``weights`` (k,), optional: weighted quantiles (inverted CDF), e.g. importance weights that make the samples
    another posterior's."""
    X = np.asarray(si_samples, float)
    step = max(1, len(X) // MAX_CURVES)
    stress = np.array([Material.from_array(m).stress(FLOW_RATES) for m in X[::step]])
    if weights is None:
        q = np.quantile(stress, QUANTILES, axis=0)
    else:
        w = np.broadcast_to(np.asarray(weights, float)[::step, None], stress.shape)
        q = np.quantile(stress, QUANTILES, axis=0, weights=w, method="inverted_cdf")
    return {"shear_rate": FLOW_RATES.tolist(), **{f"{int(100 * p)}": row.tolist() for p, row in zip(QUANTILES, q)}}


def band_width(band: dict, shear_rate: float) -> float:
    """Width of the band at ``shear_rate`` [1/s]: its 95th over its 5th percentile stress (interpolated in log
    rate)."""
    r = np.log(np.asarray(band["shear_rate"], float))
    lo, hi = (np.interp(np.log(shear_rate), r, np.log(np.asarray(band[q], float))) for q in ("5", "95"))
    return float(np.exp(hi - lo))


def band_coverage(band: dict, curve, lo: float = 1.0, hi: float = 100.0) -> float:
    """Fraction of the rheometer points (``curve``: :class:`surrogate.rheometer.FlowCurve`) with
    lo <= rate <= hi that lie inside the band."""
    rate = np.log(np.asarray(band["shear_rate"]))
    mask = (curve.shear_rate >= lo) & (curve.shear_rate <= hi)
    if not mask.any():
        raise ValueError(f"{curve.name}: no rheometer points between {lo:g} and {hi:g} 1/s")
    r = np.log(curve.shear_rate[mask])
    b5 = np.interp(r, rate, np.asarray(band["5"]))
    b95 = np.interp(r, rate, np.asarray(band["95"]))
    s = curve.shear_stress[mask]
    return float(np.mean((s >= b5) & (s <= b95)))
