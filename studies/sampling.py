"""The studies' random draws: materials spread by Poisson-disk sampling, and setups from the 1 mm grid."""
from __future__ import annotations

import numpy as np

from mpm.params import SETUP_RANGE_MM, Setup


def poisson_points(count: int, seed: int = 0, radius: float = 0.3) -> tuple[np.ndarray, float]:
    """``count`` points (count, 3) of the unit cube by Poisson-disk sampling (scipy.stats.qmc.PoissonDisk), and the
    radius they respect: ``radius``, shrunk by 15 % steps until ``count`` points fit."""
    from scipy.stats import qmc

    if count < 1:
        raise ValueError(f"count={count} must be >= 1")
    r = radius
    while True:
        pts = qmc.PoissonDisk(d=3, radius=r, seed=seed).random(count)
        if len(pts) >= count:
            return pts[:count], r
        r *= 0.85


def poisson_disk(count: int, seed: int = 0, margin: float = 0.05, radius: float = 0.3,
                 box=None) -> tuple[np.ndarray, float]:
    """:func:`poisson_points` mapped into [margin, 1 - margin]^3 (or into ``box`` = (lo, hi) corners).

    Returns the points (count, 3) and the minimum distance they respect (the radius times the box's shortest side).
    """
    if not 0 <= margin < 0.5:
        raise ValueError(f"margin={margin} must lie in [0, 0.5)")
    pts, r = poisson_points(count, seed, radius)
    if box is None:
        box = (np.full(3, margin), np.full(3, 1.0 - margin))
    lo, hi = np.asarray(box[0], dtype=float), np.asarray(box[1], dtype=float)
    side = hi - lo
    return lo + side * pts, r * float(np.min(side))


def random_setups(count: int, rng: np.random.Generator, *, replace: bool) -> list[Setup]:
    """``count`` setups drawn uniformly from the 1 mm grid of widths and heights (20..70 mm): with ``replace`` each
    independently (a setup may come twice), else ``count`` distinct ones."""
    lo, hi = SETUP_RANGE_MM
    if replace:
        return [Setup(float(w), float(h)) for w, h in rng.integers(lo, hi + 1, size=(count, 2))]
    size = int(hi - lo + 1)
    idx = rng.choice(size * size, size=count, replace=False)
    return [Setup(float(lo + i % size), float(lo + i // size)) for i in idx]
