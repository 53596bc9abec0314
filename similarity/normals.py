"""Loss normals of dam-break setups (Algorithm 2) and the perpendicularity score S_p (section 6).

For a material M and a setup S: (P, L) = Theta(M, S), H = plane-Poiseuille Hessian at (M; P, L)
(eqs. 29-42), and the loss normal is the direction of steepest loss growth in the *normalised*
material space [0, 1]^3. With A = diag(extents) and u the normalised coordinates (M = lower + A u),
the loss Hessian in u is A H A, so

* ``variant="scaled"`` (our definition): q = top eigenvector of A H A. Unit-independent: changing
  the unit system multiplies A H A by a positive constant.
* ``variant="reference"`` (what the authors' implementation did): v = top eigenvector of the
  unscaled Hessian in CGS units (dyn, cm, s), q = A v / |A v| with the CGS extents. This depends on
  the unit system (``units="si"`` gives the same recipe in SI). On the published records every
  variant selects the same second setups (tests/test_design.py).

Normals are unit vectors in the normalised space; their sign is arbitrary (scores use squares) and
fixed here so that the largest-magnitude component is positive. Where P L <= sigma_y nothing flows
in the plane-Poiseuille setup, the Hessian vanishes and the normal is NaN (candidate invalid).
"""
from __future__ import annotations

import numpy as np

from mpm.params import material_array
from poiseuille import hessian, loss
from surrogate.theta import ThetaMap, load

from .fd_hessian import canonical_sign
from .space import EXTENT, denormalize, normalize

VARIANTS = ("scaled", "reference")
P_SEARCH = 2500.0  # Pa/m: P of the plane-Poiseuille setups matched to dam-break landscapes (only P L matters, section 5.5)
# SI -> CGS factors for (eta, n, sigma_y) and the conversions of P [Pa/m -> dyn/cm^3] and L [m -> cm]
_CGS_PARAM = np.array([10.0, 1.0, 10.0])
_CGS_P = 0.1
_CGS_L = 100.0


def top_eigenvector(h) -> np.ndarray:
    """Unit eigenvector (..., 3) of the largest eigenvalue of symmetric matrices (..., 3, 3).

    Each matrix is divided by its trace first (harmless, avoids under/overflow); the sign is fixed so
    that the largest-magnitude component is positive. NaN where the matrix is zero.
    """
    h = np.asarray(h, dtype=float)
    tr = np.trace(h, axis1=-2, axis2=-1)
    ok = tr > 0
    safe = np.where(ok[..., None, None], h / np.where(ok, tr, 1.0)[..., None, None], np.eye(3))
    _, vecs = np.linalg.eigh(safe)
    return np.where(ok[..., None], canonical_sign(vecs[..., :, -1]), np.nan)


def normals_at(params, P, L, variant: str = "scaled", units: str = "cgs") -> np.ndarray:
    """Loss normals (..., 3) in the normalised space for materials ``params`` (..., 3) SI at (P, L) SI."""
    params = np.asarray(params, dtype=float)
    eta, n, sig = params[..., 0], params[..., 1], params[..., 2]
    if variant == "scaled":
        h = hessian(eta, n, sig, P, L)
        return top_eigenvector(h * EXTENT[:, None] * EXTENT[None, :])  # A H A
    if variant == "reference":
        if units == "cgs":
            h = hessian(eta * 10.0, n, sig * 10.0, np.asarray(P) * _CGS_P, np.asarray(L) * _CGS_L)
            extent = EXTENT * _CGS_PARAM
        elif units == "si":
            h, extent = hessian(eta, n, sig, P, L), EXTENT
        else:
            raise ValueError(f"units='{units}' must be 'cgs' or 'si'")
        v = top_eigenvector(h)
        q = v * extent  # A v
        return q / np.linalg.norm(q, axis=-1, keepdims=True)
    raise ValueError(f"variant='{variant}' must be one of {', '.join(VARIANTS)}")


def loss_normals(material, width_mm, height_mm, theta="reference", variant: str = "scaled", units: str = "cgs"):
    """Algorithm 2 for arrays of setups: returns (normals (k, 3), valid (k,)), valid meaning P L > sigma_y."""
    theta = theta if isinstance(theta, ThetaMap) else load(theta)
    m = material_array(material)
    P, L = theta.pl(m[..., 0], m[..., 1], m[..., 2], width_mm, height_mm)
    valid = P * L > m[..., 2]
    q = normals_at(m, P, L, variant, units)
    return np.where(valid[..., None], q, np.nan), valid


def loss_normal(material, setup, theta="reference", variant: str = "scaled", units: str = "cgs") -> np.ndarray:
    """Loss normal (3,) of one dam-break setup; ValueError when the setup gives no Poiseuille flow."""
    q, valid = loss_normals(material, setup.width_mm, setup.height_mm, theta, variant, units)
    if not bool(valid):
        raise ValueError(
            f"setup {setup} gives no plane-Poiseuille flow for this material (Theta's P*L <= sigma_y), "
            "so its loss normal is undefined"
        )
    return q


def perpendicularity(previous, q) -> np.ndarray:
    """S_p = sqrt(sum_i (q_i . q)^2) (section 6) for previous normals (m, 3) and candidates (..., 3)."""
    previous = np.atleast_2d(np.asarray(previous, dtype=float))
    dots = np.asarray(q, dtype=float) @ previous.T
    return np.sqrt(np.sum(dots * dots, axis=-1))


def poiseuille_landscape(material, offsets, c_pa: float) -> np.ndarray:
    """The plane-Poiseuille loss (eq. 26) around ``material`` at offsets (k, 3) in the normalised space, for the
    wall stress C = P L with P = ``P_SEARCH``: the counterpart of a dam-break loss landscape (docs/landscapes.md)."""
    m = material_array(material)
    m_tilde = denormalize(normalize(m) + np.asarray(offsets, dtype=float))
    return loss(m_tilde, m, P_SEARCH, c_pa / P_SEARCH)  # eq. 26
