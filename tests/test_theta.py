"""The Theta map: layout, an independent evaluation of the published description, I/O, vectorisation."""
import json
from itertools import combinations_with_replacement

import numpy as np
import pytest

from mpm.params import Material, Setup
from similarity.space import candidate_setups
from surrogate.theta import FEATURE_NAMES, ThetaMap, design_matrix, load, monomial_powers

PRIMES = [2, 3, 5, 7, 11, 13, 17, 19, 23, 29]


def _brute_force_rate(theta, eta, n, sig, h_m, w_m):
    """Straight from the written description: pairs sorted by prime product, x_i x_j * multiplicity / 2!."""
    x = [eta, n, sig, h_m, w_m, 1 / eta, 1 / n, 1 / (sig + 1e-4), 1 / h_m, 1 / w_m]
    pairs = sorted(combinations_with_replacement(range(10), 2), key=lambda ij: PRIMES[ij[0]] * PRIMES[ij[1]])
    r = theta[0] + sum(theta[1 + i] * x[i] for i in range(10))
    for k, (i, j) in enumerate(pairs):
        mult = 1 if i == j else 2
        r += theta[11 + k] * x[i] * x[j] * mult / 2
    return r


def test_reference_coefficients_are_the_published_ones(shared_data):
    published = json.loads((shared_data / "theta_reference.json").read_text())["theta"]
    np.testing.assert_array_equal(load("reference").theta, np.asarray(published, dtype=float))
    shipped = load("reference")
    assert "CC BY-NC" in shipped.attribution and "Hamamichi" in shipped.attribution


def test_monomial_layout():
    pw = monomial_powers()
    assert pw.shape == (66, 10)
    label = lambda k: "*".join(FEATURE_NAMES[i] + ("^2" if pw[k, i] == 2 else "") for i in np.flatnonzero(pw[k]))
    assert label(0) == ""
    assert [label(k) for k in range(1, 11)] == list(FEATURE_NAMES)
    assert label(11) == "eta^2" and label(20) == "eta*1/eta" and label(27) == "H^2"
    assert label(34) == "H*W" and label(38) == "sigma_y*1/(sigma_y+eps)" and label(65) == "1/W^2"


def test_evaluation_matches_independent_description():
    theta = load("reference")
    rng = np.random.default_rng(0)
    for _ in range(50):
        eta, n, sig = 10 ** rng.uniform(-4, 1.4), rng.uniform(0.3, 1), rng.uniform(0, 40)
        w, h = rng.integers(20, 71, 2)
        expect = _brute_force_rate(theta.theta, eta, n, sig, h * 1e-3, w * 1e-3)
        assert theta.rate(eta, n, sig, w, h) == pytest.approx(expect, rel=1e-10, abs=1e-12)
        assert design_matrix(eta, n, sig, h * 1e-3, w * 1e-3) @ theta.theta == pytest.approx(expect, rel=1e-10, abs=1e-12)
        P, L = theta(Material(eta, n, sig), Setup(w, h))
        assert P == 2500.0
        assert L == pytest.approx((5 + 495 * expect) / 2500.0, rel=1e-10)


def test_vectorised_over_candidates():
    theta = load("reference")
    m = Material(3.14, 0.74, 1.24)
    w, h = candidate_setups()
    P, L = theta(m, (w, h))
    assert P.shape == L.shape == (2601,)
    for k in (0, 77, 1300, 2600):
        assert L[k] == pytest.approx(theta(m, Setup(w[k], h[k]))[1], rel=1e-13)
    # height before width: the map is not symmetric in them
    assert not np.allclose(theta(m, (w, h))[1], theta(m, (h, w))[1])
    # arrays of materials broadcast too
    mats = np.array([[3.14, 0.74, 1.24], [1.0, 0.5, 10.0]])
    assert theta(mats[:, None, :], (w, h))[1].shape == (2, 2601)


def test_save_load_roundtrip(tmp_path, shared_data):
    ref = load("reference")
    path = ref.save(tmp_path / "map.json")
    again = load(path)
    np.testing.assert_array_equal(again.theta, ref.theta)
    assert again.c_extent_pa == ref.c_extent_pa and again.p_pa_per_m == ref.p_pa_per_m
    # the shared description file loads as well
    np.testing.assert_array_equal(load(shared_data / "theta_reference.json").theta, ref.theta)


def test_load_errors(tmp_path):
    with pytest.raises(FileNotFoundError):
        load(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        load(bad)
    short = tmp_path / "short.json"
    short.write_text(json.dumps({"theta": [1.0, 2.0]}))
    with pytest.raises(ValueError, match="66"):
        load(short)
    with pytest.raises(ValueError):
        ThetaMap(np.full(66, np.nan))
