"""emcee's moves on a report's posterior: time, autocorrelation time and moments per move, and the laws' evidence.

    python bench/bench_mcmc.py RUN [--seeds 2]

RUN is a folder that `virheo report` wrote (posterior.json, posterior_training.npz).  Its emulated log-posterior is
rebuilt from those files (the report's emulator refitted with its hyperparameters, its noise and its box) and sampled
from the estimate as the report samples it (:func:`similarity.mcmc.sample`: 32 walkers, ESS >= 1000, chains longer
than 50 tau) with each move, ``--seeds`` times; then the laws' evidence (`virheo laws`) is computed with each.
Prints wall seconds, steps, tau, ESS, acceptance, and the posterior mean and standard deviations (normalised), so
that a faster move is seen to sample the same posterior.  Last, each special law's evidence with its face posterior
from the shipped zoomed grid and from emcee (16 walkers started at the best of 2 048 Sobol points on the face, ESS
>= 200): wall seconds and ln Z, beside the midpoint rule's ln Z on a fine grid over the face.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402

from measured import how_measured  # noqa: E402


def moves():
    import emcee

    return {"differential evolution (shipped)": emcee.moves.DEMove(),
            "stretch (emcee's default)": emcee.moves.StretchMove(),
            "DE 0.8 + snooker 0.2": [(emcee.moves.DEMove(), 0.8), (emcee.moves.DESnookerMove(), 0.2)]}


def with_move(move):
    """A context in which every ``emcee.EnsembleSampler`` uses ``move``."""
    import contextlib

    import emcee

    @contextlib.contextmanager
    def ctx():
        orig = emcee.EnsembleSampler

        def sampler(*a, **k):
            k["moves"] = move
            return orig(*a, **k)

        emcee.EnsembleSampler = sampler
        try:
            yield
        finally:
            emcee.EnsembleSampler = orig

    return ctx()


def emcee_face(log_like, law, lo, hi, seed: int = 0) -> np.ndarray:
    """The rejected face posterior: emcee on the face's free coordinates, started at its best Sobol point."""
    from scipy.stats import qmc

    from similarity.mcmc import sample

    free = list(law.free)
    flo, fhi = np.asarray(lo, float)[free], np.asarray(hi, float)[free]

    def log_prob(z):
        z = np.atleast_2d(z)
        out = np.full(len(z), -np.inf)
        ok = np.all((z >= flo) & (z <= fhi), axis=1)
        if ok.any():
            out[ok] = log_like(law.embed(z[ok]))
        return out

    z0 = qmc.scale(qmc.Sobol(d=len(free), scramble=True, seed=seed).random(2048), flo, fhi)
    best = z0[int(np.argmax(log_prob(z0)))]
    post = sample(log_prob, best, nwalkers=max(16, 8 * len(free)), seed=seed, min_ess=200.0, max_steps=5000,
                  check_every=100, ball=1e-3 * float(np.min(fhi - flo)))
    return law.embed(post.samples)


QUADRATURE_CELLS = 1024


def quadrature_log_z(log_like, law, lo, hi) -> float:
    """ln of the integral of exp(log_like) over ``law``'s face of the box by the midpoint rule on ``QUADRATURE_CELLS``
    cells per free coordinate: the reference the importance-sampling estimates are compared with."""
    from scipy.special import logsumexp

    from similarity.evidence import face_cells

    free = list(law.free)
    z, h = face_cells(np.asarray(lo, float)[free], np.asarray(hi, float)[free], QUADRATURE_CELLS)
    ll = np.concatenate([log_like(law.embed(part)) for part in np.array_split(z, max(1, len(z) // 16384))])
    return float(logsumexp(ll) + np.sum(np.log(h)))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("run", metavar="RUN")
    p.add_argument("--seeds", type=int, default=2)
    args = p.parse_args(argv)
    from similarity.law_evidence import TRAINING_FILE, evidence_of_report
    from similarity.mcmc import sample
    from similarity.emulator_check import box_log_posterior
    from similarity.posterior_summary import read_posterior
    from surrogate.emulator import LossEmulator

    folder = Path(args.run)
    try:
        summary = read_posterior(folder)
        t = np.load(folder / TRAINING_FILE)
    except (ValueError, OSError) as exc:
        print(f"bench_mcmc: {exc}", file=sys.stderr)
        return 2
    emu = LossEmulator(seed=int(t["seed"])).fit(t["X"], t["y"], theta=t["theta"])
    lo, hi = (np.asarray(v, float) for v in summary.emulator.trust_region)
    log_prob = box_log_posterior(summary.noise, emu, lo, hi)
    x0 = np.asarray(summary.estimate_normalised, float)
    print(f"measured: {how_measured()}")
    print(f"run {folder}: {len(t['y'])} training losses, box {np.round(lo, 3).tolist()}..{np.round(hi, 3).tolist()}")
    for name, move in moves().items():
        with with_move(move):
            for seed in range(args.seeds):
                t0 = time.perf_counter()
                post = sample(log_prob, x0, seed=seed)
                wall = time.perf_counter() - t0
                print(f"{name:34s} seed {seed}: {wall:5.1f} s, {post.iterations} steps, "
                      f"tau {np.round(post.tau, 1).tolist()}, "
                      f"ESS {post.ess:.0f}, acceptance {post.acceptance:.2f}, mean {np.round(post.mean, 4).tolist()}, "
                      f"sd {np.round(np.sqrt(np.diag(post.cov)), 4).tolist()}", flush=True)
            t0 = time.perf_counter()
            ev = evidence_of_report(folder)
            print(f"{name:34s} laws' evidence: {time.perf_counter() - t0:5.1f} s, ln Z " + ", ".join(
                f"{e.law} {e.log_z:.2f} ± {e.log_z_err:.2f}" for e in ev.laws), flush=True)
    from similarity.evidence import LAWS, law_evidence

    def log_like(x):
        return summary.noise.log_likelihood(emu.predict(np.atleast_2d(x)))

    for law in (law for law in LAWS.values() if law.fixed and law.on_face(lo, hi)):
        print(f"{law.name:10s} quadrature on {QUADRATURE_CELLS} cells per free coordinate (reference): ln Z "
              f"{quadrature_log_z(log_like, law, lo, hi):.3f}", flush=True)
        for name, face in (("zoomed grid (shipped)", None), ("emcee", emcee_face)):
            t0 = time.perf_counter()
            samples = None if face is None else face(log_like, law, lo, hi)
            ev, _ = law_evidence(log_like, law, lo, hi, samples=samples)
            print(f"{law.name:10s} face posterior by {name:21s}: {time.perf_counter() - t0:5.2f} s, ln Z "
                  f"{ev.log_z:.3f} ± {ev.log_z_err:.3f}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
