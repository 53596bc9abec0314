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

from similarity.space import from_search, to_search

GENERATIONS = 8  # per face
POPSIZE = 6
SIGMA0 = 0.2  # in the search coordinates (log eta, n, sigma_y; each over [0, 1])
SPACE = "log-eta"  # runny materials' eta lie in the first percent of the linear range


def face_search(losses: Callable, law, start, *, seed: int = 0, generations: int = GENERATIONS,
                popsize: int = POPSIZE) -> tuple[np.ndarray, np.ndarray]:
    """CMA-ES over the free coordinates of ``law``'s face from ``start`` (normalised, (3,)), each generation simulated
    at once by ``losses`` (normalised (k, 3) -> mean video losses (k,), NaN where a simulation failed).  Returns the
    normalised materials simulated, all on the face, and their losses.  Deterministic for a seed: a re-run asks
    the same materials (and the store answers them)."""
    import cma

    free = list(law.free)
    u0 = to_search(np.clip(np.asarray(start, float), 0.0, 1.0), SPACE)
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
