"""Each special law's best fit found by the simulator: a small CMA-ES (Algorithm 1's optimiser) on the law's face.

The laws' evidence is integrated on the loss emulator, which is trained where the Herschel-Bulkley posterior lies.
Along a similarity valley a special law's best fit can lie far from that posterior's projection onto the law's face
(a Bingham material estimated with n < 1 moves eta and sigma_y as well), where the emulator has seen nothing and
would understate the law's evidence.  So before the evidence is computed each face is searched with the simulator,
and what the search simulated joins the emulator's training set.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from similarity.space import denormalize, from_search, to_search

GENERATIONS = 8  # per face
POPSIZE = 6
SIGMA0 = 0.2  # in the search coordinates (log eta, n, sigma_y; each over [0, 1])
SPACE = "log-eta"  # runny materials' eta lie in the first percent of the linear range


def face_search(losses: Callable, law, start, *, seed: int = 0, generations: int = GENERATIONS,
                popsize: int = POPSIZE) -> tuple[np.ndarray, np.ndarray]:
    """CMA-ES over the free coordinates of ``law``'s face (a line search where one is free) from ``start``
    (normalised, (3,)), each generation simulated at once by ``losses`` (normalised (k, 3) -> mean video losses (k,),
    NaN where a simulation failed).  Returns the normalised materials simulated, all on the face, and their losses.
    Deterministic for a seed: a re-run asks the same materials (and the store answers them)."""
    import cma

    free = list(law.free)
    u0 = to_search(np.clip(np.asarray(start, float), 0.0, 1.0), SPACE)
    if len(free) == 1:
        return _line_search(losses, law, float(u0[free[0]]), generations, popsize)
    es = cma.CMAEvolutionStrategy(np.clip(u0[free], 0.02, 0.98), SIGMA0,
                                  {"bounds": [0.0, 1.0], "popsize": popsize, "seed": seed + 1, "verbose": -9})
    X, y = [], []
    for _ in range(generations):
        z = np.asarray(es.ask())
        x = from_search(law.embed(z), SPACE)
        loss = np.asarray(losses(x), float)
        X.append(x)
        y.append(loss)
        finite = loss[np.isfinite(loss)]
        worst = (float(finite.max()) if finite.size else 1.0) * 2.0 + 1.0  # a failed simulation ranks last
        es.tell(list(z), np.where(np.isfinite(loss), loss, worst).tolist())
    return np.vstack(X), np.concatenate(y)


def search_faces(losses: Callable, laws, start, *, seed: int = 0, say=print) -> tuple[np.ndarray, np.ndarray]:
    """:func:`face_search` on the face of each special law among ``laws``, one after the other; ``say`` gets one line
    per face with its best fit.  Returns everything simulated (normalised, (k, 3)) and the losses."""
    X, y = [np.zeros((0, 3))], [np.zeros(0)]
    for law in (law for law in laws if law.fixed):
        X_face, y_face = face_search(losses, law, start, seed=seed)
        i = int(np.nanargmin(y_face)) if np.isfinite(y_face).any() else 0
        eta, n, sigma_y = denormalize(X_face[i])
        say(f"{law.name}: best fit on its face eta {eta:.3g} Pa s^n, n {n:.3g}, sigma_y {sigma_y:.3g} Pa, loss "
            f"{y_face[i]:.5f} ({len(y_face)} simulated)")
        X.append(X_face)
        y.append(y_face)
    return np.vstack(X), np.concatenate(y)


def _line_search(losses, law, u0: float, generations: int, popsize: int) -> tuple[np.ndarray, np.ndarray]:
    """The one free coordinate's search (pycma does not run in one dimension): ``popsize`` evenly spaced points around
    the best so far, over +-2 SIGMA0 at first and half as wide each generation."""
    center, half = u0, 2.0 * SIGMA0
    X, y = [], []
    for _ in range(generations):
        z = np.unique(np.clip(center + half * np.linspace(-1.0, 1.0, popsize), 0.0, 1.0))
        x = from_search(law.embed(z[:, None]), SPACE)
        loss = np.asarray(losses(x), float)
        X.append(x)
        y.append(loss)
        if np.isfinite(loss).any():
            center = float(z[np.nanargmin(loss)])
        half /= 2.0
    return np.vstack(X), np.concatenate(y)
