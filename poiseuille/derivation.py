"""Symbolic derivation (sympy) of the plane-Poiseuille velocity derivatives G(y) and the Hessian.

Starting from nothing but the velocity profile of eqs. 23-25, this module

1. differentiates v_x(y) w.r.t. (eta, n, sigma_y) at fixed y (eq. 27) and shows that, with
   s = (y - l)/(L - l), the three derivatives are A_eta (1 - s^p), A_n (1 - s^p) + B_n s^p ln s
   and A_sigma (1 - s^(1/n)), and that the plug derivative is their value at s = 0;
2. integrates every product of those three shape functions over s in [0, 1] and compares the
   results with the constants C1..C6 (eqs. 40-42) used by :mod:`poiseuille.hessian`, and with
   the constants as printed in the paper (one of which, C5, is wrong);
3. assembles H = 2 [l g g^T + (L - l) int G G^T ds] (eq. 29) and checks that it equals the
   closed-form entries of eqs. 31-36 symbolically, then numerically against the numpy code.

``check()`` runs everything and returns one :class:`Check` per claim (tests assert all pass).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import sympy as sp

eta, n, sigma_y, P, D, s = sp.symbols("eta n sigma_y P D s", positive=True)
L, y = sp.symbols("L y", positive=True)
A_eta, A_n, B_n, A_sigma = sp.symbols("A_eta A_n B_n A_sigma", real=True)
C = sp.symbols("C1:7", positive=True)

p = (n + 1) / n
l = sigma_y / P


def velocity_expr():
    """v_x in the sheared zone l <= y <= L (eqs. 23-25) and on the plug (eq. 24), as sympy expressions."""
    sheared = n / (n + 1) * (P / eta) ** (1 / n) * ((L - l) ** p - (y - l) ** p)
    plug = n / (n + 1) * (P / eta) ** (1 / n) * (L - l) ** p
    return sheared, plug


def coefficient_exprs():
    """A_eta, A_n, B_n, A_sigma (eqs. 37-39 multiplied by L) in terms of eta, n, sigma_y, P and D = L - l."""
    W = P * D / eta
    S = W**p * eta / (P * (n + 1))
    return {A_eta: -S / eta, A_n: S * (1 / (n + 1) - sp.log(W) / n), B_n: S / n, A_sigma: -(W ** (1 / n)) / P}


# Shape functions of the sheared zone, in s = (y - l)/D.
SHAPES = (1 - s**p, s**p * sp.log(s), 1 - s ** (1 / n))
# G = COEFF * SHAPES (rows: d/d eta, d/dn, d/d sigma_y).
COEFF = sp.Matrix([[A_eta, 0, 0], [A_n, B_n, 0], [0, 0, A_sigma]])


def closed_constants():
    """C1..C6 as implemented (eqs. 40-42 with C5 corrected)."""
    return (
        (1 + n) ** 2 / ((1 + 2 * n) * (2 + 3 * n)),
        n**2 * (3 + 5 * n) * (1 + n) / ((1 + 2 * n) ** 2 * (2 + 3 * n) ** 2),
        (2 + 3 * n) / (2 * (1 + n) * (1 + 2 * n)),
        (n / (2 + 3 * n)) ** 3,
        n**2 * (3 + 4 * n) / (4 * (1 + n) ** 2 * (1 + 2 * n) ** 2),
        1 / ((1 + n) * (2 + n)),
    )


def printed_constants():
    """C1..C6 exactly as printed in the paper (eqs. 40-42); C5 carries a misprint."""
    return (
        (1 + n) ** 2 / ((1 + 2 * n) * (2 + 3 * n)),
        n**2 * (3 + 5 * n) * (1 + n) / ((1 + 2 * n) ** 2 * (2 + 3 * n) ** 2),
        (2 + 3 * n) / (2 * (1 + n) * (1 + 2 * n)),
        (n / (2 + 3 * n)) ** 3,
        n**2 * (3 + 4 * n) / (4 * (1 + 2 * n) ** 2 * (1 + 2 * n) ** 2),
        1 / ((1 + n) * (2 + n)),
    )


# Which integral each constant stands for: (shape i, shape j, factor) with int_0^1 f_i f_j ds = factor * C_k.
CONSTANT_INTEGRALS = ((0, 0, 2), (0, 1, -1), (0, 2, 1), (1, 1, 2), (1, 2, -1), (2, 2, 2))


def closed_form_entries(consts=C):
    """Eqs. 31-36 in the unfactored form (H = L^3 H~ with A, B times L), in the abstract symbols."""
    c1, c2, c3, c4, c5, c6 = consts
    ae, an, bn, asg = A_eta, A_n, B_n, A_sigma
    return sp.Matrix(
        [
            [2 * ae**2 * l + 4 * ae**2 * D * c1, 2 * ae * an * l + 2 * D * (2 * ae * an * c1 - ae * bn * c2), 2 * ae * asg * l + 2 * D * ae * asg * c3],
            [0, 2 * an**2 * l + 4 * D * (bn**2 * c4 - an * bn * c2 + an**2 * c1), 2 * an * asg * l + 2 * D * (an * asg * c3 - bn * asg * c5)],
            [0, 0, 2 * asg**2 * l + 4 * D * asg**2 * c6],
        ]
    )


def _is_zero(expr) -> bool:
    expr = sp.expand_power_base(expr, force=True)
    expr = sp.expand_log(expr, force=True)
    expr = sp.powsimp(sp.expand(expr), force=True)
    return sp.simplify(expr) == 0


@dataclass(frozen=True)
class Check:
    """One claim: ``kind`` is "derivation" (must hold) or "paper" (does the printed paper agree?)."""

    name: str
    ok: bool
    detail: str
    kind: str = "derivation"


@lru_cache(maxsize=1)
def derive():
    """Return (G sheared in s, G on the plug, shape-integral matrix, H assembled) as sympy objects."""
    sheared, plug = velocity_expr()
    params = (eta, n, sigma_y)
    to_s = {L: l + D, y: l + D * s}
    g_sheared = [sp.diff(sheared, v).subs(to_s) for v in params]  # eq. 27
    g_plug = [sp.diff(plug, v).subs({L: l + D}) for v in params]  # eq. 27 on the plug
    gram = sp.zeros(3, 3)
    for i in range(3):
        for j in range(i, 3):
            gram[i, j] = gram[j, i] = sp.factor(sp.simplify(sp.integrate(sp.expand(SHAPES[i] * SHAPES[j]), (s, 0, 1), conds="none")))
    g0 = sp.Matrix([A_eta, A_n, A_sigma])
    h = 2 * (l * g0 * g0.T + D * COEFF * gram * COEFF.T)  # eq. 29, split into plug + sheared zone
    return g_sheared, g_plug, gram, h


def derived_hessian_function():
    """Numeric function H(eta, n, sigma_y, P, L) from the sympy derivation (for cross-checks)."""
    _, _, _, h = derive()
    concrete = h.subs(coefficient_exprs()).subs(D, L - l)
    f = sp.lambdify((eta, n, sigma_y, P, L), concrete, "numpy")
    return lambda *a: np.array(f(*(float(v) for v in a)), dtype=float)


def check(points=None) -> list[Check]:
    """Run every symbolic and numeric check; each Check says what was confirmed."""
    from .hessian import hessian

    g_sheared, g_plug, gram, h = derive()
    coeffs = coefficient_exprs()
    out = []
    model = COEFF * sp.Matrix(SHAPES)
    for name, g, m in zip(("d/deta", "d/dn", "d/dsigma_y"), g_sheared, model):
        out.append(Check(f"G {name} (sheared)", _is_zero(g - m.subs(coeffs)), f"{name} v = {m}"))
    for name, g, a in zip(("d/deta", "d/dn", "d/dsigma_y"), g_plug, (A_eta, A_n, A_sigma)):
        out.append(Check(f"G {name} (plug)", _is_zero(g - a.subs(coeffs)), f"{name} v = {a} on the plug (s = 0)"))
    closed, printed = closed_constants(), printed_constants()
    for k, (i, j, factor) in enumerate(CONSTANT_INTEGRALS):
        integral = gram[i, j]
        ok = sp.simplify(integral - factor * closed[k]) == 0
        out.append(Check(f"C{k + 1}", ok, f"int f{i}f{j} ds = {integral} = {factor}*C{k + 1}"))
        paper_ok = sp.simplify(integral - factor * printed[k]) == 0
        out.append(Check(f"C{k + 1} as printed", paper_ok, f"printed C{k + 1} = {printed[k]}", kind="paper"))
    closed_h = closed_form_entries(closed)
    entries = ("H_eta_eta", "H_eta_n", "H_eta_sigma", "H_n_n", "H_n_sigma", "H_sigma_sigma")
    idx = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
    for name, (i, j) in zip(entries, idx):
        out.append(Check(f"{name} symbolic", sp.simplify(h[i, j] - closed_h[i, j]) == 0, f"eq. 29 assembled = eqs. 31-36"))
    f = derived_hessian_function()
    if points is None:
        points = [(3.0, 0.7, 2.0, 2500.0, 0.01), (0.05, 0.3, 12.0, 2500.0, 0.005), (25.0, 1.0, 39.0, 2500.0, 0.0157), (1e-3, 0.45, 0.0, 2500.0, 0.002)]
    for name, (i, j) in zip(entries, idx):
        worst = 0.0
        for pt in points:
            ref = f(*pt)
            got = hessian(*pt)
            scale = np.sqrt(abs(ref[i, i] * ref[j, j]))
            worst = max(worst, abs(got[i, j] - ref[i, j]) / scale)
        out.append(Check(f"{name} numeric", worst < 1e-10, f"max |numpy - sympy| / sqrt(H_ii H_jj) = {worst:.2e}"))
    return out


if __name__ == "__main__":  # pragma: no cover - manual report
    for c in check():
        status = "ok  " if c.ok else ("MISPRINT" if c.kind == "paper" else "FAIL")
        print(f"{status:8s} {c.name:22s} {c.detail}")
