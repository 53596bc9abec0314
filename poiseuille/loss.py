"""Plane-Poiseuille loss between two materials (eq. 26), by piecewise Gauss-Legendre quadrature.

L^PP(M~, M; P, L) = int_0^L (v_M~(y) - v_M(y))^2 dy. The two profiles are constant on their
plugs [0, l] and behave like (y - l)^((n+1)/n) right past them, so the integrand has kinks
at l~ and l. The integral is split there: the part where both materials are plugs is exact,
the other two pieces use Gauss-Legendre nodes after the substitution y = a + (b - a) t^2,
which removes the low-order kink at the left end of each piece (error ~ N^-(4p+2)).
"""
from __future__ import annotations

import numpy as np

from mpm.params import material_array

from .flow import velocity

_NODES = 48
_GL_T, _GL_W = np.polynomial.legendre.leggauss(_NODES)
_GL_T = 0.5 * (_GL_T + 1.0)  # nodes on [0, 1]
_GL_W = 0.5 * _GL_W


def _piece(lo, hi, m1, m2, P, L):
    """int_lo^hi (v1 - v2)^2 dy with y = lo + (hi - lo) t^2 (kink at lo), vectorised."""
    span = (hi - lo)[..., None]
    t = _GL_T
    y = lo[..., None] + span * t * t
    P, L = P[..., None], L[..., None]
    d = velocity(y, *(x[..., None] for x in m1), P, L) - velocity(y, *(x[..., None] for x in m2), P, L)
    return np.sum(_GL_W * 2.0 * span * t * d * d, axis=-1)


def loss(m_tilde, m, P, L):
    """Plane-Poiseuille loss L^PP(M~, M; P, L) of eq. 26 (units of velocity^2 * length).

    ``m_tilde`` and ``m`` are (eta, n, sigma_y) as arrays (..., 3) or Material-like objects;
    everything broadcasts. Near M~ = M it equals 0.5 dM^T H dM with H from :func:`hessian`.
    """
    a1 = np.moveaxis(material_array(m_tilde), -1, 0)
    a2 = np.moveaxis(material_array(m), -1, 0)
    e1, n1, s1, e2, n2, s2, P, L = np.broadcast_arrays(*a1, *a2, np.asarray(P, float), np.asarray(L, float))
    l1 = np.clip(s1 / P, 0.0, L)
    l2 = np.clip(s2 / P, 0.0, L)
    a = np.minimum(l1, l2)
    b = np.maximum(l1, l2)
    zero = np.zeros_like(L)
    plug = a * (velocity(zero, e1, n1, s1, P, L) - velocity(zero, e2, n2, s2, P, L)) ** 2  # eq. 26 on [0, a]
    m1, m2 = (e1, n1, s1), (e2, n2, s2)
    return plug + _piece(a, b, m1, m2, P, L) + _piece(b, L, m1, m2, P, L)  # eq. 26
