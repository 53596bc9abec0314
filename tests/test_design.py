"""Next-setup design (section 6, Algorithm 2) against the experimenters' choices, plus score properties."""
import numpy as np
import pytest

from mpm.datasets import first_estimates
from mpm.params import Material, Setup
from poiseuille import hessian
from similarity.design import least_perpendicular_setup, next_setup, rank_setups
from similarity.normals import loss_normal, loss_normals, normals_at, perpendicularity, top_eigenvector
from similarity.space import EXTENT, candidate_setups
from surrogate.theta import load


def _records():
    for row in first_estimates():
        m = Material(
            float(row["estimate_after_setup1_eta_Pa_s_n"]),
            float(row["estimate_after_setup1_n"]),
            float(row["estimate_after_setup1_sigma_y_Pa"]),
        )
        s1 = Setup(round(float(row["setup1_width_cm"]) * 10), round(float(row["setup1_height_cm"]) * 10))
        s2 = Setup(round(float(row["chosen_setup2_width_cm"]) * 10), round(float(row["chosen_setup2_height_cm"]) * 10))
        yield row["material"], m, s1, s2


def test_reproduces_every_chosen_second_setup(shared_data):
    theta = load("reference")
    rows = list(_records())
    assert len(rows) >= 6
    for name, m, s1, s2 in rows:
        assert next_setup(m, [s1], theta=theta) == s2, name


@pytest.mark.parametrize("variant,units", [("reference", "cgs"), ("reference", "si")])
def test_reference_variant_agrees_on_records(shared_data, variant, units):
    """Reference recipe (A v of the unscaled top eigenvector) vs ours (top eigenvector of A H A)."""
    theta = load("reference")
    w, h = candidate_setups()
    for name, m, s1, s2 in _records():
        q_ref, valid = loss_normals(m, w, h, theta, variant, units)
        q_our, _ = loss_normals(m, w, h, theta, "scaled")
        cos = np.abs(np.sum(q_ref[valid] * q_our[valid], axis=1))
        assert cos.min() > 0.9999, (name, cos.min())  # < 0.81 degrees (measured max 0.49)
        q1_ref = loss_normal(m, s1, theta, variant, units)
        s_ref = perpendicularity(q1_ref, q_ref[valid])
        i = int(np.argmin(s_ref))
        assert Setup(w[valid][i], h[valid][i]) == s2, name


def test_scaled_normal_is_unit_independent():
    rng = np.random.default_rng(1)
    m = np.stack([10 ** rng.uniform(-3, 1.4, 50), rng.uniform(0.3, 1, 50), rng.uniform(0, 40, 50)], axis=1)
    P = np.full(50, 2500.0)
    L = (m[:, 2] + rng.uniform(5, 400, 50)) / P
    q_si = normals_at(m, P, L, "scaled")
    # the same computation in CGS (eta, sigma_y x10; P /10; L x100) with CGS extents
    h_cgs = hessian(m[:, 0] * 10, m[:, 1], m[:, 2] * 10, P / 10, L * 100)
    a = EXTENT * np.array([10, 1, 10])
    q_cgs = top_eigenvector(h_cgs * a[:, None] * a[None, :])
    np.testing.assert_allclose(np.abs(np.sum(q_si * q_cgs, axis=1)), 1.0, atol=1e-10)


def test_top_eigenvector_matches_numpy_eig():
    rng = np.random.default_rng(2)
    b = rng.normal(size=(100, 3, 3))
    h = b @ np.swapaxes(b, 1, 2)
    q = top_eigenvector(h)
    for k in range(100):
        lam, v = np.linalg.eig(h[k])
        ref = v[:, np.argmax(lam.real)].real
        assert abs(ref @ q[k]) == pytest.approx(1.0, abs=1e-10)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0)
    assert np.all(np.isnan(top_eigenvector(np.zeros((3, 3)))))


def test_ranking_properties():
    theta = load("reference")
    m = Material(3.14, 0.74, 1.24)
    done = [Setup(29, 59), Setup(32, 20)]
    r = rank_setups(m, done, theta)
    w, h = candidate_setups()
    P, L = theta(m, (w, h))
    valid = P * L > m.sigma_y
    np.testing.assert_array_equal(r.width_mm, w[valid])
    np.testing.assert_array_equal(r.height_mm, h[valid])
    np.testing.assert_allclose(np.linalg.norm(r.normals, axis=1), 1.0)
    manual = np.sqrt(sum((r.normals @ q) ** 2 for q in r.done_normals))
    np.testing.assert_allclose(r.score, manual)
    assert np.all(r.score <= np.sqrt(2) + 1e-12)
    best, score = r.best()
    assert score == r.score.min()
    first = int(np.flatnonzero(r.score == r.score.min())[0])
    assert best == Setup(r.width_mm[first], r.height_mm[first])  # first minimum in candidate order
    assert next_setup(m, done, theta) == best
    # a setup already done is scored ~1 against itself alone
    r1 = rank_setups(m, [Setup(29, 59)], theta)
    k = np.flatnonzero((r1.width_mm == 29) & (r1.height_mm == 59))[0]
    assert r1.score[k] == pytest.approx(1.0, abs=1e-12)
    g = r1.grid()
    assert g.shape == (51, 51) and g[59 - 20, 29 - 20] == pytest.approx(1.0)


def test_invalid_candidates_are_excluded():
    theta = load("reference")
    m = Material(0.21, 0.81, 21.74)
    w, h = candidate_setups()
    P, L = theta(m, (w, h))
    valid = P * L > m.sigma_y
    assert 0 < valid.sum() < len(w)  # this material leaves part of the grid without Poiseuille flow
    first_valid = Setup(w[valid][0], h[valid][0])
    r = rank_setups(m, [first_valid], theta)
    assert len(r) == valid.sum()
    assert np.all(np.isnan(r.grid()[~valid.reshape(51, 51)]))
    bad = Setup(w[~valid][0], h[~valid][0])
    with pytest.raises(ValueError, match="no plane-Poiseuille flow"):
        rank_setups(m, [bad], theta)


def test_least_perpendicular_ablation():
    theta = load("reference")
    m = Material(3.14, 0.74, 1.24)
    s1 = Setup(29, 59)
    s = least_perpendicular_setup(m, [s1], theta, min_distance_mm=10)
    assert np.hypot(s.width_mm - 29, s.height_mm - 59) >= 10
    r = rank_setups(m, [s1], theta)
    far = np.hypot(r.width_mm - 29, r.height_mm - 59) >= 10
    k = np.flatnonzero((r.width_mm == s.width_mm) & (r.height_mm == s.height_mm))[0]
    assert r.score[k] == r.score[far].max()
    assert r.score[k] > r.best()[1]


def test_refuses_out_of_space_input():
    with pytest.raises(ValueError, match="eta"):
        next_setup(Material(100.0, 0.5, 1.0), [Setup(30, 30)])
    with pytest.raises(ValueError, match="width_mm"):
        next_setup(Material(1.0, 0.5, 1.0), [Setup(10, 30)])
    with pytest.raises(ValueError, match="at least one"):
        next_setup(Material(1.0, 0.5, 1.0), [])
    assert next_setup((1.0, 0.5, 1.0), ["30x30"]) == next_setup(Material(1.0, 0.5, 1.0), [Setup(30, 30)])
