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
    return _drive(losses, [_searcher(law, start, seed, generations, popsize)])[0]


def search_faces(losses: Callable, laws, start, *, seed: int = 0, say=print) -> tuple[np.ndarray, np.ndarray]:
    """:func:`face_search` on the face of each special law among ``laws``, the faces' generations simulated together
    (each face's search is the one :func:`face_search` makes alone); ``say`` gets one line per face with its best fit.
    Returns everything simulated (normalised, (k, 3)) and the losses, face after face."""
    special = [law for law in laws if law.fixed]
    found = _drive(losses, [_searcher(law, start, seed, GENERATIONS, POPSIZE) for law in special])
    X, y = [np.zeros((0, 3))], [np.zeros(0)]
    for law, (X_face, y_face) in zip(special, found):
        i = int(np.nanargmin(y_face)) if np.isfinite(y_face).any() else 0
        eta, n, sigma_y = denormalize(X_face[i])
        say(f"{law.name}: best fit on its face eta {eta:.3g} Pa s^n, n {n:.3g}, sigma_y {sigma_y:.3g} Pa, loss "
            f"{y_face[i]:.5f} ({len(y_face)} simulated)")
        X.append(X_face)
        y.append(y_face)
    return np.vstack(X), np.concatenate(y)


def _drive(losses: Callable, searchers: list) -> list:
    """Run searchers (generators that yield the normalised materials of a generation and are sent their losses)
    side by side, every generation of all of them in one call of ``losses``: what each simulated and its losses."""
    asked = [next(s) for s in searchers]
    X = [[] for _ in searchers]
    y = [[] for _ in searchers]
    live = list(range(len(searchers)))
    while live:
        loss = np.asarray(losses(np.vstack([asked[k] for k in live])), float)
        cuts = np.cumsum([len(asked[k]) for k in live])[:-1]
        for k, part in zip(list(live), np.split(loss, cuts)):
            X[k].append(asked[k])
            y[k].append(part)
            try:
                asked[k] = searchers[k].send(part)
            except StopIteration:
                live.remove(k)
    return [(np.vstack(a), np.concatenate(b)) for a, b in zip(X, y)]


def _searcher(law, start, seed: int, generations: int, popsize: int):
    """One face's search as a generator: yields each generation's normalised materials, is sent their losses."""
    import cma

    free = list(law.free)
    u0 = to_search(np.clip(np.asarray(start, float), 0.0, 1.0), SPACE)
    if len(free) == 1:
        yield from _line_search(law, float(u0[free[0]]), generations, popsize)
        return
    es = cma.CMAEvolutionStrategy(np.clip(u0[free], 0.02, 0.98), SIGMA0,
                                  {"bounds": [0.0, 1.0], "popsize": popsize, "seed": seed + 1, "verbose": -9})
    # pycma seeds and draws from numpy's global generator: each search keeps its own stream of it, so that the faces
    # searched side by side ask what each asks alone
    stream = np.random.get_state()
    for _ in range(generations):
        np.random.set_state(stream)
        z = np.asarray(es.ask())
        stream = np.random.get_state()
        loss = yield from_search(law.embed(z), SPACE)
        finite = loss[np.isfinite(loss)]
        worst = (float(finite.max()) if finite.size else 1.0) * 2.0 + 1.0  # a failed simulation ranks last
        np.random.set_state(stream)
        es.tell(list(z), np.where(np.isfinite(loss), loss, worst).tolist())
        stream = np.random.get_state()


def _line_search(law, u0: float, generations: int, popsize: int):
    """The one free coordinate's search (pycma does not run in one dimension), as a generator like
    :func:`_searcher`: ``popsize`` evenly spaced points around the best so far, over +-2 SIGMA0 at first and half as
    wide each generation."""
    center, half = u0, 2.0 * SIGMA0
    for _ in range(generations):
        z = np.unique(np.clip(center + half * np.linspace(-1.0, 1.0, popsize), 0.0, 1.0))
        loss = yield from_search(law.embed(z[:, None]), SPACE)
        if np.isfinite(loss).any():
            center = float(z[np.nanargmin(loss)])
        half /= 2.0
