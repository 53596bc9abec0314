"""Elasto-viscoplastic Herschel-Bulkley model: the one home of the constitutive formulas.

Paper section 4 (eqs. 4-18) and appendix B (eqs. 52-57). SI units throughout (Pa, s, Pa s^n).

Notation. b_e is the elastic left Cauchy-Green tensor, J = sqrt(det b_e), bbar = J^(-2/3) b_e its
isochoric part, s = dev(sigma) = (mu/J) dev(bbar) the deviatoric Cauchy stress (eq. 13) and
x = ||s||_F its Frobenius norm.

Two flow rules, both written as "equivalent stress q = alpha*x, yield when q > beta*sigma_y,
plastic rate gamma_HB = ((q - beta*sigma_y)/eta)^(1/n), L_v b_e = -c * gamma_HB * s_hat * b_e":

* ``"paper"`` (eqs. 14-18): q = x/sqrt(2) is the simple-shear stress (eq. 14), the yield function is
  x/sqrt(2) - sigma_y (eq. 15), the flow direction sqrt(2) s_hat (eq. 18): alpha = 1/sqrt(2), beta = 1,
  c = sqrt(2).
* ``"yue2015"`` (Yue et al. 2015, the model before the paper's modification): von-Mises yield
  x - sqrt(2/3) sigma_y (i.e. sqrt(3/2) x > sigma_y), plastic rate ((x - sqrt(2/3) sigma_y)/eta)^(1/n)
  without the 1/sqrt(2) of eq. 14, and the flow direction the unit normal of the yield surface,
  -1/2 (L_v b_e) b_e^-1 = gamma_HB s_hat (eq. 11 with lambda = gamma_HB), i.e. c = 2: alpha = 1,
  beta = sqrt(2/3), c = 2.

With the Simo approximation (eqs. 54-56) the plastic correction only rescales dev(bbar) along s_hat,
and x solves the scalar equation (eq. 57 generalised to both rules)

    x - x_trial + c * k * ((alpha*x - beta*sigma_y)/eta)^(1/n) = 0,   k = dt * (mu/J) * tr(bbar_old)/3.

In simple shear at rate gamma_dot (b_e ~ I) the elastic predictor raises x by sqrt(2) mu gamma_dot per
unit time and the plastic correction lowers it by c mu gamma_HB, so the terminal state has
gamma_HB = sqrt(2)/c * gamma_dot. Paper: gamma_HB = gamma_dot and the eq.-14 shear stress x/sqrt(2)
tends to sigma_y + eta gamma_dot^n (eq. 7). Yue: gamma_HB = gamma_dot/sqrt(2), x = sqrt(2/3) sigma_y +
eta (gamma_dot/sqrt(2))^n, so x/sqrt(2) = sigma_y/sqrt(3) + eta gamma_dot^n / 2^((n+1)/2): lower
(paper Fig. 5). ``terminal_shear_stress`` returns both.

Trace in eq. 57: like the reference implementation (REFERENCE_SPEC 2.6) we use T = tr(bbar_old), the
isochoric trace *before* the elastic prediction, in k and in the isotropic part of the update
bbar_new ~ (T/3) I + (x/x_trial) dev(bbar_trial); eq. 57 as printed uses the trial trace. The two agree
to O(dt) per step but the O(dt) difference acts every step, so they converge to different steady
states. Measured in 3D simple shear at gamma_dot = 10/s (dt = 1e-4 s, tests/test_constitutive.py):
the old trace gives the eq.-7 terminal stress within 2e-5 for stresses up to 120 Pa and within 0.2 %
at eta = 30, n = 1, sigma_y = 40 (340 Pa), whereas the trial trace is 0.8 % low at 120 Pa and 5.5 %
low at 340 Pa (the exact continuous eq.-18 model, integrated with Radau, is 0.6 % and 4.4 % low).
The error of the trial trace grows like (sigma_s/mu)^2, so the two are equivalent only where
sigma_s << mu; the old trace is the one that meets the design goal of section 4.3 (terminal stress =
rheometer flow curve) across the material space, and it is what produced the paper's estimates.
The trial-trace variant is kept (``trial_trace=True``) only for that comparison.

Scalar solve. The reference runs 14 Newton steps on x with backtracking to keep x/sqrt(2) >= sigma_y.
Near the stiff limit (small eta, small n) Newton on x shrinks the excess stress only by a factor
(1 - n) per step, so 14 steps do not converge there (for a trial state one elastic step past the
steady state, dt = 7.5e-5 s, the excess stress is off by up to 77 % at eta ~ 6e-4 Pa s^n, n ~ 0.34;
a few mPa, so harmless in absolute terms, but avoidable). We write the equation in the excess
e = alpha*x - beta*sigma_y > 0:  e + alpha*c*k*(e/eta)^(1/n) = e_trial, and run Newton on
s = log(e) for G(s) = log(e^s + alpha*c*k*(e^s/eta)^(1/n)) - log(e_trial). G is a log-sum-exp of two
affine functions of s, hence convex and increasing, with slope between 1 and 1/n: Newton started at
s = log(e_trial) (where G >= 0) decreases monotonically onto the root and never overshoots. The
constraint e > 0 (x/sqrt(2) - sigma_y > 0) therefore holds by construction (no backtracking needed),
and a fixed budget of NEWTON_ITERATIONS converges over the whole material space.

Plasticity is isochoric: the corrected b_e is rescaled to det(b_e_trial) (paper section 4.4).

Taichi. ``kirchhoff_stress``, ``return_mapping`` and ``is_plastic`` are ``@ti.func`` for the MPM
solver (3x3, any float dtype). ``return_mapping_taichi`` runs the same func over a numpy batch.
Importing this module does not initialise Taichi; ``ensure_taichi`` does so only if nobody has.
Python float literals inside the funcs take Taichi's ``default_fp``: keep data and default_fp the
same precision (f64 data under default_fp=f32 agrees with numpy to ~1e-8 instead of ~1e-15; f32 data
under default_fp=f64 is computed in f64 and Taichi warns on the store).

Public names. numpy: ``kirchhoff_stress_np``, ``cauchy_stress``, ``dev``, ``shear_stress`` (eq. 14),
``yield_function`` (eq. 15), ``hb_flow_rate`` (eq. 17), ``solve_excess`` (eq. 57), ``return_mapping_np``,
``is_plastic_np``, ``terminal_shear_stress``, 1D model ``integrate_1d``, ``transition_time`` (eq. 8),
``terminal_stress`` (eq. 7), ``simple_shear`` -> ``ShearHistory``. Taichi: ``kirchhoff_stress``,
``return_mapping``, ``is_plastic``, ``return_mapping_taichi``, ``ensure_taichi``.
"""

from dataclasses import dataclass

import numpy as np
import taichi as ti

FLOW_RULES = ("paper", "yue2015")
NEWTON_ITERATIONS = 8
NEWTON_TOL = 1e-6  # early exit of the Taichi solve once a Newton step in log(e) is below this
SQRT2 = float(np.sqrt(2.0))
SQRT2_3 = float(np.sqrt(2.0 / 3.0))


# ---------------------------------------------------------------------------------------------------
# flow-rule coefficients (see module docstring)


@dataclass(frozen=True)
class FlowRule:
    """q = alpha*||dev sigma||_F is compared with beta*sigma_y; L_v b_e = -c*gamma_HB*s_hat*b_e."""

    alpha: float
    beta: float
    c: float


_RULES = {
    "paper": FlowRule(alpha=1.0 / SQRT2, beta=1.0, c=SQRT2),  # eqs. 14, 15, 18
    "yue2015": FlowRule(alpha=1.0, beta=SQRT2_3, c=2.0),  # von Mises, no 1/sqrt(2)
}


def get_flow_rule(name: str) -> FlowRule:
    """The coefficients of flow rule ``name`` ("paper" or "yue2015")."""
    if name not in _RULES:
        raise ValueError(f"unknown flow rule {name!r}: expected one of {', '.join(FLOW_RULES)}")
    return _RULES[name]


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


def terminal_shear_stress(eta, n, sigma_y, gamma_dot, flow_rule: str = "paper"):
    """Terminal eq.-14 shear stress of simple shear at rate gamma_dot (b_e ~ I limit).
    Paper: sigma_y + eta gamma_dot^n (eq. 7); yue2015: sigma_y/sqrt(3) + eta gamma_dot^n / 2^((n+1)/2)
    (derivation in the module docstring)."""
    r = get_flow_rule(flow_rule)
    rate = SQRT2 / r.c * np.asarray(gamma_dot, dtype=float)  # terminal plastic rate
    return (r.beta * np.asarray(sigma_y) + eta * rate ** np.asarray(n)) / (r.alpha * SQRT2)


# ---------------------------------------------------------------------------------------------------
# numpy: scalar solve and return mapping (appendix B)


def solve_excess(e_trial, a, eta, n, iterations: int = NEWTON_ITERATIONS) -> np.ndarray:
    """Root e of e + a (e/eta)^(1/n) = e_trial (eq. 57 in the excess stress e), for e_trial > 0.
    Newton on s = log(e), monotone from s = log(e_trial); see the module docstring."""
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


def return_mapping_np(be_trial, be_old, mu, eta, n, sigma_y, dt, *, flow_rule: str = "paper",
                      trial_trace: bool = False):
    """Plastic correction of the trial (elastically predicted) b_e (appendix B, eqs. 53-57).

    be_trial, be_old: (..., 3, 3), b_e after and before the elastic prediction; mu, eta, n, sigma_y,
    dt broadcast over ... . Returns the new b_e, with det b_e = det b_e_trial, and b_e_trial unchanged
    where the trial state does not yield (eq. 15). trial_trace=True uses tr(bbar_trial) instead of
    tr(bbar_old) (eq. 57 as printed; see the module docstring).
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
    if trial_trace:
        T = _trace(bbar)
    else:
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
    """True where the trial state yields (eq. 15 > 0); numpy twin of the Taichi ``is_plastic``."""
    be = np.asarray(be_trial, dtype=float)
    J = np.sqrt(np.linalg.det(be))
    s = _m(mu / J) * dev(be / _m(J ** (2.0 / 3.0)))  # eq. 13
    return yield_function(s, sigma_y, flow_rule) > 0


# ---------------------------------------------------------------------------------------------------
# 1D model (section 4.1) and 3D simple shear (section 4.3-4.4)


def transition_time(eta, n, strain_rate, mu: float = 1e3):
    """t_inf = eta / (mu * strain_rate^(1-n)) (eq. 8)."""
    return eta / (mu * np.asarray(strain_rate, dtype=float) ** (1.0 - np.asarray(n)))  # eq. 8


def terminal_stress(eta, n, sigma_y, strain_rate):
    """sigma_s,inf = sigma_y + eta strain_rate^n (eq. 7)."""
    return sigma_y + eta * np.asarray(strain_rate, dtype=float) ** np.asarray(n)  # eq. 7


def integrate_1d(eta, n, sigma_y, strain_rate: float = 10.0, *, mu: float = 1e3, t_end=None, dt=None):
    """Stress of the 1D model (eqs. 4-6) under a constant strain rate, from rest.

    d sigma/dt = mu (strain_rate - eps_p_dot), eps_p_dot = (max(0, sigma - sigma_y)/eta)^(1/n), integrated
    with backward Euler (the same scalar solve as the 3D return mapping). Defaults: t_end = yield time
    + 10 t_inf, dt = t_end/4000. Returns (t, sigma) with t[0] = 0, sigma[0] = 0.
    """
    _check_material(eta, n, sigma_y)
    t_yield = sigma_y / (mu * strain_rate)
    if t_end is None:
        t_end = t_yield + 10.0 * float(transition_time(eta, n, strain_rate, mu))
    if dt is None:
        dt = t_end / 4000
    steps = int(np.ceil(t_end / dt))
    sigma = np.zeros(steps + 1)
    for i in range(steps):
        trial = sigma[i] + mu * dt * strain_rate  # eqs. 4, 6: elastic prediction
        excess = trial - sigma_y
        if excess > 0:  # eq. 5, implicit in sigma[i+1]
            excess = float(solve_excess(excess, mu * dt, eta, n))
            trial = sigma_y + excess
        sigma[i + 1] = trial
    return dt * np.arange(steps + 1), sigma


@dataclass
class ShearHistory:
    """Time series of a 3D simple shear; stresses have shape (steps + 1, *material shape)."""

    t: np.ndarray
    shear_stress: np.ndarray  # eq. 14: ||dev sigma||_F / sqrt(2)
    sigma_xy: np.ndarray  # the xy component of the Cauchy stress


def simple_shear(eta, n, sigma_y, gamma_dot: float = 10.0, *, t_end: float = 0.1, dt: float = 1e-4,
                 mu: float = 1e3, kappa: float = 1e4, flow_rule: str = "paper",
                 trial_trace: bool = False) -> ShearHistory:
    """3D simple shear L = gamma_dot L_I (section 4.3) from rest, vectorised over materials.

    Each step: elastic prediction b* = F b F^T with F = I + dt L (eq. 52 is its first-order form; this is
    what the reference and our MPM do), then ``return_mapping_np``. Records the eq.-14 shear stress
    ||dev sigma||/sqrt(2) and sigma_xy (they agree to first order in the elastic strain).
    """
    eta, n, sigma_y = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (eta, n, sigma_y)))
    _check_material(eta, n, sigma_y)
    L = np.zeros((3, 3))
    L[0, 1] = gamma_dot  # v_x = gamma_dot * y
    F = np.eye(3) + dt * L
    steps = int(round(t_end / dt))
    be = np.broadcast_to(np.eye(3), eta.shape + (3, 3)).copy()
    tau_s = np.zeros((steps + 1,) + eta.shape)
    s_xy = np.zeros_like(tau_s)
    for i in range(steps):
        be = return_mapping_np(F @ be @ F.T, be, mu, eta, n, sigma_y, dt, flow_rule=flow_rule,
                               trial_trace=trial_trace)
        sigma = cauchy_stress(be, kappa, mu)
        tau_s[i + 1] = shear_stress(sigma)  # eq. 14
        s_xy[i + 1] = sigma[..., 0, 1]
    return ShearHistory(dt * np.arange(steps + 1), tau_s, s_xy)


def _check_material(eta, n, sigma_y) -> None:
    if np.any(np.asarray(eta) <= 0) or np.any(np.asarray(n) <= 0) or np.any(np.asarray(sigma_y) < 0):
        raise ValueError("unphysical material: need eta > 0, n > 0, sigma_y >= 0")


# ---------------------------------------------------------------------------------------------------
# Taichi (3x3, dtype of the inputs)

_IDENTITY = ((1, 0, 0), (0, 1, 0), (0, 0, 1))


_COEFFICIENTS = {y: (r.alpha, r.beta, r.c) for y, r in ((False, _RULES["paper"]), (True, _RULES["yue2015"]))}


@ti.func
def _ti_cbrt(x):
    """x^(1/3) for x > 0, in the dtype of x (a literal 1/3 would be rounded to default_fp)."""
    return ti.exp(ti.log(x) / 3)


@ti.func
def _ti_dev(a):
    return a - (a.trace() / 3.0) * ti.Matrix(_IDENTITY)


@ti.func
def kirchhoff_stress(be, kappa, mu):
    """Kirchhoff tau = (kappa/2)(J^2 - 1) I + mu dev(bbar) (eqs. 10, 12); MPM force is -V_p tau grad w."""
    det = be.determinant()
    bbar = be * _ti_cbrt(1 / det)
    return (0.5 * kappa * (det - 1.0)) * ti.Matrix(_IDENTITY) + mu * _ti_dev(bbar)


@ti.func
def _ti_solve_excess(e_trial, a, eta, n):
    """Taichi twin of ``solve_excess`` (eq. 57): Newton on log(e), fixed budget, monotone."""
    log_t = ti.log(e_trial)
    log_a = ti.log(a) - ti.log(eta) / n
    p = 1.0 / n
    s = log_t
    for _ in range(NEWTON_ITERATIONS):
        v = log_a + p * s
        m = ti.max(s, v)
        wu = ti.exp(s - m)
        wv = ti.exp(v - m)
        g = m + ti.log(wu + wv) - log_t
        step = g * (wu + wv) / (wu + p * wv)
        s -= step
        if ti.abs(step) < NEWTON_TOL:  # quadratic convergence: the remaining error is ~step^2
            break
    return ti.exp(s)


@ti.func
def _ti_excess(be_trial, mu, sigma_y, yue: ti.template()):
    """alpha*||s_trial|| - beta*sigma_y: the yield function of the trial state (eq. 15)."""
    alpha, beta, c = ti.static(_COEFFICIENTS[bool(yue)])
    det = be_trial.determinant()
    x_trial = mu / ti.sqrt(det) * _ti_dev(be_trial * _ti_cbrt(1 / det)).norm()  # eq. 13
    return alpha * x_trial - beta * sigma_y


@ti.func
def is_plastic(be_trial, mu, sigma_y, yue: ti.template()):
    """1 when the trial state yields (eq. 15 > 0), else 0 (ti.i32)."""
    result = 0
    if _ti_excess(be_trial, mu, sigma_y, yue) > 0:
        result = 1
    return result


@ti.func
def return_mapping(be_trial, be_old, mu, eta, n, sigma_y, dt, yue: ti.template()):
    """New b_e after the plastic correction of the trial b_e (appendix B, eq. 57, old trace).

    be_old: b_e before the elastic prediction; its isochoric trace enters eq. 57 (see module doc).
    yue: Python bool (template), True selects flow_rule="yue2015". Isochoric: det is kept.
    """
    alpha, beta, c = ti.static(_COEFFICIENTS[bool(yue)])
    det = be_trial.determinant()
    J = ti.sqrt(det)
    bbar = be_trial * _ti_cbrt(1 / det)
    d = _ti_dev(bbar)
    x_trial = mu / J * d.norm()  # eq. 13
    e_trial = alpha * x_trial - beta * sigma_y  # eq. 15
    result = be_trial
    if e_trial > 0:
        T = be_old.trace() * _ti_cbrt(1 / be_old.determinant())  # tr(bbar_old)
        k = dt * mu / J * T / 3.0  # eq. 57
        e = _ti_solve_excess(e_trial, alpha * c * k, eta, n)
        x = (e + beta * sigma_y) / alpha
        bbar_new = (T / 3.0) * ti.Matrix(_IDENTITY) + (x / x_trial) * d  # eq. 56
        result = bbar_new * _ti_cbrt(det / bbar_new.determinant())  # isochoric
    return result


def ensure_taichi(arch=None, default_fp=None) -> None:
    """Initialise Taichi (arch=cpu, default_fp=f32 unless given) only if nobody has initialised it yet."""
    from taichi.lang import impl

    if impl.get_runtime().prog is None:
        ti.init(arch=arch or ti.cpu, default_fp=default_fp or ti.f32, offline_cache=True)


@ti.kernel
def _return_mapping_kernel(be: ti.types.ndarray(ndim=3), be_old: ti.types.ndarray(ndim=3),
                           par: ti.types.ndarray(ndim=2), out: ti.types.ndarray(ndim=3),
                           plastic: ti.types.ndarray(ndim=1), yue: ti.template()):
    for p in range(be.shape[0]):
        b = ti.Matrix([[be[p, i, j] for j in ti.static(range(3))] for i in ti.static(range(3))])
        b0 = ti.Matrix([[be_old[p, i, j] for j in ti.static(range(3))] for i in ti.static(range(3))])
        plastic[p] = is_plastic(b, par[p, 0], par[p, 3], yue)
        r = return_mapping(b, b0, par[p, 0], par[p, 1], par[p, 2], par[p, 3], par[p, 4], yue)
        for i, j in ti.static(ti.ndrange(3, 3)):
            out[p, i, j] = r[i, j]


def return_mapping_taichi(be_trial, be_old, mu, eta, n, sigma_y, dt, *, flow_rule: str = "paper",
                          dtype=np.float64):
    """Run the Taichi ``return_mapping`` over a batch (N, 3, 3) in ``dtype`` (float32 or float64).
    Returns (new b_e as float64, plastic flags from ``is_plastic`` as bool)."""
    yue = get_flow_rule(flow_rule) is _RULES["yue2015"]
    ensure_taichi()
    be = np.ascontiguousarray(np.asarray(be_trial).reshape(-1, 3, 3), dtype=dtype)
    old = np.ascontiguousarray(np.broadcast_to(np.asarray(be_old), np.shape(be_trial)).reshape(-1, 3, 3),
                               dtype=dtype)
    batch = np.shape(be_trial)[:-2]
    par = np.stack([np.broadcast_to(np.asarray(v, dtype=float), batch).reshape(-1)
                    for v in (mu, eta, n, sigma_y, dt)], axis=1).astype(dtype)
    out = np.zeros_like(be)
    plastic = np.zeros(len(be), dtype=np.int32)
    _return_mapping_kernel(be, old, par, out, plastic, yue)
    return out.astype(np.float64).reshape(np.shape(be_trial)), plastic.astype(bool)
