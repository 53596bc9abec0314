"""Benchmark: ``rank_setups`` over all 2601 candidate setups for one material (target < 20 ms).

    python bench/bench_rank_setups.py [--repeat 200]

Prints the median and best wall time of one full ranking (Theta map, plane-Poiseuille Hessians,
batched eigenvectors, scores) and of its parts. Numbers go to docs/performance.md ("Setup ranking").
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from mpm.params import Material, Setup  # noqa: E402
from poiseuille import hessian  # noqa: E402
from similarity.design import rank_setups  # noqa: E402
from similarity.normals import top_eigenvector  # noqa: E402
from similarity.space import candidate_setups  # noqa: E402
from surrogate.theta import load  # noqa: E402
from measured import how_measured  # noqa: E402  (bench/ is this script's folder)


def timeit(fn, repeat: int) -> tuple[float, float]:
    fn()  # warm-up (imports, caches)
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)) * 1e3, float(np.min(times)) * 1e3


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=200)
    args = ap.parse_args()
    theta = load("reference")
    material = Material(3.142, 0.7394, 1.243)  # moisturizing milk, estimate after setup 1
    done = [Setup(29, 59)]
    w, h = candidate_setups()
    P, L = theta(material, (w, h))
    H = hessian(material.eta, material.n, material.sigma_y, P, L)
    rows = [
        ("rank_setups, 2601 candidates, 1 setup done", lambda: rank_setups(material, done, theta)),
        ("rank_setups, 2601 candidates, 3 setups done", lambda: rank_setups(material, done + [Setup(32, 20), Setup(70, 70)], theta)),
        ("  part: Theta map (P, L) for 2601", lambda: theta(material, (w, h))),
        ("  part: 2601 closed-form Hessians", lambda: hessian(material.eta, material.n, material.sigma_y, P, L)),
        ("  part: 2601 top eigenvectors (eigh)", lambda: top_eigenvector(H)),
    ]
    print(f"# measured: {how_measured()}", flush=True)
    print(f"{'what':48s} {'median ms':>10s} {'best ms':>9s}   (repeat {args.repeat})")
    for name, fn in rows:
        med, best = timeit(fn, args.repeat)
        print(f"{name:48s} {med:10.2f} {best:9.2f}")


if __name__ == "__main__":
    main()
