"""emcee sampling with a resumable HDF5 backend, and the posterior samples it returns.

``emcee.EnsembleSampler`` (``vectorize=True``, seeded) with an ``HDFBackend``, so that a killed run
resumes where it stopped; walkers start in a small ball around a given point.  The move is differential
evolution (``emcee.moves.DEMove``): on the reports' posteriors, elongated along the similarity valley and cut
by the box, its autocorrelation time is about 2.5x shorter than the default stretch move's
(bench/bench_mcmc.py).  Convergence: chains longer than 50 integrated autocorrelation times tau, with tau
within 5 % of the tau of the chain one chunk shorter; effective sample size
ESS = walkers x (steps - burn-in) / max(tau), burn-in = 2 max(tau).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from similarity.space import denormalize
from similarity.progress import Sampling, first_line

QUANTILES = (0.05, 0.5, 0.95)


@dataclass
class Posterior:
    """Samples (normalised coordinates, burn-in removed, all walkers) and their diagnostics."""

    samples: np.ndarray
    tau: np.ndarray
    iterations: int
    nwalkers: int
    burn: int
    converged: bool
    wall_seconds: float
    acceptance: float = float("nan")
    log_prob: np.ndarray | None = None  # the sampled log-posterior at each sample, as emcee computed it

    @property
    def ess(self) -> float:
        """Effective sample size: walkers x (steps - burn-in) / max(tau)."""
        return float(self.nwalkers * (self.iterations - self.burn) / max(float(np.max(self.tau)), 1.0))

    @property
    def mean(self) -> np.ndarray:
        return self.samples.mean(axis=0)

    @property
    def cov(self) -> np.ndarray:
        return np.cov(self.samples, rowvar=False)

    def si(self) -> np.ndarray:
        """Samples in SI (eta, n, sigma_y)."""
        return denormalize(self.samples)

    def summary(self) -> dict:
        si = self.si()
        q = np.quantile(si, QUANTILES, axis=0)
        names = ("eta", "n", "sigma_y")
        return {
            "mean": dict(zip(names, si.mean(axis=0).tolist())),
            "quantiles": {f"{int(100 * p)}": dict(zip(names, row.tolist())) for p, row in zip(QUANTILES, q)},
            "mean_normalised": self.mean.tolist(), "cov_normalised": self.cov.tolist(),
            "ess": self.ess, "tau": np.asarray(self.tau).tolist(), "iterations": self.iterations,
            "nwalkers": self.nwalkers, "burn": self.burn, "converged": self.converged,
            "acceptance": self.acceptance, "wall_seconds": self.wall_seconds,
        }


def check_backend(path) -> None:
    """ValueError (one line) when ``path`` exists but is not a readable HDF5 file."""
    path = Path(path)
    if path.exists():
        import h5py

        try:
            with h5py.File(path, "r"):
                pass
        except OSError as exc:
            raise ValueError(f"{path}: corrupt posterior backend ({str(exc).splitlines()[0]}); "
                             "delete it to sample again") from None


def chunked_backend(path, name: str):
    """emcee's in-memory backend, read from the HDF5 group ``name`` of ``path`` where a run left one and written
    back there by its ``persist()`` at the end of each chunk of steps.  emcee's own HDF5 backend opens the file at
    every step, which cost 14 times the sampler's own step on the emulated likelihood (bench/bench_posterior.py)."""
    import emcee
    import h5py

    class ChunkedBackend(emcee.backends.Backend):
        def __init__(self):
            super().__init__()
            self.saved = 0  # steps already in the file

        def reset(self, nwalkers, ndim):
            super().reset(nwalkers, ndim)
            self.saved = -1  # the file's group is stale: replaced at the next persist

        def load(self) -> None:
            with h5py.File(path, "r") as f:
                if name not in f or "rng_keys" not in f[name]:  # none, or emcee's own layout: sampled afresh
                    return
                g = f[name]
                super().reset(int(g.attrs["nwalkers"]), int(g.attrs["ndim"]))
                n = int(g.attrs["iteration"])
                self.chain, self.log_prob = g["chain"][:n], g["log_prob"][:n]
                self.accepted = g["accepted"][:]
                self.random_state = (str(g.attrs["rng"]), g["rng_keys"][:], int(g.attrs["rng_pos"]),
                                     int(g.attrs["rng_has_gauss"]), float(g.attrs["rng_gauss"]))
                self.iteration = self.saved = n

        def persist(self) -> None:
            with h5py.File(path, "a") as f:
                if self.saved < 0 and name in f:
                    del f[name]
                self.saved = max(self.saved, 0)
                g = f.require_group(name)
                nw, nd = self.nwalkers, self.ndim
                if "chain" not in g:
                    g.create_dataset("chain", (0, nw, nd), maxshape=(None, nw, nd), dtype=self.dtype, chunks=True)
                    g.create_dataset("log_prob", (0, nw), maxshape=(None, nw), dtype=self.dtype, chunks=True)
                new = slice(self.saved, self.iteration)
                for key, values in (("chain", self.chain), ("log_prob", self.log_prob)):
                    g[key].resize(self.iteration, axis=0)
                    g[key][new] = values[new]
                if "accepted" in g:
                    del g["accepted"], g["rng_keys"]
                g["accepted"] = self.accepted
                kind, keys, pos, has_gauss, gauss = self.random_state
                g["rng_keys"] = keys
                g.attrs.update(nwalkers=nw, ndim=nd, iteration=self.iteration, rng=kind, rng_pos=pos,
                               rng_has_gauss=has_gauss, rng_gauss=gauss)
            self.saved = self.iteration

    check_backend(path)
    backend = ChunkedBackend()
    if Path(path).exists():
        backend.load()
    return backend


def stored_chain(path, name: str = "mcmc") -> np.ndarray:
    """The chain (steps, walkers, dims) that :func:`sample` keeps in the HDF5 group ``name`` of ``path``."""
    backend = chunked_backend(path, name)
    return backend.chain[: backend.iteration] if backend.initialized else np.zeros((0, 0, 0))


def sample(log_prob: Callable[[np.ndarray], np.ndarray], x0, *, nwalkers: int = 32, seed: int = 0,
           min_ess: float = 1000.0, max_steps: int = 20000, check_every: int = 250, ball: float = 1e-3,
           backend=None, backend_name: str = "mcmc", min_steps: int = 0,
           progress: Callable[[dict], None] | None = None) -> Posterior:
    """Sample ``log_prob`` (vectorised: (k, d) -> (k,), -inf outside the support) with emcee.

    Walkers start at ``x0`` plus N(0, ball^2) (redrawn until their log_prob is finite).  Runs in chunks
    of ``check_every`` steps until converged (module docstring) with ESS >= ``min_ess``, or
    ``max_steps``.  ``backend``: an HDF5 path; re-running with the same path and name resumes.
    """
    import emcee

    x0 = np.asarray(x0, float)
    ndim = x0.size
    t0 = time.perf_counter()
    try:
        hdf = chunked_backend(backend, backend_name) if backend is not None else None
    except (OSError, KeyError) as exc:
        raise ValueError(f"{backend}: corrupt posterior backend ({first_line(exc)}); delete it to sample again") from None
    resume = False
    if hdf is not None:
        try:
            resume = hdf.initialized and hdf.iteration > 0
            if resume and hdf.shape != (nwalkers, ndim):
                raise ValueError(f"{backend}: backend holds {hdf.shape[0]} walkers in {hdf.shape[1]} dimensions, "
                                 f"not {nwalkers} in {ndim}; delete it to sample again")
        except (OSError, KeyError) as exc:
            raise ValueError(f"{backend}: corrupt posterior backend ({exc}); delete it to sample again") from None
    sampler = emcee.EnsembleSampler(nwalkers, ndim, log_prob, vectorize=True, backend=hdf,
                                    moves=emcee.moves.DEMove())
    if resume:
        state = None
    else:
        if hdf is not None:
            hdf.reset(nwalkers, ndim)
        rng = np.random.default_rng(seed)
        state = x0 + ball * rng.standard_normal((nwalkers, ndim))
        for _ in range(200):
            bad = ~np.isfinite(log_prob(state))
            if not bad.any():
                break
            state[bad] = x0 + ball * rng.standard_normal((int(bad.sum()), ndim))
        else:
            raise ValueError("could not place the walkers: the log-posterior is -inf around the start")
        sampler.random_state = np.random.RandomState(seed).get_state()
    tau = np.full(ndim, np.inf)
    converged = False
    while True:
        it = sampler.iteration
        if it > 0:
            chain = sampler.get_chain()
            tau = emcee.autocorr.integrated_time(chain, tol=0)
            # stable: tau of the chain one chunk shorter agrees within 5 % (also right after a resume)
            prev = emcee.autocorr.integrated_time(chain[: it - check_every], tol=0) if it > check_every else np.inf
            stable = np.all(np.abs(tau - prev) < 0.05 * tau)
            t = float(np.max(tau))
            burn = int(2 * t)
            ess = nwalkers * (it - burn) / max(t, 1.0)
            converged = bool(it > 50 * t and stable and np.all(np.isfinite(tau)))
            if progress:
                progress(Sampling(it, t, ess))
            if (converged and ess >= min_ess and it >= min_steps) or it >= max_steps:
                break
        steps = min(check_every, max_steps - it)
        sampler.run_mcmc(state, steps, progress=False)
        if hdf is not None:
            hdf.persist()
        state = None
    t = float(np.max(tau))
    burn = min(int(2 * t), sampler.iteration - 1)
    chain = sampler.get_chain(discard=burn, flat=True)
    return Posterior(chain, tau, int(sampler.iteration), nwalkers, burn, converged, time.perf_counter() - t0,
                     float(np.mean(sampler.acceptance_fraction)), sampler.get_log_prob(discard=burn, flat=True))


def gaussian_moments_check(mean, cov, **kwargs) -> Posterior:
    """Sample a Gaussian truncated to [0, 1]^d (for tests/benchmarks of :func:`sample`)."""
    mean, prec = np.asarray(mean, float), np.linalg.inv(np.asarray(cov, float))

    def log_prob(x):
        d = x - mean
        inside = np.all((x >= 0) & (x <= 1), axis=1)
        return np.where(inside, -0.5 * np.einsum("ij,jk,ik->i", d, prec, d), -np.inf)

    return sample(log_prob, mean, **kwargs)
