"""Closed-form Hessian of the plane-Poiseuille loss at M~ = M (eqs. 29-42).

H = 2 int_0^L G(y) G(y)^T dy with G = d v_x / d(eta, n, sigma_y) (eq. 29). With the plug
half-width l = sigma_y/P, the gap D = L - l, the wall "rate" W = P D / eta and s = (y - l)/D,
the profile is v = n S (1 - s^p), S = W^p eta / (P (n+1)), p = (n+1)/n, and

    dv/deta   = A_eta (1 - s^p)
    dv/dn     = A_n (1 - s^p) + B_n s^p ln s
    dv/dsigma = A_sigma (1 - s^(1/n))            (s = 0 on the plug)

The paper factors H = L^3 H~ (eq. 30) and prints A/L, B/L (eqs. 37-39); here the unfactored
coefficients are used, which is the same matrix. Every entry is checked against sympy in
:mod:`poiseuille.derivation` and against finite differences + quadrature in the tests. The
paper's printed C5 (eq. 42) is wrong; see docs/method/errata.md.
"""
from __future__ import annotations

import numpy as np

from poiseuille.flow import plug_half_width


def constants(n):
    """The integrals C1..C6 over the sheared zone (eqs. 40-42, C5 corrected), as a tuple of arrays."""
    n = np.asarray(n, dtype=float)
    c1 = (1 + n) ** 2 / ((1 + 2 * n) * (2 + 3 * n))  # eq. 40: int (1-s^p)^2 = 2 C1
    c2 = n**2 * (3 + 5 * n) * (1 + n) / ((1 + 2 * n) ** 2 * (2 + 3 * n) ** 2)  # eq. 40: int (1-s^p) s^p ln s = -C2
    c3 = (2 + 3 * n) / (2 * (1 + n) * (1 + 2 * n))  # eq. 41: int (1-s^p)(1-s^(1/n)) = C3
    c4 = (n / (2 + 3 * n)) ** 3  # eq. 41: int (s^p ln s)^2 = 2 C4
    c5 = n**2 * (3 + 4 * n) / (4 * (1 + n) ** 2 * (1 + 2 * n) ** 2)  # eq. 42 (corrected): int s^p ln s (1-s^(1/n)) = -C5
    c6 = 1 / ((1 + n) * (2 + n))  # eq. 42: int (1-s^(1/n))^2 = 2 C6
    return c1, c2, c3, c4, c5, c6


def coefficients(eta, n, sigma_y, P, L):
    """(A_eta, A_n, B_n, A_sigma, l, D, flowing) of the velocity derivatives (eqs. 37-39 times L).

    Where P*L <= sigma_y nothing flows: the coefficients are 0 and ``flowing`` is False.
    """
    eta, n, sigma_y, P, L = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (eta, n, sigma_y, P, L)))
    l = plug_half_width(sigma_y, P)
    gap = L - l
    flowing = gap > 0
    wall_excess = np.where(flowing, P * L - sigma_y, eta)  # P L - sigma_y, dummy where no flow
    log_w = np.log(wall_excess) - np.log(eta)  # ln W, W = (P L - sigma_y)/eta = P D / eta
    p = (n + 1) / n
    S = np.exp(p * log_w) * eta / (P * (n + 1))
    a_eta = -S / eta  # eq. 37 (times L)
    a_n = S * (1 / (n + 1) - log_w / n)  # eq. 38 (times L)
    b_n = S / n  # eq. 39 (times L)
    a_sigma = -np.exp(log_w / n) / P  # eq. 37 (times L)
    zero = np.zeros_like(S)
    a_eta, a_n, b_n, a_sigma = (np.where(flowing, c, zero) for c in (a_eta, a_n, b_n, a_sigma))
    return a_eta, a_n, b_n, a_sigma, np.minimum(l, L), np.where(flowing, gap, 0.0), flowing


def hessian(eta, n, sigma_y, P, L):
    """Hessian H^PP of the plane-Poiseuille loss w.r.t. (eta, n, sigma_y) at M~ = M, shape (..., 3, 3).

    All arguments broadcast; units are whatever consistent system they are given in (SI in this
    package: Pa s^n, -, Pa, Pa/m, m). Zero where P*L <= sigma_y (no flow, flat loss).
    """
    a_e, a_n, b_n, a_s, l, d, _ = coefficients(eta, n, sigma_y, P, L)
    c1, c2, c3, c4, c5, c6 = constants(np.broadcast_to(np.asarray(n, dtype=float), l.shape))
    h = np.empty(l.shape + (3, 3))
    h[..., 0, 0] = 2 * a_e**2 * l + 4 * a_e**2 * d * c1  # eq. 31
    h[..., 0, 1] = 2 * a_e * a_n * l + 2 * d * (2 * a_e * a_n * c1 - a_e * b_n * c2)  # eq. 32
    h[..., 0, 2] = 2 * a_e * a_s * l + 2 * d * a_e * a_s * c3  # eq. 33
    h[..., 1, 1] = 2 * a_n**2 * l + 4 * d * (b_n**2 * c4 - a_n * b_n * c2 + a_n**2 * c1)  # eq. 34
    h[..., 1, 2] = 2 * a_n * a_s * l + 2 * d * (a_n * a_s * c3 - b_n * a_s * c5)  # eq. 35
    h[..., 2, 2] = 2 * a_s**2 * l + 4 * d * a_s**2 * c6  # eq. 36
    h[..., 1, 0] = h[..., 0, 1]
    h[..., 2, 0] = h[..., 0, 2]
    h[..., 2, 1] = h[..., 1, 2]
    return h
