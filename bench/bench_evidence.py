"""The laws' evidence (similarity/evidence.py) against closed forms: accuracy and time, and nested sampling beside it.

    python bench/bench_evidence.py [--repeats 5]

A Gaussian likelihood in the unit box, cut by the n = 1 and sigma_y = 0 faces (the case of a material near
Bingham and the power law), with widths like a report's posterior (0.4 % to 3 % of the space): the exact ln Z of
each law is a product of normal CDFs.  Prints, per law, the importance-sampling estimate's error against the exact
value, its stated Monte Carlo error and its wall time (the face posterior on its grid included), over ``--repeats`` seeds;
then the same for nested sampling (dynesty, 500 live points, dlogz 0.1; ultranest, 400 live points) where those
packages are installed (they are not dependencies).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402
from scipy.stats import norm, truncnorm  # noqa: E402

from measured import how_measured  # noqa: E402

MU, SD = np.array([0.31, 0.97, 0.02]), np.array([0.004, 0.03, 0.015])


def log_like(x):
    return -0.5 * np.sum(((np.atleast_2d(x) - MU) / SD) ** 2, axis=1)


def exact(law) -> float:
    free = list(law.free)
    z = np.sum(np.log(SD[free] * np.sqrt(2 * np.pi) * (norm.cdf((1 - MU[free]) / SD[free]) - norm.cdf(-MU[free] / SD[free]))))
    return float(z + sum(-0.5 * ((v - MU[i]) / SD[i]) ** 2 for i, v in law.fixed))


def main(argv=None) -> int:
    from similarity.evidence import LAWS, law_evidence

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeats", type=int, default=5)
    args = p.parse_args(argv)
    print(f"measured: {how_measured()}")
    lo, hi = np.zeros(3), np.ones(3)
    samples = truncnorm.rvs(-MU / SD, (1 - MU) / SD, loc=MU, scale=SD, size=(4000, 3), random_state=1)
    print("| method | law | exact ln Z | mean error | RMS error | stated error (mean) | wall per law [s] |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for law in LAWS.values():
        errs, stated, walls = [], [], []
        for seed in range(args.repeats):
            t0 = time.perf_counter()
            ev, _ = law_evidence(log_like, law, lo, hi, samples=None if law.fixed else samples, seed=seed)
            walls.append(time.perf_counter() - t0)
            errs.append(ev.log_z - exact(law))
            stated.append(ev.log_z_err)
        errs = np.array(errs)
        print(f"| importance sampling | {law.name} | {exact(law):.3f} | {errs.mean():+.4f} | "
              f"{np.sqrt(np.mean(errs ** 2)):.4f} | {np.mean(stated):.4f} | {np.median(walls):.2f} |")
    try:
        import dynesty
    except ImportError:
        print("dynesty: not installed (pip install dynesty to compare)")
    else:
        law = LAWS["herschel-bulkley"]
        t0 = time.perf_counter()
        ns = dynesty.NestedSampler(lambda x: float(log_like(x)[0]), lambda u: u, 3, nlive=500,
                                   rstate=np.random.default_rng(0))
        ns.run_nested(print_progress=False, dlogz=0.1)
        r = ns.results
        print(f"| dynesty {dynesty.__version__} | {law.name} | {exact(law):.3f} | {r.logz[-1] - exact(law):+.4f} | | "
              f"{r.logzerr[-1]:.4f} | {time.perf_counter() - t0:.2f} |")
    try:
        import logging

        import ultranest
    except ImportError:
        print("ultranest: not installed (pip install ultranest to compare)")
    else:
        logging.getLogger("ultranest").setLevel(logging.WARNING)
        law = LAWS["herschel-bulkley"]
        t0 = time.perf_counter()
        s = ultranest.ReactiveNestedSampler(["a", "b", "c"], log_like, lambda u: u, vectorized=True)
        r = s.run(show_status=False, viz_callback=False, min_num_live_points=400)
        print(f"| ultranest {ultranest.__version__} | {law.name} | {exact(law):.3f} | {r['logz'] - exact(law):+.4f} | | "
              f"{r['logzerr']:.4f} | {time.perf_counter() - t0:.2f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
