"""Rotational-rheometer flow curves (instrument CSV export) and their Herschel-Bulkley fit.

The export is UTF-16 (little-endian, BOM), tab separated, CRLF, with Japanese header rows (test
name, result, interval, column names), a units row ``[s] [1/s] [Pa] [mPa·s] [mN·m] [°C]`` and one
row per point: point number, time, shear rate, shear stress, viscosity, torque, temperature.
Columns are identified by their units, converted to SI, and the Herschel-Bulkley flow curve
(eq. 1, ``Material.stress``) is fitted by least squares in log10 stress over the range where the
instrument is reliable (1-100 1/s by default).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from mpm.params import Material

# unit label in the export -> (field name, factor to SI)
_UNITS = {
    "[s]": ("time_s", 1.0),
    "[1/s]": ("shear_rate", 1.0),
    "[pa]": ("shear_stress", 1.0),
    "[mpa·s]": ("viscosity", 1e-3),
    "[mpa s]": ("viscosity", 1e-3),
    "[mpa*s]": ("viscosity", 1e-3),
    "[mn·m]": ("torque", 1e-3),
    "[mn m]": ("torque", 1e-3),
    "[mn*m]": ("torque", 1e-3),
    "[°c]": ("temperature_k", 1.0),
}
REQUIRED = ("shear_rate", "shear_stress")
# file-name prefix -> material, for the four shared flow curves
MATERIALS = {
    "Nyueki": "moisturizing milk",
    "Chuno": "Japanese thickened Worcestershire sauce",
    "Okonomiyaki": "Japanese cabbage pancake sauce",
    "Lotion": "lotion",
}
RELIABLE_RANGE = (1.0, 100.0)  # 1/s


@dataclass(frozen=True, eq=False)
class FlowCurve:
    """One steady-shear flow curve in SI: rates [1/s], stresses [Pa], viscosity [Pa s], torque [N m], T [K]."""

    name: str
    path: str
    point: np.ndarray
    time_s: np.ndarray
    shear_rate: np.ndarray
    shear_stress: np.ndarray
    viscosity: np.ndarray
    torque: np.ndarray
    temperature_k: np.ndarray

    def __len__(self) -> int:
        return len(self.shear_rate)

    @property
    def material_name(self) -> str:
        """The specimen, from the file-name prefix (e.g. Chuno -> Japanese thickened Worcestershire sauce)."""
        stem = Path(self.path).stem
        for prefix, material in MATERIALS.items():
            if stem.lower().startswith(prefix.lower()):
                return material
        return self.name

    @property
    def temperature_c(self) -> np.ndarray:
        return self.temperature_k - 273.15

    def window(self, lo: float = RELIABLE_RANGE[0], hi: float = RELIABLE_RANGE[1]) -> np.ndarray:
        """Boolean mask of the points with lo <= shear rate <= hi (inclusive, 1e-9 relative slack)."""
        return (self.shear_rate >= lo * (1 - 1e-9)) & (self.shear_rate <= hi * (1 + 1e-9))


def _decode(raw: bytes, path: Path) -> str:
    if raw.startswith((b"\xff\xfe", b"\xfe\xff")):
        return raw.decode("utf-16")
    for enc in ("utf-16-le", "utf-8-sig"):
        try:
            text = raw.decode(enc)
        except UnicodeDecodeError:
            continue
        if "\t" in text:
            return text
    raise ValueError(f"{path}: not a rheometer export (expected UTF-16 tab-separated text)")


def read_flow_curve(path) -> FlowCurve:
    """Read an instrument CSV export; ValueError (one line) when the file is not one."""
    path = Path(path)
    if path.is_dir():
        raise ValueError(f"{path} is a folder; give one rheometer CSV file")
    if not path.is_file():
        raise FileNotFoundError(f"rheometer file {path} not found")
    text = _decode(path.read_bytes(), path)
    lines = [line.rstrip("\r") for line in text.replace("\r\n", "\n").split("\n")]
    name = path.stem
    header = None
    for i, line in enumerate(lines):
        cells = [c.strip() for c in line.split("\t")]
        if i == 0 and cells[0].endswith(":") and len(cells) > 1 and cells[1]:
            name = cells[1]  # first header row: "<test label>:\t<test name>"
        if "[1/s]" in [c.lower() for c in cells]:
            header = i, [c.lower() for c in cells]
            break
    if header is None:
        raise ValueError(f"{path}: not a rheometer export (no units row with a [1/s] column)")
    row0, units = header
    columns = {}
    for j, u in enumerate(units):
        if u in _UNITS:
            columns[_UNITS[u][0]] = (j, _UNITS[u][1])
    missing = [c for c in REQUIRED if c not in columns]
    if missing:
        raise ValueError(f"{path}: units row lacks the column(s) {', '.join(missing)}")
    rows = []
    for k, line in enumerate(lines[row0 + 1 :], start=row0 + 2):
        cells = line.split("\t")
        if not line.strip():
            continue
        try:
            rows.append([float(c) if c.strip() else np.nan for c in cells])
        except ValueError:
            raise ValueError(f"{path}, line {k}: non-numeric data row {line.strip()!r}") from None
    if not rows:
        raise ValueError(f"{path}: no data rows after the units row")
    width = max(len(r) for r in rows)
    data = np.array([r + [np.nan] * (width - len(r)) for r in rows])

    def col(field, default=np.nan):
        if field not in columns:
            return np.full(len(data), default)
        j, factor = columns[field]
        return data[:, j] * factor if j < width else np.full(len(data), np.nan)

    rate, stress = col("shear_rate"), col("shear_stress")
    good = np.isfinite(rate) & np.isfinite(stress) & (rate > 0) & (stress > 0)
    if good.sum() < len(data):
        raise ValueError(f"{path}: {len(data) - good.sum()} data row(s) without a positive shear rate and stress")
    return FlowCurve(
        name=name,
        path=str(path),
        point=data[:, 0].astype(int) if np.all(np.isfinite(data[:, 0])) else np.arange(1, len(data) + 1),
        time_s=col("time_s"),
        shear_rate=rate,
        shear_stress=stress,
        viscosity=col("viscosity"),
        torque=col("torque"),
        temperature_k=col("temperature_k") + 273.15,
    )


def log_stress_residuals(material: Material, curve: FlowCurve, lo: float = RELIABLE_RANGE[0], hi: float = RELIABLE_RANGE[1]) -> np.ndarray:
    """log10(model stress) - log10(measured stress) at the curve's points with lo <= rate <= hi."""
    mask = curve.window(lo, hi)
    return np.log10(material.stress(curve.shear_rate[mask])) - np.log10(curve.shear_stress[mask])


def log_stress_rms(material: Material, curve: FlowCurve, lo: float = RELIABLE_RANGE[0], hi: float = RELIABLE_RANGE[1]) -> float:
    """RMS of log10(model stress) - log10(measured stress) over lo <= shear rate <= hi (1/s)."""
    r = log_stress_residuals(material, curve, lo, hi)
    if r.size == 0:
        raise ValueError(f"{curve.name}: no points between {lo:g} and {hi:g} 1/s")
    return float(np.sqrt(np.mean(r * r)))


@dataclass(frozen=True)
class HerschelBulkleyFit:
    """A least-squares fit of eq. 1 (or one of its special cases, ``law``: mpm.laws.LAWS) in log10 stress."""

    material: Material
    rms_log10: float
    n_points: int
    lo: float
    hi: float
    law: str = "herschel-bulkley"
    parameters: int = 3  # fitted

    @property
    def aic(self) -> float:
        """Akaike's criterion of the Gaussian least-squares fit: N ln(RSS / N) + 2 k."""
        return self.n_points * np.log(max(self.rms_log10, 1e-300) ** 2) + 2 * self.parameters

    @property
    def bic(self) -> float:
        """Schwarz's criterion: N ln(RSS / N) + k ln N."""
        return self.n_points * np.log(max(self.rms_log10, 1e-300) ** 2) + self.parameters * np.log(self.n_points)


def fit_herschel_bulkley(curve: FlowCurve, lo: float = RELIABLE_RANGE[0], hi: float = RELIABLE_RANGE[1],
                         law: str = "herschel-bulkley") -> HerschelBulkleyFit:
    """Least-squares fit of eq. 1 in log10 stress over lo <= rate <= hi (scipy least_squares), with the parameters
    that ``law`` fixes (mpm.laws.LAWS: bingham n = 1, power-law sigma_y = 0, newtonian both) held.

    Unknowns (log10 eta, n, sigma_y) with bounds eta 1e-8..1e6 Pa s^n, n 0.05..2, 0 <= sigma_y <= the
    largest stress in the window (no law with eta >= 0 fits below its yield stress; the smallest stress would hold
    a law with n held, e.g. Bingham's, at the bound and make its AIC/BIC worse than its best fit); several starts
    (no, half and most of the lowest stress as yield stress), the best is kept.
    """
    from mpm.laws import LAWS

    if law not in LAWS:
        raise ValueError(f"unknown law '{law}': choose from {', '.join(LAWS)}")
    mask = curve.window(lo, hi)
    rate, stress = curve.shear_rate[mask], curve.shear_stress[mask]
    if len(rate) < 3:
        raise ValueError(f"{curve.name}: only {len(rate)} point(s) between {lo:g} and {hi:g} 1/s; need 3 for a fit")
    s_min = float(stress.min())
    target = np.log10(stress)
    held = {("eta", "n", "sigma_y").index(k): v for k, v in LAWS[law].items()}
    free = [i for i in range(3) if i not in held]

    def full(x):
        v = np.empty(3)
        v[free] = x
        for i, val in held.items():
            v[i] = val
        return v

    def residual(x):
        v = full(x)
        return np.log10(Material(10.0 ** v[0], v[1], v[2]).stress(rate)) - target

    lower, upper = np.array([-8.0, 0.05, 0.0]), np.array([6.0, 2.0, float(stress.max())])
    scale = np.array([1.0, 0.1, max(s_min, 1e-3)])
    best = None
    for frac in ((0.0,) if 2 in held else (0.0, 0.5, 0.9)):
        sig0 = frac * s_min
        excess = np.maximum(stress - sig0, 1e-12 * s_min)
        slope, intercept = np.polyfit(np.log10(rate), np.log10(excess), 1)
        if 1 in held:  # the slope is held: the intercept at that slope
            intercept = float(np.mean(np.log10(excess) - held[1] * np.log10(rate)))
        x0 = np.array([float(np.clip(intercept, -7.9, 5.9)), float(np.clip(slope, 0.06, 1.99)), sig0])[free]
        res = least_squares(residual, x0, bounds=(lower[free], upper[free]), x_scale=scale[free],
                            xtol=1e-12, ftol=1e-12, gtol=1e-12)
        if best is None or res.cost < best.cost:
            best = res
    v = full(best.x)
    m = Material(float(10.0 ** v[0]), float(v[1]), float(v[2]))
    return HerschelBulkleyFit(m, log_stress_rms(m, curve, lo, hi), int(len(rate)), lo, hi, law, len(free))
