"""Plane-Poiseuille flow, loss (eq. 26) and closed-form Hessian (eqs. 29-42) against independent numerics."""
import numpy as np
import pytest
from scipy.integrate import quad, quad_vec

import poiseuille
from poiseuille import hessian, loss, velocity
from poiseuille.flow import max_velocity, decay_ratio


def test_public_names():
    assert set(poiseuille.__all__) == {"velocity", "loss", "hessian"}


def test_newtonian_profile_is_parabola():
    y = np.linspace(-0.01, 0.01, 41)
    u = velocity(y, 2.0, 1.0, 0.0, 300.0, 0.01)
    np.testing.assert_allclose(u, 300.0 / (2 * 2.0) * (0.01**2 - y**2), rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("eta,n,sig", [(3.0, 0.7, 2.0), (0.01, 0.3, 20.0), (25.0, 1.0, 39.0)])
def test_profile_satisfies_constitutive_law_and_no_slip(eta, n, sig):
    P, L = 2500.0, 0.018
    l = sig / P
    y = np.linspace(l + 0.05 * (L - l), L * 0.999, 50)
    h = 1e-7 * L
    rate = -(velocity(y + h, eta, n, sig, P, L) - velocity(y - h, eta, n, sig, P, L)) / (2 * h)
    # Herschel-Bulkley (eq. 1) in the sheared zone: sigma_y + eta * rate^n = shear stress P*y
    np.testing.assert_allclose(sig + eta * rate**n, P * y, rtol=1e-5)
    assert velocity(L, eta, n, sig, P, L) == pytest.approx(0.0, abs=1e-15)
    plug = velocity(np.linspace(-l, l, 7), eta, n, sig, P, L)
    np.testing.assert_allclose(plug, max_velocity(eta, n, sig, P, L), rtol=1e-13)
    np.testing.assert_allclose(velocity(-y, eta, n, sig, P, L), velocity(y, eta, n, sig, P, L))
    np.testing.assert_allclose(velocity(y, eta, n, sig, P, L), max_velocity(eta, n, sig, P, L) * decay_ratio(y, eta, n, sig, P, L), rtol=1e-12)


def test_no_flow_below_yield():
    assert np.all(velocity(np.linspace(0, 0.01, 5), 1.0, 0.5, 30.0, 2500.0, 0.01) == 0.0)
    assert np.all(hessian(1.0, 0.5, 30.0, 2500.0, 0.01) == 0.0)


def test_broadcasting_shapes():
    eta = np.full((4, 1), 3.0)
    L = np.linspace(0.002, 0.02, 5)
    assert hessian(eta, 0.7, 2.0, 2500.0, L).shape == (4, 5, 3, 3)
    assert velocity(0.001, eta, 0.7, 2.0, 2500.0, L).shape == (4, 5)
    m = np.array([3.0, 0.7, 2.0])
    assert loss(m + np.zeros((4, 1, 3)), m, 2500.0, L).shape == (4, 5)


def _random_points(rng, k=240):
    eta = 10 ** rng.uniform(-4, np.log10(30), k)
    n = rng.uniform(0.3, 1.0, k)
    n[:30] = 0.3
    n[30:60] = 1.0
    sig = rng.uniform(0, 40, k)
    sig[::17] = 0.0
    P = 10 ** rng.uniform(2, 4, k)
    P[::2] = 2500.0
    wall = sig + rng.uniform(0.5, 500, k)  # wall stress P*L above the yield stress
    # L just above sigma_y / P: relative excess down to 1e-6
    close = np.arange(k) % 6 == 0
    wall[close] = np.maximum(sig[close], 0.5) * (1 + 10 ** rng.uniform(-6, -2, close.sum()))
    return eta, n, sig, P, wall / P


def _numerical_hessian(eta, n, sig, P, L, scale):
    """Independent check: 5-point finite differences of the velocity profile (no closed-form
    derivative), integrated by adaptive Gauss-Kronrod quadrature over the plug and the sheared
    zone. ``scale`` (per point, 3) only normalises the integrand so that the error control is
    uniform across points of very different magnitude."""
    steps = np.stack([1e-4 * eta, np.full_like(n, 1e-5), 1e-4 * (P * L - sig)], axis=1)
    base = np.stack([eta, n, sig], axis=1)
    l = sig / P

    def grad(y):
        g = np.empty((len(eta), 3))
        for k in range(3):
            def v(c):
                m = base.copy()
                m[:, k] += c * steps[:, k]
                return velocity(y, m[:, 0], m[:, 1], m[:, 2], P, L)
            g[:, k] = (-v(2) + 8 * v(1) - 8 * v(-1) + v(-2)) / (12 * steps[:, k])
        return g / scale

    def outer(g, w):
        return 2 * w[:, None, None] * g[:, :, None] * g[:, None, :]

    kw = dict(epsabs=1e-13, epsrel=1e-11, norm="max", limit=20000)
    h1 = quad_vec(lambda t: outer(grad(l * t), l), 0, 1, **kw)[0]
    h2 = quad_vec(lambda t: outer(grad(l + (L - l) * t), L - l), 0, 1, points=[1e-6, 1e-3], **kw)[0]
    return (h1 + h2) * scale[:, :, None] * scale[:, None, :]


def test_hessian_matches_finite_difference_quadrature():
    rng = np.random.default_rng(7)
    pts = _random_points(rng)
    assert len(pts[0]) >= 200
    assert np.any(pts[1] == 0.3) and np.any(pts[1] == 1.0)
    assert np.min(pts[4] * pts[3] / np.maximum(pts[2], 1e-300) - 1) < 1e-5  # L just above sigma_y/P
    closed = hessian(*pts)
    d = np.sqrt(np.einsum("kii->ki", closed))
    num = _numerical_hessian(*pts, d)
    # error relative to each entry's natural scale sqrt(H_ii H_jj) (off-diagonals can cross zero)
    err = np.abs(closed - num) / (d[:, :, None] * d[:, None, :])
    assert err.max() < 1e-5, err.max()


def test_loss_matches_adaptive_quadrature():
    rng = np.random.default_rng(3)
    for _ in range(20):
        m = np.array([10 ** rng.uniform(-3, 1.4), rng.uniform(0.3, 1), rng.uniform(0, 30)])
        mt = m * rng.uniform(0.7, 1.3, 3)
        mt[1] = min(mt[1], 1.0)
        P, L = 2500.0, (m[2] + rng.uniform(1, 300)) / 2500.0
        f = lambda yy: (velocity(yy, *mt, P, L) - velocity(yy, *m, P, L)) ** 2
        pts = sorted({min(m[2] / P, L), min(mt[2] / P, L)})
        ref = quad(f, 0, L, points=pts, epsabs=0, epsrel=1e-12, limit=200)[0]
        assert loss(mt, m, P, L) == pytest.approx(ref, rel=1e-8)


def test_loss_is_half_quadratic_form_for_small_dm():
    rng = np.random.default_rng(11)
    for _ in range(30):
        m = np.array([10 ** rng.uniform(-3, 1.4), rng.uniform(0.3, 1), rng.uniform(0, 30)])
        P = 2500.0
        L = (m[2] + rng.uniform(2, 300)) / P
        u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        H = hessian(*m, P, L)
        errs = []
        for eps in (1e-4, 1e-5):
            dm = eps * u * np.array([m[0], 0.5, max(m[2], 1.0)])
            errs.append(abs(loss(m + dm, m, P, L) / (0.5 * dm @ H @ dm) - 1))
        assert errs[1] < 1e-3
        assert errs[1] < errs[0] / 5 or errs[1] < 1e-8  # remainder is O(|dM|^3)


def test_hessian_symmetric_positive_semidefinite():
    rng = np.random.default_rng(5)
    pts = _random_points(rng, 500)
    H = hessian(*pts)
    np.testing.assert_array_equal(H, np.swapaxes(H, -1, -2))
    d = np.sqrt(np.einsum("kii->ki", H))
    lam = np.linalg.eigvalsh(H / (d[:, :, None] * d[:, None, :]))
    assert lam.min() > -1e-9


def test_paper_factorisation_eq30():
    """H = L^3 H~ (eq. 30) with the paper's coefficients (eqs. 37-39) that carry an extra 1/L."""
    eta, n, sig, P, L = 3.0, 0.7, 2.0, 2500.0, 0.01
    W = (P * L - sig) / eta
    a_eta = -1 / (n + 1) / (P * L) * W ** ((n + 1) / n)  # eq. 37
    from poiseuille.hessian import constants
    c1 = constants(n)[0]
    h_tilde = 2 * sig / (P * L) * a_eta**2 + 4 * (1 - sig / (P * L)) * a_eta**2 * c1  # eq. 31
    assert hessian(eta, n, sig, P, L)[0, 0] == pytest.approx(L**3 * h_tilde, rel=1e-12)
