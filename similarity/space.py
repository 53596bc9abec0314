"""Material and setup spaces of the paper (section 3.1-3.3), in SI units (setups in mm).

``Material`` holds Herschel-Bulkley parameters, ``Setup`` a dam-break width x height.
The material space box (eta 1e-4..30 Pa s^n, n 0.3..1, sigma_y 0..40 Pa) is linearly
mapped onto the normalised space [0, 1]^3 used by CMA-ES and the loss normals.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Bounds of the paper's material space (SI), in the order (eta, n, sigma_y).
ETA_RANGE = (1e-4, 30.0)
N_RANGE = (0.3, 1.0)
SIGMA_Y_RANGE = (0.0, 40.0)
LOWER = np.array([ETA_RANGE[0], N_RANGE[0], SIGMA_Y_RANGE[0]])
UPPER = np.array([ETA_RANGE[1], N_RANGE[1], SIGMA_Y_RANGE[1]])
EXTENT = UPPER - LOWER

# Candidate dam-break setups: 20..70 mm in 1 mm steps for both width and height.
SETUP_RANGE_MM = (20, 70)


@dataclass(frozen=True)
class Material:
    """Herschel-Bulkley material: consistency eta [Pa s^n], power index n [-], yield stress sigma_y [Pa]."""

    eta: float
    n: float
    sigma_y: float

    def __post_init__(self):
        for name, value in (("eta", self.eta), ("n", self.n), ("sigma_y", self.sigma_y)):
            if not np.isfinite(value):
                raise ValueError(f"{name}={value} is not a finite number")
        if self.eta <= 0:
            raise ValueError(f"eta={self.eta} Pa s^n is unphysical: it must be > 0 (material space {ETA_RANGE[0]:g}..{ETA_RANGE[1]:g})")
        if self.n <= 0:
            raise ValueError(f"n={self.n} is unphysical: it must be > 0 (material space {N_RANGE[0]:g}..{N_RANGE[1]:g})")
        if self.sigma_y < 0:
            raise ValueError(f"sigma_y={self.sigma_y} Pa is unphysical: it must be >= 0 (material space {SIGMA_Y_RANGE[0]:g}..{SIGMA_Y_RANGE[1]:g})")

    def as_array(self) -> np.ndarray:
        return np.array([self.eta, self.n, self.sigma_y], dtype=float)

    @classmethod
    def from_array(cls, x) -> "Material":
        x = np.asarray(x, dtype=float)
        return cls(float(x[0]), float(x[1]), float(x[2]))

    @classmethod
    def parse(cls, text: str) -> "Material":
        """Parse 'ETA,N,SIGMA_Y' (SI)."""
        parts = [p.strip() for p in str(text).split(",")]
        if len(parts) != 3:
            raise ValueError(f"material '{text}' must be three numbers ETA,N,SIGMA_Y (Pa s^n, -, Pa)")
        try:
            values = [float(p) for p in parts]
        except ValueError:
            raise ValueError(f"material '{text}' must be three numbers ETA,N,SIGMA_Y (Pa s^n, -, Pa)") from None
        return cls(*values)

    def in_space(self) -> bool:
        x = self.as_array()
        return bool(np.all(x >= LOWER - 1e-12) and np.all(x <= UPPER + 1e-12))

    def check_in_space(self) -> "Material":
        """Raise ValueError naming the first parameter outside the paper's material space."""
        for name, value, (lo, hi), unit in (
            ("eta", self.eta, ETA_RANGE, " Pa s^n"),
            ("n", self.n, N_RANGE, ""),
            ("sigma_y", self.sigma_y, SIGMA_Y_RANGE, " Pa"),
        ):
            if not (lo - 1e-12 <= value <= hi + 1e-12):
                raise ValueError(f"{name}={value:g}{unit} lies outside the material space {lo:g}..{hi:g}{unit}")
        return self

    def to_dict(self) -> dict:
        return {"eta": self.eta, "n": self.n, "sigma_y": self.sigma_y}

    def stress(self, gamma_dot):
        """Herschel-Bulkley flow curve sigma = sigma_y + eta * gamma_dot^n (eq. 1), Pa."""
        return self.sigma_y + self.eta * np.asarray(gamma_dot, dtype=float) ** self.n


@dataclass(frozen=True)
class Setup:
    """Dam-break setup: initial cuboid width (along the flow) and height, in millimetres."""

    width_mm: float
    height_mm: float

    def __post_init__(self):
        for name, value in (("width_mm", self.width_mm), ("height_mm", self.height_mm)):
            if not np.isfinite(value) or value <= 0:
                raise ValueError(f"{name}={value} is unphysical: it must be > 0 mm (setup space {SETUP_RANGE_MM[0]}..{SETUP_RANGE_MM[1]} mm)")

    @classmethod
    def parse(cls, text: str) -> "Setup":
        """Parse 'WxH' in millimetres, e.g. '29x59'."""
        parts = str(text).lower().replace("*", "x").split("x")
        if len(parts) != 2:
            raise ValueError(f"setup '{text}' must be WIDTHxHEIGHT in mm, e.g. 29x59")
        try:
            w, h = float(parts[0]), float(parts[1])
        except ValueError:
            raise ValueError(f"setup '{text}' must be WIDTHxHEIGHT in mm, e.g. 29x59") from None
        return cls(w, h)

    def in_space(self) -> bool:
        lo, hi = SETUP_RANGE_MM
        return lo <= self.width_mm <= hi and lo <= self.height_mm <= hi

    def check_in_space(self) -> "Setup":
        lo, hi = SETUP_RANGE_MM
        for name, value in (("width_mm", self.width_mm), ("height_mm", self.height_mm)):
            if not (lo <= value <= hi):
                raise ValueError(f"{name}={value:g} lies outside the setup space {lo}..{hi} mm")
        return self

    @property
    def width_m(self) -> float:
        return self.width_mm * 1e-3

    @property
    def height_m(self) -> float:
        return self.height_mm * 1e-3

    def __str__(self) -> str:
        return f"{self.width_mm:g}x{self.height_mm:g}"

    def to_dict(self) -> dict:
        return {"width_mm": self.width_mm, "height_mm": self.height_mm}


def normalize(x) -> np.ndarray:
    """Material parameters (..., 3) in SI -> normalised material space [0, 1]^3."""
    return (np.asarray(x, dtype=float) - LOWER) / EXTENT


def denormalize(u) -> np.ndarray:
    """Normalised material space (..., 3) -> SI parameters (eta, n, sigma_y)."""
    return LOWER + np.asarray(u, dtype=float) * EXTENT


def center() -> Material:
    """Centre of the material space (initial CMA-ES mean for the first setup)."""
    return Material.from_array(denormalize([0.5, 0.5, 0.5]))


def candidate_setups() -> tuple[np.ndarray, np.ndarray]:
    """All 51 x 51 = 2601 candidate setups: (width_mm, height_mm) arrays, height outer, width inner."""
    lo, hi = SETUP_RANGE_MM
    sizes = np.arange(lo, hi + 1, dtype=float)
    h, w = np.meshgrid(sizes, sizes, indexing="ij")
    return w.ravel(), h.ravel()


def e_rel(truth, estimate) -> float:
    """Relative error E_rel between two materials, normalised by the material-space extents (eq. 44)."""
    a = np.array([truth.eta, truth.n, truth.sigma_y], dtype=float)
    b = np.array([estimate.eta, estimate.n, estimate.sigma_y], dtype=float)
    return float(np.sqrt(np.sum(((b - a) / EXTENT) ** 2)))
