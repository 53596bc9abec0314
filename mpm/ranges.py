"""What the forward model accepts: densities, discretisations, and materials beyond the paper's material space.

The paper's material space (section 3.1) is where estimation searches.  A single simulation may go
beyond it, up to 100 times its bounds; extreme values (eta = 1e30 Pa s^n) make the solver crawl and are
refused.
"""
from __future__ import annotations

import math

DENSITY_RANGE_KG_M3 = (300.0, 5000.0)
CELL_MM_RANGE = (0.2, 10.0)  # MPM cell width in mm (0.2 mm: about the particle budget of a 70 x 70 mm box)
PPC_RANGE = (1, 4)  # particles per cell per axis
SLIP_RANGE_M = (0.0, 1.0)  # Navier slip length of floor and walls (0: sticking)
# elastic moduli kappa and mu (section 4.2: 1e4 and 1e3 Pa); the explicit time step shrinks as sqrt(modulus)
MODULUS_RANGE_PA = (1e2, 1e6)
# accepted for one simulation (SI): eta in Pa s^n, n dimensionless, sigma_y in Pa
ETA_LIMIT = 3000.0
N_RANGE_SIMULABLE = (0.1, 2.0)  # n > 1 (shear-thickening) is outside the paper's space: simulated, with a warning
SIGMA_Y_LIMIT = 4000.0


def check_within(value, bounds: tuple, unit: str, what: str) -> float:
    """``value`` as a float if it is a finite number within ``bounds`` (lo, hi, in ``unit``), else a one-line
    ValueError naming ``what`` and the accepted range."""
    lo, hi = bounds
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{what} {value!r} is not a number of {unit}") from None
    if not (math.isfinite(v) and lo <= v <= hi):
        raise ValueError(f"{what} {v:g} {unit} lies outside the accepted range {lo:g}..{hi:g} {unit}")
    return v


def check_density(density: float, what: str = "density") -> float:
    """``density`` as a float in kg/m^3 if it is a finite number within ``DENSITY_RANGE_KG_M3`` (300..5000
    kg/m^3), else a one-line ValueError naming ``what`` and the accepted range.

    The one rule for a density: the dam-break scene (every simulation), ``settings.xml`` of an experiment folder
    and the ``--density`` options all call it (docs/user-guide.md, "What happens when...")."""
    return check_within(density, DENSITY_RANGE_KG_M3, "kg/m^3", what)


def check_cell_mm(cell_mm, what: str = "cell_mm") -> float:
    """The MPM cell width in mm within ``CELL_MM_RANGE`` (:func:`check_within`)."""
    return check_within(cell_mm, CELL_MM_RANGE, "mm", what)


def check_modulus(value, what: str) -> float:
    """An elastic modulus in Pa within ``MODULUS_RANGE_PA`` (:func:`check_within`)."""
    return check_within(value, MODULUS_RANGE_PA, "Pa", what)


def check_ppc(ppc, what: str = "ppc") -> int:
    """``ppc`` as an int if it is a whole number within ``PPC_RANGE``, else a one-line ValueError."""
    lo, hi = PPC_RANGE
    if isinstance(ppc, bool) or not isinstance(ppc, (int, float)) or ppc != int(ppc) or not lo <= ppc <= hi:
        raise ValueError(f"{what}={ppc!r} must be a whole number of particles per cell per axis within {lo}..{hi}")
    return int(ppc)


def check_simulable(eta: float, n: float, sigma_y: float) -> None:
    """ValueError when a (positive, finite) material lies beyond what the solver simulates in reasonable time."""
    lo, hi = N_RANGE_SIMULABLE
    for name, value, ok, accepted in (
        ("eta", eta, eta <= ETA_LIMIT, f"eta <= {ETA_LIMIT:g} Pa s^n"),
        ("n", n, lo <= n <= hi, f"{lo:g} <= n <= {hi:g}"),
        ("sigma_y", sigma_y, sigma_y <= SIGMA_Y_LIMIT, f"sigma_y <= {SIGMA_Y_LIMIT:g} Pa"),
    ):
        if not ok:
            raise ValueError(f"{name}={value:g} lies beyond what the solver simulates in reasonable time "
                             f"(accepted: {accepted})")
