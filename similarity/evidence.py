"""Evidence of Herschel-Bulkley and its special cases, and the verdicts they support.

Eq. 1 holds three simpler laws as faces and an edge of the material space: Bingham (n = 1), the power law
(sigma_y = 0) and Newtonian (both).  Each law is the same model with coordinates fixed, so its prior is the
Herschel-Bulkley prior restricted: uniform, density 1 per unit of each free normalised coordinate
(:mod:`similarity.space`), and its likelihood is the same eq. (1) of :mod:`similarity.likelihood`.  The
evidence of a law with free coordinates z is

    Z = integral over the free coordinates of p(footage | z) dz,

the likelihood taken as nothing outside the emulator's trust region [lo, hi] (the caller grows that box until
every law's posterior lies inside it: :mod:`similarity.posterior`).  The Bayes factor of a law against a
special case of it is the Savage-Dickey ratio of the posterior density on the special case's face to the
prior's there, and equals Z_law / Z_case.

Method: importance sampling.  The proposal is a Gaussian mixture fitted (scikit-learn) to posterior samples of
the law (emcee, :func:`similarity.mcmc.sample`; for a special case, a zoomed grid over its face:
:func:`face_posterior`), its covariances widened by ``WIDEN`` and mixed with a uniform share ``DEFENSIVE`` over
the box, which bounds the weights.  With N draws,
Z ~ mean(w), w = p(footage | z) / q(z), and its Monte Carlo error is the weights' standard error
(``log_z_err`` = std(w) / (mean(w) sqrt(N))).

Verdicts: natural-log Bayes factors on the Jeffreys scale (Kass and Raftery's table in ln units); a question is
resolved when |ln BF| reaches ``RESOLVED`` = ln 10.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
from scipy.special import logsumexp

from mpm.files import JsonRecord
from mpm import laws as law_table
from mpm.params import Material
from similarity.space import LOWER, denormalize, normalize

DRAWS = 8000  # importance draws per law (error about 0.01 in ln Z on the closed-form Gaussian: bench_evidence.py)
WIDEN = 1.5  # the proposal's standard deviations over the posterior samples'
DEFENSIVE = 0.1  # the proposal's uniform share over the box
COMPONENTS = 3  # the proposal's Gaussian components at most
RESOLVED = float(np.log(10.0))  # |ln BF| at which a question is resolved: a factor of 10 (Jeffreys: strong)
# Jeffreys' scale in natural-log units: the least |ln BF| of each grade, strongest first
JEFFREYS = ((float(np.log(100.0)), "decisive"), (float(np.log(10.0**1.5)), "very strong"), (RESOLVED, "strong"),
            (float(np.log(10.0**0.5)), "substantial"), (0.0, "barely worth mentioning"))
ADVERBS = {"decisive": "decisively", "very strong": "very strongly", "strong": "strongly",
           "substantial": "substantially", "barely worth mentioning": "barely"}


def _coordinate(index: int, value_si: float) -> float:
    """The normalised coordinate ``index`` of an SI value of that parameter."""
    x = np.array(LOWER, float)
    x[index] = value_si
    return float(normalize(x)[index])


@dataclass(frozen=True)
class Law:
    """Eq. 1 with some normalised coordinates fixed: ``fixed`` holds (coordinate, value) pairs."""

    name: str
    fixed: tuple
    description: str

    @property
    def free(self) -> tuple:
        held = {i for i, _ in self.fixed}
        return tuple(i for i in range(3) if i not in held)

    def embed(self, z) -> np.ndarray:
        """Free coordinates (k, len(free)) -> normalised materials (k, 3) on the law's face."""
        z = np.atleast_2d(np.asarray(z, float))
        x = np.empty((len(z), 3))
        x[:, list(self.free)] = z
        for i, v in self.fixed:
            x[:, i] = v
        return x

    def on_face(self, lo, hi) -> bool:
        """Whether the box [lo, hi] (normalised) reaches the law's face."""
        return all(lo[i] - 1e-12 <= v <= hi[i] + 1e-12 for i, v in self.fixed)


def _law(name: str, fixed_si: dict) -> Law:
    fixed = tuple((PARAMETERS.index(k), _coordinate(PARAMETERS.index(k), v)) for k, v in fixed_si.items())
    return Law(name, fixed, ", ".join(f"{k} = {v:g}" for k, v in fixed_si.items()) or "eq. 1")


PARAMETERS = ("eta", "n", "sigma_y")
LAWS = {name: _law(name, fixed) for name, fixed in law_table.LAWS.items()}
N_ONE, SIGMA_Y_ZERO = dict(LAWS["newtonian"].fixed)[1], dict(LAWS["newtonian"].fixed)[2]
REFERENCE = "herschel-bulkley"


def get_law(name: str) -> Law:
    try:
        return LAWS[name]
    except KeyError:
        raise ValueError(f"unknown law '{name}': choose from {', '.join(LAWS)}") from None


def parse_laws(text: str) -> tuple:
    """Comma-separated law names -> their :class:`Law` s, Herschel-Bulkley first (the reference, always in)."""
    names = [s.strip() for s in str(text).split(",") if s.strip()]
    laws = [get_law(n) for n in names]
    return tuple([LAWS[REFERENCE]] + [law for law in dict.fromkeys(laws) if law.name != REFERENCE])


@dataclass(kw_only=True)
class LawEvidence(JsonRecord):
    """The evidence of one law (module docstring)."""

    law: str
    log_z: float  # ln Z
    log_z_err: float  # Monte Carlo standard error of ln Z
    ess: float  # the importance weights' effective sample size
    draws: int
    best: Material  # the most likely material of the law among the draws
    best_log_likelihood: float

    READERS = {"best": lambda d: Material(**d)}


def strength(log_bf: float) -> str:
    """Jeffreys' grade of a Bayes factor's |ln BF| (``JEFFREYS``)."""
    for least, grade in JEFFREYS:
        if abs(log_bf) >= least:
            return grade
    return JEFFREYS[-1][1]


@dataclass(frozen=True)
class Question:
    """A yes/no question a pair of nested laws answers: ``general`` with the property, ``special`` without."""

    name: str
    general: str
    special: str
    yes: str  # the property held, in symbols
    no: str


QUESTIONS = (Question("yield stress", "herschel-bulkley", "power-law", "sigma_y > 0", "sigma_y = 0"),
             Question("shear thinning", "herschel-bulkley", "bingham", "n < 1", "n = 1"))


@dataclass(kw_only=True)
class Verdict(JsonRecord):
    """One question's answer: ln BF of the general law over its special case, its grade and the sentence."""

    question: str
    log_bf: float  # ln Z_general - ln Z_special: > 0 for the property
    log_bf_err: float
    strength: str  # Jeffreys' grade
    resolved: bool  # |ln BF| >= RESOLVED
    holds: bool | None  # the property held (None: not resolved)
    text: str


def verdict(question: Question, log_bf: float, log_bf_err: float, next_setup: str | None = None,
            filmed=()) -> Verdict:
    """The plain-words answer to ``question`` from ln BF (general over special); ``filmed``: the setups already run
    (a next setup among them is filmed again)."""
    grade = strength(log_bf)
    figure = f"log BF {log_bf:+.2f} ± {log_bf_err:.2f}"
    if abs(log_bf) >= RESOLVED:
        holds = log_bf > 0
        text = f"{question.name}: resolved, {question.yes if holds else question.no} {ADVERBS[grade]} ({figure})"
    else:
        holds = None
        again = "again" if next_setup in set(map(str, filmed)) else "next"
        film = f"film {next_setup} mm {again} (the design's next setup)" if next_setup else "film another setup"
        text = f"{question.name}: not resolved by these setups ({figure}, {grade}); {film}"
    return Verdict(question=question.name, log_bf=float(log_bf), log_bf_err=float(log_bf_err), strength=grade,
                   resolved=abs(log_bf) >= RESOLVED, holds=holds, text=text)


@dataclass(kw_only=True)
class EvidenceSummary(JsonRecord):
    """The laws' evidences, their posterior probabilities (equal prior odds) and the verdicts."""

    laws: list  # LawEvidence
    probabilities: dict  # law -> posterior probability among the laws computed
    verdicts: list  # Verdict
    trust_region: list  # [lo, hi] of the box the evidences were integrated over

    READERS = {"laws": lambda v: [LawEvidence.from_dict(d) for d in v],
               "verdicts": lambda v: [Verdict.from_dict(d) for d in v]}

    def of(self, law: str) -> LawEvidence | None:
        return next((e for e in self.laws if e.law == law), None)

    @property
    def most_probable(self) -> str:
        return max(self.probabilities, key=self.probabilities.get)


def summarise(evidences, lo, hi, next_setup: str | None = None, filmed=()) -> EvidenceSummary:
    """Probabilities and verdicts of the :class:`LawEvidence` s ``evidences`` (the questions whose two laws are there);
    ``filmed``: the setups already run."""
    by = {e.law: e for e in evidences}
    log_z = np.array([e.log_z for e in evidences])
    p = np.exp(log_z - logsumexp(log_z))
    verdicts = []
    for q in QUESTIONS:
        if q.general in by and q.special in by:
            g, s = by[q.general], by[q.special]
            verdicts.append(verdict(q, g.log_z - s.log_z, float(np.hypot(g.log_z_err, s.log_z_err)), next_setup,
                                    filmed))
    return EvidenceSummary(laws=list(evidences), probabilities={e.law: float(v) for e, v in zip(evidences, p)},
                           verdicts=verdicts, trust_region=[np.asarray(lo).tolist(), np.asarray(hi).tolist()])


# -- the integral -----------------------------------------------------------------------------------
def proposal(samples, lo, hi, seed: int = 0):
    """The importance proposal over the box [lo, hi] (module docstring): returns (draw(n, rng), log_q(z))."""
    from sklearn.mixture import GaussianMixture

    samples = np.atleast_2d(np.asarray(samples, float))
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    k = samples.shape[1]
    rng = np.random.default_rng(seed)
    fit_on = samples[rng.choice(len(samples), size=min(len(samples), 4000), replace=False)]
    width = np.maximum(hi - lo, 1e-12)
    floor = (1e-6 * width) ** 2  # a flat direction keeps a positive width
    components = max(1, min(COMPONENTS, len(fit_on) // (10 * (k + 1))))
    gmm = GaussianMixture(components, covariance_type="full", reg_covar=float(floor.min()), random_state=seed)
    gmm.fit(fit_on)
    means = gmm.means_
    covs = gmm.covariances_ * WIDEN**2 + np.diag(floor)[None]
    weights = gmm.weights_
    chol = np.linalg.cholesky(covs)
    inv = np.linalg.inv(covs)
    log_norm = -0.5 * (k * np.log(2 * np.pi) + np.linalg.slogdet(covs)[1])
    log_uniform = -float(np.sum(np.log(width)))

    def log_q(z):
        z = np.atleast_2d(z)
        d = z[:, None, :] - means[None]
        m = np.einsum("nci,cij,ncj->nc", d, inv, d)
        log_g = logsumexp(np.log(weights)[None] + log_norm[None] - 0.5 * m, axis=1)
        inside = np.all((z >= lo) & (z <= hi), axis=1)
        log_u = np.where(inside, log_uniform, -np.inf)
        return np.logaddexp(np.log1p(-DEFENSIVE) + log_g, np.log(DEFENSIVE) + log_u)

    def draw(n: int, rng):
        n_u = rng.binomial(n, DEFENSIVE)
        which = rng.choice(len(weights), size=n - n_u, p=weights)
        g = means[which] + np.einsum("nij,nj->ni", chol[which], rng.standard_normal((n - n_u, k)))
        u = lo + (hi - lo) * rng.random((n_u, k))
        return np.vstack([g, u])

    return draw, log_q


def importance_log_z(log_like: Callable, samples, lo, hi, *, draws: int = DRAWS, seed: int = 0):
    """ln of the integral of exp(``log_like``) over the box [lo, hi] (free coordinates; vectorised ``log_like``:
    (m, k) -> (m,)), by importance sampling from posterior ``samples``.  Returns (ln Z, its standard error,
    the weights' ESS, the draws, their log-likelihoods)."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    draw, log_q = proposal(samples, lo, hi, seed=seed)
    rng = np.random.default_rng([seed, 1])
    z = draw(draws, rng)
    inside = np.all((z >= lo) & (z <= hi), axis=1)
    ll = np.full(len(z), -np.inf)
    if inside.any():
        ll[inside] = log_like(z[inside])
    log_w = np.where(inside, ll - log_q(z), -np.inf)
    if not np.isfinite(log_w).any():
        raise ValueError("the likelihood vanishes on every importance draw: no evidence")
    log_z = float(logsumexp(log_w) - np.log(len(z)))
    w = np.exp(log_w - log_w.max())
    mean = w.mean()
    err = float(w.std(ddof=1) / (mean * np.sqrt(len(w))))
    ess = float(w.sum() ** 2 / np.sum(w * w))
    return log_z, err, ess, z, ll


FACE_CELLS = {1: 4096, 2: 128}  # a special law's face grid: cells per free coordinate, by how many are free
FACE_SAMPLES = 10000  # draws of a special law's posterior on its face (face_posterior)
FACE_LEVELS = 3  # grids at most: each zooms onto the cells of the one before that hold the posterior's mass


def face_cells(a, b, cells: int) -> tuple[np.ndarray, np.ndarray]:
    """The centres (m, k) of a grid of ``cells`` cells per coordinate over the box [a, b] of a face's k free
    coordinates, and the cells' widths (k,)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    h = (b - a) / cells
    axes = [a[i] + h[i] * (np.arange(cells) + 0.5) for i in range(len(a))]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, len(a)), h


def face_posterior(log_like: Callable, law: Law, lo, hi, *, seed: int = 0, samples: int = FACE_SAMPLES):
    """``samples`` draws (free coordinates) of ``law``'s posterior on its face of the box [lo, hi] (``log_like`` takes
    normalised materials (m, 3)).  A face has one or two free coordinates, so the posterior is computed on a grid of
    ``FACE_CELLS`` cell centres, zoomed (at most ``FACE_LEVELS`` grids) onto the cells whose weight exceeds 1e-12 of
    the total, one cell of margin each way, while that halves the grid's extent; the draws are cells drawn by weight,
    each placed uniformly in its cell.  Unlike a sampler started at one point it sees every mode on the face."""
    free = list(law.free)
    face_lo, face_hi = np.asarray(lo, float)[free], np.asarray(hi, float)[free]
    a, b = face_lo, face_hi
    for _ in range(FACE_LEVELS):
        z, h = face_cells(a, b, FACE_CELLS[len(free)])
        ll = log_like(law.embed(z))
        if not np.isfinite(ll).any():
            raise ValueError(f"the likelihood vanishes on the {law.name} face: no posterior there")
        w = np.exp(ll - np.max(ll))
        w /= w.sum()
        held = z[w > 1e-12]
        a_new, b_new = np.maximum(held.min(axis=0) - h, face_lo), np.minimum(held.max(axis=0) + h, face_hi)
        if np.all(b_new - a_new > 0.5 * (b - a)):
            break
        a, b = a_new, b_new
    rng = np.random.default_rng([seed, 11])
    pick = rng.choice(len(z), size=samples, p=w)
    return z[pick] + (rng.random((samples, len(free))) - 0.5) * h


def law_evidence(log_like: Callable, law: Law, lo, hi, *, samples=None, seed: int = 0, draws: int = DRAWS):
    """:class:`LawEvidence` of ``law`` over its face of the box [lo, hi] (normalised), with ``log_like`` the
    vectorised log-likelihood of normalised materials (m, 3); ``samples``: posterior samples on the face (normalised,
    full coordinates; sampled with :func:`face_posterior` when None).  Also returns the face's posterior samples
    (full coordinates), for the caller's check that the box holds them."""
    if not law.on_face(lo, hi):
        raise ValueError(f"the box does not reach the {law.name} face ({law.description})")
    free = list(law.free)
    if samples is None:
        z_post = face_posterior(log_like, law, lo, hi, seed=seed)
    else:
        z_post = np.atleast_2d(samples)[:, free]
    lo_f, hi_f = np.asarray(lo, float)[free], np.asarray(hi, float)[free]
    log_z, err, ess, z, ll = importance_log_z(lambda q: log_like(law.embed(q)), z_post, lo_f, hi_f, draws=draws,
                                              seed=seed)
    i = int(np.argmax(ll))
    best = Material.from_array(denormalize(law.embed(z[i])[0]))
    ev = LawEvidence(law=law.name, log_z=log_z, log_z_err=err, ess=ess, draws=len(z), best=best,
                     best_log_likelihood=float(ll[i]))
    return ev, law.embed(z_post)
