"""The conversion map Theta(M, S) -> S^PP = (P, L) (paper section 5.5), stored as data.

A map is 66 coefficients of a second-order polynomial in ten features of the material and the
dam-break setup (the five inputs and their reciprocals), evaluated in SI with lengths in metres:

    z = [eta, n, sigma_y, H, W, 1/eta, 1/n, 1/(sigma_y + eps), 1/H, 1/W]
    r = theta_0 + sum_i theta_i z_i + sum over monomials z_i z_j (i <= j) of theta_ij z_i z_j / (e_i! e_j!)

The monomials are ordered by the product of the primes (2, 3, 5, ..., 29) that label their
variables, the layout of the authors' published map (our own description of it). The rate r is
mapped onto a wall shear stress C = 5 + r (500 - 5) Pa, and S^PP = (P, L) = (2500 Pa/m, C / P).

``load("reference")`` returns the authors' published coefficients, shipped as package data
with attribution (CC BY-NC 4.0); ``load("fitted")`` our own map, fitted to MPM loss landscapes by
:mod:`surrogate.theta_fit`; ``load(path)`` reads a map saved by :meth:`ThetaMap.save`.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import lru_cache
from importlib import resources
from math import factorial
from pathlib import Path

import numpy as np
from sklearn.preprocessing import PolynomialFeatures

from mpm.params import material_array, setup_arrays

FORMAT = "virheometry-theta/1"
PRIMES = np.array([2, 3, 5, 7, 11, 13, 17, 19, 23, 29])
FEATURE_NAMES = ("eta", "n", "sigma_y", "H", "W", "1/eta", "1/n", "1/(sigma_y+eps)", "1/H", "1/W")
N_COEFFS = 66


@lru_cache(maxsize=1)
def monomial_powers() -> np.ndarray:
    """Exponents (66, 10) of the monomials in the stored order: by degree, then by prime product."""
    powers = PolynomialFeatures(degree=2).fit(np.ones((1, len(PRIMES)))).powers_
    key = np.prod(PRIMES.astype(float) ** powers, axis=1)
    order = np.lexsort((key, powers.sum(axis=1)))
    out = powers[order]
    out.setflags(write=False)
    return out


def monomial_weights() -> np.ndarray:
    """1 / prod(e_i!) per monomial: 1/2 for squares, 1 for everything else (the 1/k! Taylor factor)."""
    return 1.0 / np.prod(np.vectorize(factorial)(monomial_powers()), axis=1)


def base_features(eta, n, sigma_y, height_m, width_m, sigma_eps=1e-4) -> np.ndarray:
    """The ten features z (..., 10), SI with lengths in metres (eps shifts only 1/sigma_y)."""
    x = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (eta, n, sigma_y, height_m, width_m)))
    e, nn, s, h, w = x
    return np.stack([e, nn, s, h, w, 1 / e, 1 / nn, 1 / (s + sigma_eps), 1 / h, 1 / w], axis=-1)


def design_matrix(eta, n, sigma_y, height_m, width_m, sigma_eps=1e-4) -> np.ndarray:
    """All 66 weighted monomials (..., 66) in the stored order, e.g. for fitting a new map."""
    z = base_features(eta, n, sigma_y, height_m, width_m, sigma_eps)
    flat = z.reshape(-1, z.shape[-1])
    poly = PolynomialFeatures(degree=2).fit(flat[:1])
    cols = {tuple(p): i for i, p in enumerate(poly.powers_)}
    perm = [cols[tuple(p)] for p in monomial_powers()]
    out = poly.transform(flat)[:, perm] * monomial_weights()
    return out.reshape(z.shape[:-1] + (N_COEFFS,))


@dataclass(frozen=True, eq=False)
class ThetaMap:
    """A conversion map: 66 coefficients plus the constants of the output mapping."""

    theta: np.ndarray
    name: str = "unnamed"
    attribution: str = ""
    sigma_eps: float = 1e-4
    c_extent_pa: tuple = (5.0, 500.0)
    p_pa_per_m: float = 2500.0
    _linear: np.ndarray = field(init=False, repr=False)
    _quadratic: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        theta = np.asarray(self.theta, dtype=float).ravel()
        if theta.shape != (N_COEFFS,) or not np.all(np.isfinite(theta)):
            raise ValueError(f"Theta map '{self.name}' needs {N_COEFFS} finite coefficients, got {theta.size}")
        theta.setflags(write=False)
        object.__setattr__(self, "theta", theta)
        # r = theta_0 + b . z + 1/2 z^T Q z  with Q symmetric: the same polynomial, evaluated fast
        powers = monomial_powers()
        b = np.zeros(len(PRIMES))
        q = np.zeros((len(PRIMES), len(PRIMES)))
        for coef, pw in zip(theta[1:], powers[1:]):
            idx = np.flatnonzero(pw)
            if pw.sum() == 1:
                b[idx[0]] = coef
            elif len(idx) == 1:  # square: weight 1/2 -> Q_ii = coef
                q[idx[0], idx[0]] = coef
            else:  # z_i z_j with weight 1 -> Q_ij = Q_ji = coef
                q[idx[0], idx[1]] = q[idx[1], idx[0]] = coef
        object.__setattr__(self, "_linear", b)
        object.__setattr__(self, "_quadratic", q)

    def rate(self, eta, n, sigma_y, width_mm, height_mm) -> np.ndarray:
        """The polynomial's value r (the rate of C inside its extent)."""
        z = base_features(eta, n, sigma_y, np.asarray(height_mm, float) * 1e-3, np.asarray(width_mm, float) * 1e-3, self.sigma_eps)
        return self.theta[0] + z @ self._linear + 0.5 * np.einsum("...i,ij,...j->...", z, self._quadratic, z)

    def wall_stress(self, eta, n, sigma_y, width_mm, height_mm) -> np.ndarray:
        """C = P L in Pa, the plane-Poiseuille wall shear stress."""
        lo, hi = self.c_extent_pa
        return lo + self.rate(eta, n, sigma_y, width_mm, height_mm) * (hi - lo)

    def pl(self, eta, n, sigma_y, width_mm, height_mm):
        """(P [Pa/m], L [m]) for arrays of materials and setups (broadcast)."""
        L = self.wall_stress(eta, n, sigma_y, width_mm, height_mm) / self.p_pa_per_m
        return np.full_like(L, self.p_pa_per_m), L

    def __call__(self, material, setup):
        """Theta(M, S) -> (P, L): ``material`` a Material or (..., 3) array, ``setup`` a Setup,
        a (width_mm, height_mm) pair of arrays (e.g. ``candidate_setups()``) or an (..., 2) array."""
        return self.pl(*np.moveaxis(material_array(material), -1, 0), *setup_arrays(setup))

    def to_dict(self) -> dict:
        return {
            "format": FORMAT,
            "name": self.name,
            "attribution": self.attribution,
            "inputs": "eta [Pa s^n], n [-], sigma_y [Pa], H [m], W [m] (height before width)",
            "features": "see surrogate/theta.py: prime-ordered degree-2 monomials of "
            "[eta, n, sigma_y, H, W, 1/eta, 1/n, 1/(sigma_y + sigma_eps), 1/H, 1/W], squares weighted 1/2",
            "output": "C = C_extent_Pa[0] + r (C_extent_Pa[1] - C_extent_Pa[0]); P = P_Pa_per_m; L = C / P [m]",
            "sigma_eps": self.sigma_eps,
            "C_extent_Pa": list(self.c_extent_pa),
            "P_Pa_per_m": self.p_pa_per_m,
            "theta": [float(t) for t in self.theta],
        }

    def save(self, path) -> Path:
        """Write the map as JSON (the format :func:`load` reads)."""
        path = Path(path)
        path.write_text(json.dumps(self.to_dict(), indent=1) + "\n")
        return path


def from_dict(d: dict, name: str = "unnamed") -> ThetaMap:
    if "theta" not in d:
        raise ValueError(f"Theta map '{name}' has no 'theta' coefficients")
    return ThetaMap(
        theta=np.asarray(d["theta"], dtype=float),
        name=str(d.get("name", name)),
        attribution=str(d.get("attribution", "")),
        sigma_eps=float(d.get("sigma_eps", 1e-4)),
        c_extent_pa=tuple(float(c) for c in d.get("C_extent_Pa", (5.0, 500.0))),
        p_pa_per_m=float(d.get("P_Pa_per_m", 2500.0)),
    )


PACKAGED = ("reference", "fitted")


@lru_cache(maxsize=8)
def _load_packaged(name: str) -> ThetaMap:
    text = resources.files("surrogate").joinpath(f"data/theta_{name}.json").read_text()
    return from_dict(json.loads(text), name)


def load(which="reference") -> ThetaMap:
    """``"reference"``: the authors' published map; ``"fitted"``: our map fitted to MPM landscapes
    (docs/landscapes.md gives the command that refits it); otherwise a path to a JSON file saved by ``save``."""
    if isinstance(which, ThetaMap):
        return which
    if str(which) in PACKAGED:
        return _load_packaged(str(which))
    path = Path(which)
    if not path.is_file():
        raise FileNotFoundError(f"Theta map file {path} not found (use 'reference', 'fitted' or a JSON file saved by ThetaMap.save)")
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"Theta map file {path} is not valid JSON: {exc}") from None
    if not isinstance(data, dict):
        raise ValueError(f"Theta map file {path} must hold a JSON object with a 'theta' list")
    return from_dict(data, path.stem)
