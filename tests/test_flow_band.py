"""The posterior's flow-curve band (similarity/flow_band.py): weighted quantiles, width, rheometer coverage, and the
band of a tempered posterior against its closed form."""
import numpy as np
import pytest
from scipy.stats import norm

from similarity.flow_band import FLOW_RATES, band_coverage, band_width, flow_band
from studies.credible import tempering_weights
from surrogate.rheometer import FlowCurve


def _newtonian(log_eta):
    """Newtonian samples (n = 1, sigma_y = 0): the stress at any rate is eta x rate."""
    return np.column_stack([np.exp(log_eta), np.ones_like(log_eta), np.zeros_like(log_eta)])


def test_weighted_band_is_the_band_of_repeated_samples():
    rng = np.random.default_rng(0)
    X = np.column_stack([rng.uniform(0.5, 5, 300), rng.uniform(0.4, 1, 300), rng.uniform(0, 20, 300)])
    w = rng.integers(1, 4, 300)
    stress = np.array([[m[2] + m[0] * g ** m[1] for g in FLOW_RATES] for m in np.repeat(X, w, axis=0)])
    band = flow_band(X, w)
    for p in ("5", "50", "95"):
        want = np.quantile(stress, int(p) / 100, axis=0, method="inverted_cdf")
        assert np.allclose(band[p], want, rtol=1e-12)


@pytest.mark.parametrize("k", [1.0, 3.0])
def test_tempered_band_of_a_lognormal_viscosity_narrows_as_one_over_sqrt_k(k):
    # log eta ~ N(0, s^2): the band's width is exp(2 z_0.95 s) at every rate; the posterior to the power k
    # has s / sqrt(k), which the samples of k = 1 reweighted by p^(k-1) must reproduce
    s = 0.5
    log_eta = np.random.default_rng(1).normal(0.0, s, 200000)
    w = tempering_weights(-0.5 * (log_eta / s) ** 2, k)
    band = flow_band(_newtonian(log_eta), w)
    want = np.exp(2 * norm.ppf(0.95) * s / np.sqrt(k))
    for rate in (1.0, 10.0, 100.0):
        assert band_width(band, rate) == pytest.approx(want, rel=0.03)
    assert band["50"][60] == pytest.approx(FLOW_RATES[60], rel=0.03)  # median eta 1


def test_band_coverage_counts_the_rheometer_points_inside_between_1_and_100_per_s():
    band = flow_band(_newtonian(np.random.default_rng(2).normal(0.0, 0.3, 20000)))
    rate = np.array([0.1, 1.0, 3.0, 10.0, 30.0, 100.0, 1000.0])
    stress = rate * np.array([100.0, 1.0, 1.0, 2.0, 0.5, 1.2, 100.0])  # outside, in, in, out, out, in, outside
    z = np.zeros_like(rate)
    curve = FlowCurve("test", "-", z, z, rate, stress, stress / rate, z, z)
    assert band_coverage(band, curve) == pytest.approx(3 / 5)
    with pytest.raises(ValueError, match="no rheometer points"):
        band_coverage(band, curve, lo=2000.0, hi=3000.0)


def test_tempering_weights_are_p_to_the_k_minus_1_and_zero_outside_the_support():
    lp = np.array([-1.0, 0.0, -3.0, -np.inf])
    assert np.allclose(tempering_weights(lp, 1.0), [1, 1, 1, 0])
    assert np.allclose(tempering_weights(lp, 3.0), [np.exp(-2), 1, np.exp(-6), 0])
    with pytest.raises(ValueError, match="finite"):
        tempering_weights([-np.inf], 2.0)
