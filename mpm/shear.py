"""Homogeneous tests of the constitutive model: the 1D elasto-viscoplastic model under a constant strain
rate (paper section 4.1, eqs. 4-8) and 3D simple shear through the return mapping of
``mpm.constitutive`` (sections 4.3-4.4, paper Figs. 2 and 5). numpy only, SI units.
"""
from dataclasses import dataclass

import numpy as np

from mpm.constitutive import SQRT2, cauchy_stress, get_flow_rule, return_mapping_np, shear_stress, solve_excess
from mpm.params import check_material, flow_curve
from mpm.scene import KAPPA_PA, MU_PA


def transition_time(eta, n, strain_rate, mu: float = MU_PA):
    """t_inf = eta / (mu * strain_rate^(1-n)) (eq. 8)."""
    return eta / (mu * np.asarray(strain_rate, dtype=float) ** (1.0 - np.asarray(n)))  # eq. 8


def terminal_stress(eta, n, sigma_y, strain_rate):
    """sigma_s,inf = sigma_y + eta strain_rate^n (eq. 7): the flow curve (eq. 1) at the imposed rate."""
    return flow_curve(eta, np.asarray(n), sigma_y, strain_rate)  # eq. 7


def integrate_1d(eta, n, sigma_y, strain_rate: float = 10.0, *, mu: float = MU_PA, t_end=None, dt=None):
    """Stress of the 1D model (eqs. 4-6) under a constant strain rate, from rest.

    d sigma/dt = mu (strain_rate - eps_p_dot), eps_p_dot = (max(0, sigma - sigma_y)/eta)^(1/n), integrated
    with backward Euler (the same scalar solve as the 3D return mapping). Defaults: t_end = yield time
    + 10 t_inf, dt = t_end/4000. Returns (t, sigma) with t[0] = 0, sigma[0] = 0.
    """
    check_material(eta, n, sigma_y)
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
                 mu: float = MU_PA, kappa: float = KAPPA_PA, flow_rule: str = "paper") -> ShearHistory:
    """3D simple shear L = gamma_dot L_I (section 4.3) from rest, vectorised over materials.

    Each step: elastic prediction b* = F b F^T with F = I + dt L (eq. 52 is its first-order form; this is
    what the reference implementation and our MPM do), then ``return_mapping_np``. Records the eq.-14 shear stress
    ||dev sigma||/sqrt(2) and sigma_xy (they agree to first order in the elastic strain).
    """
    eta, n, sigma_y = np.broadcast_arrays(*(np.asarray(v, dtype=float) for v in (eta, n, sigma_y)))
    check_material(eta, n, sigma_y)
    L = np.zeros((3, 3))
    L[0, 1] = gamma_dot  # v_x = gamma_dot * y
    F = np.eye(3) + dt * L
    steps = int(round(t_end / dt))
    be = np.broadcast_to(np.eye(3), eta.shape + (3, 3)).copy()
    tau_s = np.zeros((steps + 1,) + eta.shape)
    s_xy = np.zeros_like(tau_s)
    for i in range(steps):
        be = return_mapping_np(F @ be @ F.T, be, mu, eta, n, sigma_y, dt, flow_rule=flow_rule)
        sigma = cauchy_stress(be, kappa, mu)
        tau_s[i + 1] = shear_stress(sigma)  # eq. 14
        s_xy[i + 1] = sigma[..., 0, 1]
    return ShearHistory(dt * np.arange(steps + 1), tau_s, s_xy)



def terminal_shear_stress(eta, n, sigma_y, gamma_dot, flow_rule: str = "paper"):
    """Terminal eq.-14 shear stress of simple shear at rate gamma_dot (b_e ~ I limit).
    Paper: sigma_y + eta gamma_dot^n (eq. 7); yue2015: sigma_y/sqrt(3) + eta gamma_dot^n / 2^((n+1)/2)
    (with the Simo approximation the terminal plastic rate is sqrt(2)/c gamma_dot)."""
    r = get_flow_rule(flow_rule)
    rate = SQRT2 / r.c * np.asarray(gamma_dot, dtype=float)  # terminal plastic rate
    return (r.beta * np.asarray(sigma_y) + eta * rate ** np.asarray(n)) / (r.alpha * SQRT2)

