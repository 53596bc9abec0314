"""Elasto-viscoplastic Herschel-Bulkley model: the one home of the constitutive formulas.

Paper section 4 (eqs. 4-18) and appendix B (eqs. 52-57); SI units. Two flow rules, ``"paper"`` (eqs.
14-18) and ``"yue2015"`` (von Mises), both "yield when alpha*||dev sigma|| > beta*sigma_y, L_v b_e =
-c gamma_HB s_hat b_e" (``FlowRule``). numpy: stress, yield function, flow rate, the scalar solve of eq. 57
and the return mapping. Taichi (``@ti.func``, 3x3, any float dtype): ``iso_factor``,
``kirchhoff_stress`` and ``return_mapping`` for the MPM kernels, and ``return_mapping_taichi`` over a numpy
batch.
Python float literals inside the funcs take Taichi's ``default_fp``: keep data and default_fp alike.
"""

import numpy as np
import taichi as ti

from mpm import runtime
from mpm.solver_constants import (CBRT_ITERATIONS, CBRT_TOL, NEWTON_ITERATIONS, NEWTON_TOL,  # noqa: F401 (re-exported)
                                  NO_WARM_START, SQRT2, SQRT2_3, FlowRule, get_flow_rule)

# ---------------------------------------------------------------------------------------------------
# numpy: stress, yield, flow rate (arrays of shape (..., 3, 3), parameters broadcast over ...)


def _eye_like(a: np.ndarray) -> np.ndarray:
    return np.broadcast_to(np.eye(3, dtype=a.dtype), a.shape)


def _trace(a: np.ndarray) -> np.ndarray:
    return np.trace(a, axis1=-2, axis2=-1)


def _norm(a: np.ndarray) -> np.ndarray:
    return np.sqrt(np.sum(a * a, axis=(-2, -1)))


def _m(v) -> np.ndarray:
    """Broadcast a per-particle scalar against a (..., 3, 3) stack."""
    return np.asarray(v)[..., None, None]


def dev(a: np.ndarray) -> np.ndarray:
    """Deviatoric part A - tr(A)/3 I (section 4.2, after eq. 13)."""
    a = np.asarray(a, dtype=float)
    return a - _m(_trace(a) / 3.0) * _eye_like(a)


def kirchhoff_stress_np(be, kappa: float, mu: float) -> np.ndarray:
    """Kirchhoff stress tau = J sigma of the energy of eq. 12 (through eq. 10):
    tau = (kappa/2)(J^2 - 1) I + mu dev(bbar)."""
    be = np.asarray(be, dtype=float)
    J = np.sqrt(np.linalg.det(be))
    bbar = be * _m(J ** (-2.0 / 3.0))
    return _m(0.5 * kappa * (J * J - 1.0)) * _eye_like(be) + mu * dev(bbar)  # eqs. 10, 12


def cauchy_stress(be, kappa: float, mu: float) -> np.ndarray:
    """Cauchy stress sigma = tau / J (eq. 10); its deviator is (mu/J) dev(bbar) (eq. 13)."""
    be = np.asarray(be, dtype=float)
    return kirchhoff_stress_np(be, kappa, mu) / _m(np.sqrt(np.linalg.det(be)))


def shear_stress(sigma) -> np.ndarray:
    """Scalar shear stress sigma_s = ||dev sigma||_F / sqrt(2) (eq. 14)."""
    return _norm(dev(np.asarray(sigma, dtype=float))) / SQRT2  # eq. 14


def yield_function(sigma, sigma_y, flow_rule: str = "paper") -> np.ndarray:
    """Phi(sigma; sigma_y) > 0 means plastic. Paper: ||dev sigma||/sqrt(2) - sigma_y (eq. 15);
    yue2015: ||dev sigma|| - sqrt(2/3) sigma_y (von Mises)."""
    r = get_flow_rule(flow_rule)
    return r.alpha * _norm(dev(np.asarray(sigma, dtype=float))) - r.beta * np.asarray(sigma_y)  # eq. 15


def hb_flow_rate(sigma_s, eta, n, sigma_y) -> np.ndarray:
    """Herschel-Bulkley flow rate gamma_HB = (max(0, sigma_s - sigma_y)/eta)^(1/n) (eq. 17)."""
    excess = np.maximum(0.0, np.asarray(sigma_s, dtype=float) - sigma_y)
    return (excess / eta) ** (1.0 / np.asarray(n, dtype=float))  # eq. 17



# ---------------------------------------------------------------------------------------------------
# numpy: scalar solve and return mapping (appendix B)


def solve_excess(e_trial, a, eta, n, iterations: int = NEWTON_ITERATIONS) -> np.ndarray:
    """Root e of e + a (e/eta)^(1/n) = e_trial (eq. 57 in the excess stress e), for e_trial > 0.
    Newton on s = log(e) from s = log(e_trial): G(s) = log(e^s + a (e^s/eta)^(1/n)) - log(e_trial) is
    convex and increasing, so the iterates decrease monotonically onto the root and keep e > 0."""
    e_trial, a, eta, n = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (e_trial, a, eta, n)))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        log_t = np.log(e_trial)
        log_a = np.log(a) - np.log(eta) / n
        p = 1.0 / n
        s = log_t.copy()
        for _ in range(iterations):
            u, v = s, log_a + p * s
            m = np.maximum(u, v)
            wu, wv = np.exp(u - m), np.exp(v - m)
            g = m + np.log(wu + wv) - log_t
            s = s - g * (wu + wv) / (wu + p * wv)
        e = np.exp(s)
    return np.where(e_trial > 0, np.where(np.isfinite(e), e, e_trial), 0.0)


def return_mapping_np(be_trial, be_old, mu, eta, n, sigma_y, dt, *, flow_rule: str = "paper"):
    """Plastic correction of the trial (elastically predicted) b_e (appendix B, eqs. 53-57).

    be_trial, be_old: (..., 3, 3), b_e after and before the elastic prediction; mu, eta, n, sigma_y,
    dt broadcast over ... . Returns the new b_e, with det b_e = det b_e_trial, and b_e_trial unchanged
    where the trial state does not yield (eq. 15). The isochoric trace in eq. 57 is tr(bbar_old), before
    the elastic prediction, as in the reference implementation (eq. 57 as printed uses the trial trace).
    """
    r = get_flow_rule(flow_rule)
    be = np.asarray(be_trial, dtype=float)
    det = np.linalg.det(be)
    J = np.sqrt(det)
    bbar = be / _m(np.cbrt(det))
    d = dev(bbar)
    x_trial = mu / J * _norm(d)  # eq. 13
    e_trial = r.alpha * x_trial - r.beta * np.asarray(sigma_y, dtype=float)  # eq. 15
    plastic = e_trial > 0
    old = np.asarray(be_old, dtype=float)
    T = _trace(old / _m(np.cbrt(np.linalg.det(old))))
    k = dt * mu / J * T / 3.0  # eq. 57, mu_hat = mu tr(bbar)/3
    e = solve_excess(np.where(plastic, e_trial, 1.0), r.alpha * r.c * k, eta, n)  # eq. 57
    x = (e + r.beta * np.asarray(sigma_y, dtype=float)) / r.alpha
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(plastic, x / x_trial, 1.0)
    bbar_new = _m(T / 3.0) * _eye_like(be) + _m(ratio) * d  # eq. 56
    be_new = bbar_new * _m(np.cbrt(det / np.linalg.det(bbar_new)))  # isochoric: det kept
    return np.where(_m(plastic), be_new, be)


def is_plastic_np(be_trial, mu, sigma_y, flow_rule: str = "paper") -> np.ndarray:
    """True where the trial state yields (eq. 15 > 0)."""
    be = np.asarray(be_trial, dtype=float)
    J = np.sqrt(np.linalg.det(be))
    s = _m(mu / J) * dev(be / _m(J ** (2.0 / 3.0)))  # eq. 13
    return yield_function(s, sigma_y, flow_rule) > 0


# ---------------------------------------------------------------------------------------------------
# Taichi (3x3, dtype of the inputs)

_IDENTITY = ((1, 0, 0), (0, 1, 0), (0, 0, 1))


_COEFFICIENTS = {y: (r.alpha, r.beta, r.c) for y, r in ((False, get_flow_rule("paper")), (True, get_flow_rule("yue2015")))}


@ti.func
def _ti_cbrt(x):
    """x^(1/3) for x > 0, in the dtype of x: Halley's iteration y <- y (y^3 + 2x) / (2y^3 + x) from y = 1.

    It converges cubically, and the arguments here (determinants of b_e and their ratios) lie close to 1,
    so two or three iterations (a few multiplications and one division each) replace exp(log(x)/3).
    Far from 1 it doubles or halves y per iteration until it gets close. It stops once the relative change
    is below CBRT_TOL: the error left is then of the order CBRT_TOL^3, below f64 resolution.
    """
    y = x * 0 + 1
    for _ in range(CBRT_ITERATIONS):
        y3 = y * y * y
        y_new = y * (y3 + 2 * x) / (2 * y3 + x)
        small = ti.abs(y_new - y) <= CBRT_TOL * y_new
        y = y_new
        if small:
            break
    return y


@ti.func
def _ti_dev(a):
    return a - (a.trace() / 3.0) * ti.Matrix(_IDENTITY)


@ti.func
def iso_factor(det):
    """det(b_e)^(-1/3): bbar = iso_factor(det b_e) b_e is the isochoric part of b_e (eq. 10). The MPM kernels
    keep it per particle: the return mapping keeps det b_e, so the factor of the trial state is the factor
    of the new b_e, used again by the next step's stress and eq. 57."""
    return _ti_cbrt(1 / det)


@ti.func
def kirchhoff_stress(be, iso, kappa, mu):
    """Kirchhoff tau = (kappa/2)(J^2 - 1) I + mu dev(bbar) (eqs. 10, 12), iso = ``iso_factor(det be)``;
    the MPM force is -V_p tau grad w."""
    det = be.determinant()
    return (0.5 * kappa * (det - 1.0)) * ti.Matrix(_IDENTITY) + mu * _ti_dev(be * iso)


@ti.func
def _ti_solve_excess(e_trial, a, eta, n, s0):
    """Taichi twin of ``solve_excess`` (eq. 57): Newton on s = log(e) from min(s0, log(e_trial)); returns s.

    From above the root the iterates decrease monotonically (G is convex and increasing); from below (a warm
    start s0: last step's log(e) of the particle) the first step lands above the root, and the rest is
    monotone. G' lies between 1 and 1/n, so a start near the root converges in one or two steps.
    """
    log_t = ti.log(e_trial)
    log_a = ti.log(a) - ti.log(eta) / n
    p = 1.0 / n
    s = ti.min(s0, log_t)
    for _ in range(NEWTON_ITERATIONS):
        # G(s) = log(e^s + e^v) - log_t with v = log_a + p s; with d = v - s and r = e^-|d| <= 1:
        # G = max(s, v) + log(1 + r) - log_t, G' = (1 + p r)/(1 + r) (d <= 0) or (r + p)/(1 + r)
        d = log_a + (p - 1.0) * s
        r = ti.exp(-ti.abs(d))
        g = ti.max(s, s + d) + ti.log(1.0 + r) - log_t
        slope = (1.0 + p * r) / (1.0 + r)
        if d > 0:
            slope = (r + p) / (1.0 + r)
        step = g / slope
        s -= step
        if ti.abs(step) < NEWTON_TOL:  # quadratic convergence: the remaining error is ~step^2
            break
    return s


@ti.func
def return_mapping(be_trial, be_old, iso_old, mu, eta, n, sigma_y, dt, log_e0, yue: ti.template()):
    """Plastic correction of the trial b_e (appendix B, eq. 57, old trace).

    be_old: b_e before the elastic prediction, iso_old its ``iso_factor`` (its isochoric trace enters eq.
    57); log_e0: start of the Newton solve in log(excess stress) (last step's result, or NO_WARM_START).
    yue: Python bool (template), True selects flow_rule="yue2015". Isochoric: det is kept. Returns
    (new b_e, its iso_factor, log(e) of the solve or NO_WARM_START when elastic, 1 if plastic else 0).
    """
    alpha, beta, c = ti.static(_COEFFICIENTS[bool(yue)])
    det = be_trial.determinant()
    J = ti.sqrt(det)
    iso = iso_factor(det)
    d = _ti_dev(be_trial * iso)
    x_trial = mu / J * d.norm()  # eq. 13
    e_trial = alpha * x_trial - beta * sigma_y  # eq. 15
    result = be_trial
    log_e = e_trial * 0 + NO_WARM_START
    plastic = 0
    if e_trial > 0:
        T = be_old.trace() * iso_old  # tr(bbar_old)
        k = dt * mu / J * T / 3.0  # eq. 57
        log_e = _ti_solve_excess(e_trial, alpha * c * k, eta, n, log_e0)
        x = (ti.exp(log_e) + beta * sigma_y) / alpha
        bbar_new = (T / 3.0) * ti.Matrix(_IDENTITY) + (x / x_trial) * d  # eq. 56
        result = bbar_new * _ti_cbrt(det / bbar_new.determinant())  # isochoric
        plastic = 1
    return result, iso, log_e, plastic


@ti.kernel
def _return_mapping_kernel(be: ti.types.ndarray(ndim=3), be_old: ti.types.ndarray(ndim=3),
                           par: ti.types.ndarray(ndim=2), out: ti.types.ndarray(ndim=3),
                           plastic: ti.types.ndarray(ndim=1), log_e: ti.types.ndarray(ndim=1), yue: ti.template()):
    for p in range(be.shape[0]):
        b = ti.Matrix([[be[p, i, j] for j in ti.static(range(3))] for i in ti.static(range(3))])
        b0 = ti.Matrix([[be_old[p, i, j] for j in ti.static(range(3))] for i in ti.static(range(3))])
        r, _, s, pl = return_mapping(b, b0, iso_factor(b0.determinant()), par[p, 0], par[p, 1], par[p, 2],
                                     par[p, 3], par[p, 4], par[p, 5], yue)
        plastic[p] = pl
        log_e[p] = s
        for i, j in ti.static(ti.ndrange(3, 3)):
            out[p, i, j] = r[i, j]


def return_mapping_taichi(be_trial, be_old, mu, eta, n, sigma_y, dt, *, flow_rule: str = "paper",
                          dtype=np.float64, log_e0=NO_WARM_START):
    """Run the Taichi ``return_mapping`` over a batch (N, 3, 3) in ``dtype`` (float32 or float64), its
    Newton solve started from ``log_e0`` (broadcast; default: from log(e_trial)). Returns (new b_e as
    float64, plastic flags as bool, log of the excess stress e of eq. 57 where plastic, else NaN)."""
    yue = get_flow_rule(flow_rule) is get_flow_rule("yue2015")
    runtime.ensure_taichi()
    be = np.ascontiguousarray(np.asarray(be_trial).reshape(-1, 3, 3), dtype=dtype)
    old = np.ascontiguousarray(np.broadcast_to(np.asarray(be_old), np.shape(be_trial)).reshape(-1, 3, 3),
                               dtype=dtype)
    batch = np.shape(be_trial)[:-2]
    par = np.stack([np.broadcast_to(np.asarray(v, dtype=float), batch).reshape(-1)
                    for v in (mu, eta, n, sigma_y, dt, log_e0)], axis=1).astype(dtype)
    out = np.zeros_like(be)
    plastic = np.zeros(len(be), dtype=np.int32)
    log_e = np.zeros(len(be), dtype=dtype)
    _return_mapping_kernel(be, old, par, out, plastic, log_e, yue)
    flags = plastic.astype(bool)
    return (out.astype(np.float64).reshape(np.shape(be_trial)), flags.reshape(batch),
            np.where(flags, log_e.astype(np.float64), np.nan).reshape(batch))
