"""Elasto-viscoplastic Herschel-Bulkley model (mpm/constitutive.py) and its homogeneous tests (mpm/shear.py):
physics and numpy/Taichi agreement."""

import itertools

import numpy as np
import pytest
import taichi as ti

from mpm import constitutive as c
from mpm import runtime
from mpm import shear

MU, KAPPA, GAMMA_DOT = 1e3, 1e4, 10.0
GRID = np.array(list(itertools.product([0.1, 1.0, 10.0], [0.3, 0.6, 1.0], [0.0, 5.0, 20.0]))).T  # eta, n, sy


@pytest.fixture(scope="module")
def shear_paper():
    return shear.simple_shear(*GRID, GAMMA_DOT, t_end=0.1, dt=1e-4)


def random_states(N, seed=0, strain=0.01):
    """Random b_e before (be_old) and after (be_trial) an elastic prediction, and random materials
    spanning the material space; stresses of ~0-40 Pa so that both branches occur."""
    rng = np.random.default_rng(seed)
    A = np.eye(3) + strain * rng.normal(size=(N, 3, 3))
    be_old = A @ A.transpose(0, 2, 1)
    F = np.eye(3) + 0.5 * strain * rng.normal(size=(N, 3, 3))
    be_trial = F @ be_old @ F.transpose(0, 2, 1)
    eta = 10 ** rng.uniform(-4, np.log10(30), N)
    n = rng.uniform(0.3, 1.0, N)
    sy = rng.uniform(0.0, 40.0, N)
    dt = 10 ** rng.uniform(-5, np.log10(5e-4), N)
    return be_trial, be_old, eta, n, sy, dt


def rel_diff(a, b):
    return np.max(np.abs(a - b), axis=(-2, -1)) / np.max(np.abs(b), axis=(-2, -1))


# ---------------------------------------------------------------------------------------------------
# closed forms and scalar pieces


def test_stress_of_identity_and_pure_volume_change():
    assert np.allclose(c.kirchhoff_stress_np(np.eye(3), KAPPA, MU), 0.0)
    J = 1.05
    tau = c.kirchhoff_stress_np(J ** (2 / 3) * np.eye(3), KAPPA, MU)  # b_e of F = J^(1/3) I
    assert np.allclose(tau, 0.5 * KAPPA * (J * J - 1) * np.eye(3))  # eq. 12 pressure, no shear
    assert np.allclose(c.cauchy_stress(J ** (2 / 3) * np.eye(3), KAPPA, MU), tau / J)


def test_shear_stress_and_yield_function_of_simple_shear_stress():
    sigma = 7.0 * np.array([[0, 1, 0], [1, 0, 0], [0, 0, 0]]) + 3.0 * np.eye(3)  # sigma_s D_I - p I
    assert c.shear_stress(sigma) == pytest.approx(7.0)  # eq. 14 recovers the scalar shear stress
    assert c.yield_function(sigma, 5.0) == pytest.approx(2.0)  # eq. 15
    # von Mises: sqrt(3/2)||dev|| = sqrt(3)*7 = 12.12 > 12, but < 12.2
    assert c.yield_function(sigma, 12.0, "yue2015") > 0 > c.yield_function(sigma, 12.2, "yue2015")


def test_hb_flow_rate_inverts_the_flow_curve():
    eta, n, sy = GRID
    assert np.allclose(c.hb_flow_rate(shear.terminal_stress(eta, n, sy, GAMMA_DOT), eta, n, sy), GAMMA_DOT)  # eqs. 7, 17
    assert np.all(c.hb_flow_rate(sy * 0.5, eta, n, sy) == 0.0)


def test_scalar_solve_converges_over_the_material_space_within_the_fixed_budget():
    g = np.array(list(itertools.product(np.logspace(-4, np.log10(30), 8), np.linspace(0.3, 1, 6),
                                        np.logspace(-8, 5, 10), np.logspace(-6, 1, 6)))).T
    eta, n, e_trial, a = g
    e = c.solve_excess(e_trial, a, eta, n)
    assert np.all(e > 0) and np.all(e <= e_trial * (1 + 1e-12))  # stays on the yielding side, never overshoots
    residual = np.abs(e + a * (e / eta) ** (1 / n) - e_trial) / e_trial
    assert residual.max() < 1e-12
    assert np.allclose(e, c.solve_excess(e_trial, a, eta, n, iterations=60), rtol=1e-12)


def test_unknown_flow_rule_and_unphysical_material_raise():
    with pytest.raises(ValueError, match="flow rule"):
        c.get_flow_rule("bingham")
    with pytest.raises(ValueError, match="unphysical"):
        shear.simple_shear(-1.0, 0.5, 0.0, t_end=1e-3)


# ---------------------------------------------------------------------------------------------------
# 1D model (section 4.1)


@pytest.mark.parametrize("eta, n, sy", [(0.1, 0.3, 5.0), (1.0, 0.6, 0.0), (10.0, 1.0, 20.0), (3.0, 0.45, 12.0)])
def test_1d_model_terminal_stress_and_transition_time(eta, n, sy):
    t, sigma = shear.integrate_1d(eta, n, sy, GAMMA_DOT)
    term = shear.terminal_stress(eta, n, sy, GAMMA_DOT)  # eq. 7
    t_inf = shear.transition_time(eta, n, GAMMA_DOT)  # eq. 8
    assert sigma[-1] == pytest.approx(term, rel=1e-3)
    assert np.all(np.diff(sigma) >= -1e-12)  # monotone approach from below
    t_yield = sy / (MU * GAMMA_DOT)
    t95 = t[np.argmax(sigma >= sy + 0.95 * (term - sy))] - t_yield
    # of the order of t_inf: ln(20) t_inf = 3.0 t_inf exactly for n = 1 (linear ODE), faster for n < 1
    assert t_inf / 3 <= t95 <= 3.1 * t_inf


def test_1d_model_relaxes_exponentially_for_n_1():
    """For n = 1 the 1D model is linear: the excess stress relaxes like exp(-t / t_inf) after yield, so it
    reaches 95 % of its terminal value ln(20) t_inf after the yield time."""
    eta, sy = 10.0, 20.0
    t, sigma = shear.integrate_1d(eta, 1.0, sy, GAMMA_DOT)
    term, t_inf = shear.terminal_stress(eta, 1.0, sy, GAMMA_DOT), shear.transition_time(eta, 1.0, GAMMA_DOT)
    t95 = t[np.argmax(sigma >= sy + 0.95 * (term - sy))] - sy / (MU * GAMMA_DOT)
    assert t95 == pytest.approx(np.log(20) * t_inf, rel=0.01)


# ---------------------------------------------------------------------------------------------------
# 3D simple shear (sections 4.3, 4.4; paper Fig. 5)


def test_simple_shear_terminal_stress_is_the_flow_curve(shear_paper):
    final = shear_paper.shear_stress[-1]
    assert np.allclose(final, shear.terminal_stress(*GRID, GAMMA_DOT), rtol=0.01)  # eq. 7 within 1 %
    assert np.allclose(final, shear_paper.shear_stress[-100], rtol=1e-3)  # steady


def test_simple_shear_terminal_stress_at_large_stress_and_mpm_time_step():
    h = shear.simple_shear([30.0, 1e-3], [1.0, 0.3], [40.0, 0.0], GAMMA_DOT, t_end=0.25, dt=5e-4)
    assert np.allclose(h.shear_stress[-1], shear.terminal_stress([30.0, 1e-3], [1.0, 0.3], [40.0, 0.0], GAMMA_DOT),
                       rtol=0.01)


def test_yue2015_terminal_stress_is_lower_and_matches_its_closed_form(shear_paper):
    h = shear.simple_shear(*GRID, GAMMA_DOT, t_end=0.1, dt=1e-4, flow_rule="yue2015")
    final = h.shear_stress[-1]
    assert np.all(final < 0.8 * shear_paper.shear_stress[-1])  # paper Fig. 5: substantially lower
    assert np.allclose(final, shear.terminal_shear_stress(*GRID, GAMMA_DOT, "yue2015"), rtol=0.01)


def test_old_trace_in_eq57_keeps_the_flow_curve_up_to_the_largest_stresses():
    """With tr(bbar_old) in eq. 57 the terminal stress is eq. 7 within 0.2 % from 5.8 Pa to 340 Pa (the
    printed eq. 57, with the trial trace, is several % low at 340 Pa)."""
    eta, n, sy = [0.1, 10.0, 30.0], [0.6, 1.0, 1.0], [5.0, 20.0, 40.0]
    term = shear.terminal_stress(eta, n, sy, GAMMA_DOT)
    old = shear.simple_shear(eta, n, sy, t_end=0.25, dt=2e-4).shear_stress[-1] / term - 1
    assert np.all(np.abs(old) < 2e-3)


# ---------------------------------------------------------------------------------------------------
# return mapping: invariants and Taichi vs numpy


def test_return_mapping_is_isochoric_and_identity_below_yield():
    be_trial, be_old, eta, n, sy, dt = random_states(2000)
    out = c.return_mapping_np(be_trial, be_old, MU, eta, n, sy, dt)
    plastic = c.is_plastic_np(be_trial, MU, sy)
    assert 0.2 < plastic.mean() < 0.9  # both branches exercised
    assert np.allclose(np.linalg.det(out), np.linalg.det(be_trial), rtol=1e-12, atol=0)  # isochoric
    assert np.array_equal(out[~plastic], be_trial[~plastic])  # elastic: identity
    # plastic: the deviatoric stress keeps its direction (radial return) and is lowered onto the yield
    # surface, up to O(strain^2) from the Simo approximation (eq. 55) and the unimodular rescaling,
    # and, with the old trace, up to the relative trace change tr(bbar_trial)/tr(bbar_old) - 1
    d_new = c.dev(c.cauchy_stress(out, KAPPA, MU))[plastic]
    d_trial = c.dev(c.cauchy_stress(be_trial, KAPPA, MU))[plastic]
    cos = np.sum(d_new * d_trial, axis=(1, 2)) / (np.linalg.norm(d_new, axis=(1, 2)) * np.linalg.norm(d_trial, axis=(1, 2)))
    assert np.allclose(cos, 1.0, atol=1e-12)
    s_trial = c.shear_stress(d_trial)
    assert np.all(c.shear_stress(d_new) < s_trial * (1 + 1e-3))
    assert np.all(c.yield_function(d_new, sy[plastic]) > -1e-3 * s_trial)


def test_high_yield_stress_never_yields():
    be_trial, be_old, eta, n, _, dt = random_states(200)
    sy = np.full(200, 1e4)
    assert not c.is_plastic_np(be_trial, MU, sy).any()
    assert np.array_equal(c.return_mapping_np(be_trial, be_old, MU, eta, n, sy, dt), be_trial)


def _check_f32(out32, pl32, flags, be_trial, ref, sy, flow_rule):
    clear = np.abs(c.yield_function(c.cauchy_stress(be_trial, KAPPA, MU), sy, flow_rule)) > 1e-2
    assert np.array_equal(pl32[clear], flags[clear])
    assert rel_diff(out32, ref).max() < 1e-5  # f32: ~3e-7 measured
    # f32 stress: the deviator is a difference of O(1) numbers, so compare in Pa
    dstress = np.abs(c.cauchy_stress(out32, KAPPA, MU) - c.cauchy_stress(ref, KAPPA, MU)).max()
    assert dstress < 0.05


@pytest.mark.parametrize("flow_rule", ["paper", "yue2015"])
def test_taichi_return_mapping_equals_numpy(flow_rule):
    be_trial, be_old, eta, n, sy, dt = random_states(1000, seed=1)
    ref = c.return_mapping_np(be_trial, be_old, MU, eta, n, sy, dt, flow_rule=flow_rule)
    flags = c.is_plastic_np(be_trial, MU, sy, flow_rule)
    out64, pl64, _ = c.return_mapping_taichi(be_trial, be_old, MU, eta, n, sy, dt, flow_rule=flow_rule)
    assert np.array_equal(pl64, flags)
    assert rel_diff(out64, ref).max() < 1e-7  # f64 literals may be f32 under default_fp=f32
    assert np.allclose(np.linalg.det(out64), np.linalg.det(be_trial), rtol=1e-7, atol=0)
    out32, pl32, _ = c.return_mapping_taichi(be_trial, be_old, MU, eta, n, sy, dt, flow_rule=flow_rule,
                                             dtype=np.float32)
    _check_f32(out32, pl32, flags, be_trial, ref, sy, flow_rule)


@pytest.mark.parametrize("flow_rule", ["paper", "yue2015"])
def test_native_return_mapping_equals_numpy(flow_rule):
    """The native engine's return mapping (f32 only) against numpy, as Taichi's f32 one."""
    native = _native_engine()
    be_trial, be_old, eta, n, sy, dt = random_states(1000, seed=1)
    ref = c.return_mapping_np(be_trial, be_old, MU, eta, n, sy, dt, flow_rule=flow_rule)
    flags = c.is_plastic_np(be_trial, MU, sy, flow_rule)
    out32, pl32, _ = native.return_mapping(be_trial, be_old, MU, eta, n, sy, dt, flow_rule=flow_rule)
    _check_f32(out32, pl32, flags, be_trial, ref, sy, flow_rule)


def _native_engine():
    import engines

    engines.require("native")
    from mpm import native_engine

    return native_engine


@ti.kernel
def _kirchhoff_kernel(be: ti.types.ndarray(ndim=3), out: ti.types.ndarray(ndim=3)):
    for p in range(be.shape[0]):
        b = ti.Matrix([[be[p, i, j] for j in ti.static(range(3))] for i in ti.static(range(3))])
        tau = c.kirchhoff_stress(b, c.iso_factor(b.determinant()), 1e4, 1e3)
        for i, j in ti.static(ti.ndrange(3, 3)):
            out[p, i, j] = tau[i, j]


def test_taichi_kirchhoff_stress_equals_numpy():
    runtime.ensure_taichi()
    be = random_states(100, seed=2, strain=0.05)[0]
    out = np.zeros_like(be)
    _kirchhoff_kernel(be, out)
    ref = c.kirchhoff_stress_np(be, KAPPA, MU)
    assert np.abs(out - ref).max() < 1e-6 * np.abs(ref).max()


@pytest.mark.parametrize("engine, dtype", [("taichi-cpu", np.float64), ("taichi-cpu", np.float32),
                                           ("native", np.float32)])
def test_warm_started_newton_solve_reaches_the_same_root(engine, dtype):
    """The MPM kernel starts the Newton solve of eq. 57 from the particle's last log(e): from below the
    root (the first step lands above it) or above it, near or far, the result is the cold-started one."""
    if engine == "native":
        native = _native_engine()

        def mapping(*args, log_e0=c.NO_WARM_START):
            return native.return_mapping(*args, log_e0=log_e0)
    else:
        def mapping(*args, log_e0=c.NO_WARM_START):
            return c.return_mapping_taichi(*args, dtype=dtype, log_e0=log_e0)
    be_trial, be_old, eta, n, sy, dt = random_states(1000, seed=3)
    cold, plastic, log_e = mapping(be_trial, be_old, MU, eta, n, sy, dt)
    assert plastic.sum() > 300 and np.isfinite(log_e[plastic]).all() and np.isnan(log_e[~plastic]).all()
    e = np.exp(log_e[plastic])
    assert np.all(e > 0)
    root = np.where(plastic, log_e, 0.0)
    tol = 1e-8 if dtype == np.float64 else 2e-6  # the solve stops within ~1e-9 of the root (NEWTON_TOL)
    for shift in (-3.0, -0.3, -1e-3, 1e-3, 0.3, 3.0):
        warm, plastic_w, log_w = mapping(be_trial, be_old, MU, eta, n, sy, dt, log_e0=root + shift)
        assert np.array_equal(plastic_w, plastic)
        assert rel_diff(warm, cold).max() < tol
        assert np.abs(log_w[plastic] - log_e[plastic]).max() < 100 * tol
