"""The sympy derivation confirms every closed-form Hessian entry and constant, and pins the paper's C5 misprint."""
import pytest
import sympy as sp

from poiseuille import derivation


@pytest.fixture(scope="module")
def checks():
    return derivation.check()


def test_every_derivation_check_passes(checks):
    out = checks
    failed = [c for c in out if c.kind == "derivation" and not c.ok]
    assert not failed, failed
    names = {c.name for c in out if c.kind == "derivation"}
    for entry in ("H_eta_eta", "H_eta_n", "H_eta_sigma", "H_n_n", "H_n_sigma", "H_sigma_sigma"):
        assert f"{entry} symbolic" in names and f"{entry} numeric" in names
    assert {f"C{k}" for k in range(1, 7)} <= names


def test_only_printed_c5_is_wrong(checks):
    out = checks
    wrong = sorted(c.name for c in out if c.kind == "paper" and not c.ok)
    assert wrong == ["C5 as printed"]


def test_c5_integral_value():
    n = derivation.n
    s = derivation.s
    # n = 1: int_0^1 s^2 ln s (1 - s) ds = -1/9 + 1/16 = -7/144
    val = sp.integrate((s**2 * sp.log(s) * (1 - s)), (s, 0, 1))
    assert val == sp.Rational(-7, 144)
    assert derivation.closed_constants()[4].subs(n, 1) == sp.Rational(7, 144)
    assert derivation.printed_constants()[4].subs(n, 1) == sp.Rational(7, 324)
