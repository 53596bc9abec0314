"""Which dam-break setup to run next (section 6): the candidate whose loss normal is most
perpendicular to the normals of the setups already done.

All 2601 candidates (20..70 mm, 1 mm steps; height outer, width inner) are scored at once. A
candidate is valid when Theta's plane-Poiseuille setup flows, P L > sigma_y. The first minimum of
S_p in candidate order wins ties (the authors' strict "<" scan). ``least_perpendicular_setup`` is
the ablation of the paper's Fig. 10(d): the candidate with the *largest* S_p among those at least
``min_distance_mm`` away from every setup already done (the paper asks for "distant" setups without
a number; 10 mm is our choice).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from surrogate.theta import ThetaMap, load

from .normals import loss_normal, loss_normals, perpendicularity
from .space import SETUP_RANGE_MM, Material, Setup, candidate_setups


@dataclass(frozen=True, eq=False)
class Ranking:
    """Every valid candidate with its loss normal and score S_p, in candidate order."""

    material: Material
    done: tuple
    width_mm: np.ndarray
    height_mm: np.ndarray
    score: np.ndarray
    normals: np.ndarray
    done_normals: np.ndarray

    def __len__(self) -> int:
        return len(self.score)

    def best(self) -> tuple[Setup, float]:
        """(setup, S_p) of the most perpendicular candidate (first minimum)."""
        i = int(np.argmin(self.score))
        return Setup(float(self.width_mm[i]), float(self.height_mm[i])), float(self.score[i])

    def grid(self) -> np.ndarray:
        """S_p on the 51 x 51 candidate grid, rows = height, columns = width; NaN where invalid."""
        lo, hi = SETUP_RANGE_MM
        size = hi - lo + 1
        out = np.full((size, size), np.nan)
        out[(self.height_mm - lo).astype(int), (self.width_mm - lo).astype(int)] = self.score
        return out


def _material(material) -> Material:
    m = material if isinstance(material, Material) else Material(*(float(v) for v in material))
    return m.check_in_space()


def _setups(done) -> tuple:
    if isinstance(done, (Setup, str)):
        done = [done]
    out = []
    for s in done:
        if isinstance(s, str):
            s = Setup.parse(s)
        elif not isinstance(s, Setup):
            s = Setup(*(float(v) for v in s))
        out.append(s.check_in_space())
    if not out:
        raise ValueError("at least one setup must have been done before choosing the next one")
    return tuple(out)


def rank_setups(material, done, theta="reference", variant: str = "scaled") -> Ranking:
    """Score every valid candidate setup (vectorised over all 2601) against the setups ``done``."""
    material = _material(material)
    done = _setups(done)
    theta = theta if isinstance(theta, ThetaMap) else load(theta)
    q_done = np.array([loss_normal(material, s, theta, variant) for s in done])
    width, height = candidate_setups()
    q, valid = loss_normals(material, width, height, theta, variant)
    if not np.any(valid):
        raise ValueError(f"no candidate setup makes {material} flow in Theta's plane-Poiseuille model")
    q = q[valid]
    return Ranking(material, done, width[valid], height[valid], perpendicularity(q_done, q), q, q_done)


def next_setup(material, done, theta="reference") -> Setup:
    """The next setup: the valid candidate whose loss normal is most perpendicular to those of ``done``."""
    return rank_setups(material, done, theta).best()[0]


def least_perpendicular_setup(material, done, theta="reference", min_distance_mm: float = 10.0) -> Setup:
    """Ablation (Fig. 10(d)): the candidate with the largest S_p at least ``min_distance_mm`` from every done setup."""
    r = rank_setups(material, done, theta)
    dist = np.min([np.hypot(r.width_mm - s.width_mm, r.height_mm - s.height_mm) for s in r.done], axis=0)
    far = dist >= min_distance_mm
    if not np.any(far):
        raise ValueError(f"no valid candidate lies {min_distance_mm:g} mm or more from the setups done")
    score = np.where(far, r.score, -np.inf)
    i = int(np.argmax(score))
    return Setup(float(r.width_mm[i]), float(r.height_mm[i]))
