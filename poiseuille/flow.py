"""Steady Herschel-Bulkley plane-Poiseuille flow (paper section 5.4, eqs. 23-25).

Two no-slip plates at y = +-L, a constant pressure gradient P along them. The shear stress
is P*|y|; where it stays below the yield stress the material moves as a rigid plug of
half-width l = sigma_y / P, outside it shears. All functions broadcast over every argument
and work in any consistent unit system (the package uses SI: Pa s^n, -, Pa, Pa/m, m).
When P*L <= sigma_y the wall stress never reaches the yield stress and nothing flows.
"""
from __future__ import annotations

import numpy as np


def plug_half_width(sigma_y, P):
    """Half-width l = sigma_y / P of the unyielded plug (section 5.4)."""
    return np.asarray(sigma_y, dtype=float) / np.asarray(P, dtype=float)


def exponent(n):
    """Profile exponent p = (n + 1) / n of eqs. 24-25."""
    n = np.asarray(n, dtype=float)
    return (n + 1.0) / n


def max_velocity(eta, n, sigma_y, P, L):
    """Plug (maximum) velocity v_max = n/(n+1) (P/eta)^(1/n) (L - l)^((n+1)/n); 0 without flow."""
    eta, n, sigma_y, P, L = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (eta, n, sigma_y, P, L)))
    gap = np.maximum(L - plug_half_width(sigma_y, P), 0.0)
    return n / (n + 1.0) * (P / eta) ** (1.0 / n) * gap ** exponent(n)  # eq. 24


def decay_ratio(y, eta, n, sigma_y, P, L):
    """zeta(y) = 1 - (max(0, |y| - l) / (L - l))^((n+1)/n) for |y| <= L; 0 where nothing flows."""
    y, eta, n, sigma_y, P, L = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (y, eta, n, sigma_y, P, L)))
    l = plug_half_width(sigma_y, P)
    gap = L - l
    flowing = gap > 0
    safe_gap = np.where(flowing, gap, 1.0)
    zeta = 1.0 - (np.maximum(np.abs(y) - l, 0.0) / safe_gap) ** exponent(n)  # eq. 25
    return np.where(flowing, zeta, 0.0)


def velocity(y, eta, n, sigma_y, P, L):
    """Velocity v_x(y) along the plates at distance y from the mid-plane (|y| <= L), eq. 23.

    Written as n/(n+1) (P/eta)^(1/n) [(L-l)^p - max(0, |y|-l)^p], which is v_max * zeta (eqs. 23-25)
    without the division by L - l, so it stays accurate right above the no-flow limit L -> l.
    """
    y, eta, n, sigma_y, P, L = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (y, eta, n, sigma_y, P, L)))
    l = plug_half_width(sigma_y, P)
    p = exponent(n)
    gap = np.maximum(L - l, 0.0)
    sheared = np.minimum(np.maximum(np.abs(y) - l, 0.0), gap)
    return n / (n + 1.0) * (P / eta) ** (1.0 / n) * (gap ** p - sheared ** p)  # eqs. 23-25
