"""Values that define a dam-break experiment: ``Material``, ``Setup`` and their validation, the paper's
material-space and setup ranges, the flow-rule names, the frame times, the working image size and an
experiment's default density and depth. It imports nothing of the project, so every floor may import it
(docs/layers.md).

Pure Python and numpy (no Taichi). SI units; setups in millimetres (``width_mm``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# the paper's material space (section 3.1), per parameter (lower, upper)
ETA_RANGE = (1e-4, 30.0)  # Pa s^n
N_RANGE = (0.3, 1.0)
SIGMA_Y_RANGE = (0.0, 40.0)  # Pa
SETUP_RANGE_MM = (20, 70)  # width and height of a dam-break setup (section 3.3)
FLOW_RULES = ("paper", "yue2015")  # the paper's modified flow rule (eqs. 14-18) and Yue et al. 2015
FPS = 24.0  # frame k of a video is at t = k / FPS
N_FRAMES = 8
WORKING_SIZE = (960, 540)  # (width, height) in pixels at which silhouettes are compared
DEFAULT_DENSITY_KG_M3 = 1000.0  # a material's density where none is given (water-like)
DEFAULT_DEPTH_MM = 40.0  # distance between the box's side walls where none is given (section 3.3)


def frame_times() -> np.ndarray:
    """t_k = k / 24 s for k = 1..8."""
    return np.arange(1, N_FRAMES + 1) / FPS


def flow_curve(eta, n, sigma_y, gamma_dot):
    """Herschel-Bulkley flow curve sigma = sigma_y + eta * gamma_dot^n in Pa (eq. 1); scalars or arrays that
    broadcast. Its terminal-stress form (eq. 7) in ``mpm.shear`` and ``Material.stress`` call it."""
    return sigma_y + eta * np.asarray(gamma_dot, dtype=float) ** n  # eq. 1


def check_material(eta, n, sigma_y) -> None:
    """ValueError (one line) unless eta > 0, n > 0 and sigma_y >= 0 are finite; scalars or arrays."""
    for name, value, unit, lower, strict, (lo, hi) in (
        ("eta", eta, " Pa s^n", 0.0, True, ETA_RANGE),
        ("n", n, "", 0.0, True, N_RANGE),
        ("sigma_y", sigma_y, " Pa", 0.0, False, SIGMA_Y_RANGE),
    ):
        v = np.asarray(value, dtype=float)
        good = np.isfinite(v) & ((v > lower) if strict else (v >= lower))
        if not np.all(good):
            bad = float(v[~good].flat[0]) if v.ndim else float(v)
            rule = "a finite number " + ("> 0" if strict else ">= 0")
            raise ValueError(f"{name}={bad:g}{unit} is unphysical: it must be {rule} "
                             f"(material space {lo:g}..{hi:g}{unit})")


def material_array(material) -> np.ndarray:
    """(eta, n, sigma_y) as a float array (..., 3) from a ``Material``, any object with numeric (or array)
    ``.eta``, ``.n`` and ``.sigma_y``, or an array-like (..., 3); a one-line ValueError otherwise."""
    try:
        if all(hasattr(material, k) for k in ("eta", "n", "sigma_y")):
            parts = (np.asarray(getattr(material, k), dtype=float) for k in ("eta", "n", "sigma_y"))
            return np.stack(np.broadcast_arrays(*parts), axis=-1)
        m = np.asarray(material, dtype=float)
    except (TypeError, ValueError):
        raise ValueError("material needs numeric .eta (Pa s^n), .n and .sigma_y (Pa), or three numbers") from None
    if m.shape[-1:] != (3,):
        raise ValueError(f"material must be a Material or an array (..., 3) of eta, n, sigma_y; got shape {m.shape}")
    return m


def setup_arrays(setup) -> tuple:
    """(width_mm, height_mm) from a ``Setup`` (or any object with ``.width_mm`` and ``.height_mm``), a
    (width_mm, height_mm) pair of arrays (e.g. ``similarity.space.candidate_setups()``) or an array (..., 2)."""
    if hasattr(setup, "width_mm") and hasattr(setup, "height_mm"):
        return setup.width_mm, setup.height_mm
    if isinstance(setup, tuple) and len(setup) == 2:
        return setup
    a = np.asarray(setup, dtype=float)
    if a.shape[-1:] != (2,):
        raise ValueError(f"setup must be a Setup, a (width_mm, height_mm) pair or an array (..., 2); "
                         f"got shape {a.shape}")
    return a[..., 0], a[..., 1]


def check_flow_rule(name) -> str:
    """``name`` if it is one of ``FLOW_RULES``, else a one-line ValueError."""
    if name not in FLOW_RULES:
        raise ValueError(f"unknown flow rule {name!r}: expected one of {', '.join(FLOW_RULES)}")
    return name


@dataclass(frozen=True)
class Material:
    """Herschel-Bulkley material: consistency eta [Pa s^n], power index n [-], yield stress sigma_y [Pa]."""

    eta: float
    n: float
    sigma_y: float

    def __post_init__(self):
        check_material(self.eta, self.n, self.sigma_y)

    @classmethod
    def of(cls, material) -> "Material":
        """A validated ``Material`` from any object with numeric ``.eta``, ``.n`` and ``.sigma_y``, or from three
        numbers (eta, n, sigma_y): :func:`material_array`."""
        if isinstance(material, cls):
            return material
        m = material_array(material)
        if m.shape != (3,):
            raise ValueError(f"material needs one (eta, n, sigma_y), got shape {m.shape[:-1]} of them")
        return cls.from_array(m)

    def as_array(self) -> np.ndarray:
        return material_array(self)

    @classmethod
    def from_array(cls, x) -> "Material":
        x = np.asarray(x, dtype=float)
        return cls(float(x[0]), float(x[1]), float(x[2]))

    @classmethod
    def parse(cls, text: str) -> "Material":
        """Parse 'ETA,N,SIGMA_Y' (SI)."""
        parts = [p.strip() for p in str(text).split(",")]
        message = f"material '{text}' must be three numbers ETA,N,SIGMA_Y (Pa s^n, -, Pa)"
        if len(parts) != 3:
            raise ValueError(message)
        try:
            values = [float(p) for p in parts]
        except ValueError:
            raise ValueError(message) from None
        return cls(*values)

    def in_space(self) -> bool:
        return all(lo - 1e-12 <= v <= hi + 1e-12 for v, (lo, hi) in
                   zip(self.as_array(), (ETA_RANGE, N_RANGE, SIGMA_Y_RANGE)))

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
        """This material's flow curve (eq. 1, :func:`flow_curve`), Pa."""
        return flow_curve(self.eta, self.n, self.sigma_y, gamma_dot)


@dataclass(frozen=True)
class Setup:
    """Dam-break setup: initial cuboid width (along the flow) and height, in millimetres."""

    width_mm: float
    height_mm: float

    def __post_init__(self):
        lo, hi = SETUP_RANGE_MM
        for name, value in (("width_mm", self.width_mm), ("height_mm", self.height_mm)):
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name}={value} is unphysical: it must be > 0 mm (setup space {lo}..{hi} mm)")

    @classmethod
    def of(cls, setup) -> "Setup":
        """A validated ``Setup`` from any object with numeric ``.width_mm`` and ``.height_mm``."""
        if isinstance(setup, cls):
            return setup
        try:
            values = float(setup.width_mm), float(setup.height_mm)
        except (AttributeError, TypeError, ValueError):
            raise ValueError("setup needs numeric .width_mm and .height_mm") from None
        return cls(*values)

    @classmethod
    def parse(cls, text: str) -> "Setup":
        """Parse 'WxH' in millimetres, e.g. '29x59'."""
        parts = str(text).lower().replace("*", "x").split("x")
        message = f"setup '{text}' must be WIDTHxHEIGHT in mm, e.g. 29x59"
        if len(parts) != 2:
            raise ValueError(message)
        try:
            w, h = float(parts[0]), float(parts[1])
        except ValueError:
            raise ValueError(message) from None
        return cls(w, h)

    def in_space(self) -> bool:
        lo, hi = SETUP_RANGE_MM
        return lo <= self.width_mm <= hi and lo <= self.height_mm <= hi

    def volume_ml(self, depth_mm: float = DEFAULT_DEPTH_MM) -> float:
        """The material the box holds, W x H x depth, in millilitres (cm^3)."""
        return self.width_mm * self.height_mm * float(depth_mm) / 1000.0

    def check_in_space(self) -> "Setup":
        """Raise ValueError naming the first dimension outside the setup space (20..70 mm)."""
        lo, hi = SETUP_RANGE_MM
        for name, value in (("width_mm", self.width_mm), ("height_mm", self.height_mm)):
            if not (lo - 1e-9 <= value <= hi + 1e-9):
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
