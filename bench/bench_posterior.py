"""Time a posterior with >= 1000 effective samples once the loss emulator is built (target <= 2 min, 2 cores).

The emulator is trained on a synthetic dam-break-like loss: a quadratic valley in the normalised
material space (one long, one medium, one thin axis; eigenvalues 40 : 2 : 0.1), rough at the 1e-5 level
like the MPM loss, sampled at 150 scrambled-Sobol points in a box of half-width 0.1 around the optimum
(the size of the store's archive plus a space-filling batch).  The likelihood is eq. (1) of
similarity/likelihood.py with N_eff = 40 and s^2 = 3e-3 (the figures of a two-setup run).

    python bench/bench_posterior.py [--min-ess 1000] [--walkers 32] [--points 150]
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from similarity.likelihood import NoiseScale  # noqa: E402
from similarity.mcmc import sample  # noqa: E402
from similarity.emulator_check import box_log_posterior  # noqa: E402
from surrogate.emulator import LossEmulator, box, space_filling  # noqa: E402
from measured import how_measured  # noqa: E402  (bench/ is this script's folder)


def synthetic_loss(x, center, rng=None):
    q, _ = np.linalg.qr(np.array([[1.0, 0.3, 0.2], [0.4, 1.0, -0.3], [0.1, 0.5, 1.0]]))
    h = q @ np.diag([40.0, 2.0, 0.1]) @ q.T
    d = x - center
    rough = 1e-5 * np.sin(60 * x[:, 0]) * np.cos(45 * x[:, 2])
    return 3e-3 + 0.5 * np.einsum("ij,jk,ik->i", d, h, d) + rough


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--min-ess", type=float, default=1000.0)
    ap.add_argument("--walkers", type=int, default=32)
    ap.add_argument("--points", type=int, default=150)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    print(f"# measured: {how_measured()}", flush=True)
    center = np.array([0.3, 0.5, 0.4])
    X = space_filling(center, 0.1, args.points, seed=args.seed)
    t0 = time.perf_counter()
    emu = LossEmulator(seed=args.seed)
    Xt = space_filling(center, 0.08, 30, seed=args.seed + 1)
    v = emu.validate(X, synthetic_loss(X, center), Xt, synthetic_loss(Xt, center))
    t_emu = time.perf_counter() - t0
    noise = NoiseScale(8 * 2 * 518400, 40.0, 3e-3, 0.0, v.rmse, 16)
    log_prob = box_log_posterior(noise, emu, *box(center, 0.1))

    c0, t0 = time.process_time(), time.perf_counter()
    post = sample(log_prob, center, nwalkers=args.walkers, seed=args.seed, min_ess=args.min_ess)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    load = os.getloadavg()[0]
    print(f"emulator: {args.points} points, fit + validation {t_emu:.1f} s, held-out RMSE {v.rmse:.2e} "
          f"(range {v.loss_range:.2e})")
    print(f"posterior: {post.iterations} steps x {args.walkers} walkers, tau {np.max(post.tau):.1f}, "
          f"ESS {post.ess:.0f}, converged {post.converged}")
    print(f"time to >= {args.min_ess:g} effective samples: wall {wall:.1f} s, CPU {cpu:.1f} s "
          f"(load average {load:.1f}); target <= 120 s")


if __name__ == "__main__":
    main()
