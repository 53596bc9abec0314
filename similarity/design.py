"""Which dam-break setup to run next (section 6): the candidate whose loss normal is most
perpendicular to the normals of the setups already done.

All 2601 candidates (20..70 mm, 1 mm steps; height outer, width inner) are scored at once. A
candidate is valid when Theta's plane-Poiseuille setup flows, P L > sigma_y. The first minimum of
S_p in candidate order wins ties (the authors' strict "<" scan). ``least_perpendicular_setup`` is
the ablation of the paper's Fig. 10(d): the candidate with the *largest* S_p among those at least
``min_distance_mm`` away from every setup already done (the paper asks for "distant" setups without
a number; 10 mm is our choice).

``criterion="eig"`` ranks the same candidates by expected information gain instead (beyond the
paper), in a linear-Gaussian (Laplace) approximation in the normalised material space:

* the current posterior is Gaussian with covariance Sigma (from an emcee posterior, or, without one,
  the Laplace posterior implied by the setups done: Sigma^-1 = 12 I + c sum_done H^_d, 12 I being the
  precision of the uniform prior on [0, 1]^3);
* a setup s adds the Fisher information F_s = c H^_s, where H^_s = A H A / tr(A H A) is the
  plane-Poiseuille loss Hessian of s (eqs. 29-42, through Theta) in the normalised space scaled to
  unit trace: its *shape* says which direction s pins down, and one scale c is shared by all setups;
* c is fitted to the posterior: the least-squares c with Sigma^-1 ~= c sum_done H^_d (Frobenius
  norm), i.e. a new setup is assumed to be as informative as the ones done were on average;
  without a posterior c = ``information_scale``;
* EIG(s) = 1/2 log det(I + Sigma F_s) nats, exact for a linear-Gaussian model.

``criterion="information"`` (:func:`similarity.simulated_design.rank_by_simulation`) asks the simulator instead of
the plane-Poiseuille model: the 16 setups of :func:`similarity.information.grid_setups` are scored by the log det
gain of their FD loss Hessians at the current estimate (sequential D-optimal design,
:func:`similarity.information.predicted_gains`), 19 simulations per setup. It sees how much a setup pins down as
well as which direction, which the Theta-based criteria do not (docs/uncertainty.md, "Does the design pay off?").

A setup done in which Theta's plane-Poiseuille setup does not flow at the material (P L <= sigma_y: a thin box and
a yield stress) has no loss normal and no Hessian.  The Theta-based criteria leave it out, with a line in
``Ranking.notes``; when no setup done is left, perpendicularity has nothing to be perpendicular to and raises
ValueError, while ``eig`` ranks from the prior.  Candidates with no flow, or a non-finite normal or gain, are not
valid.  Every failure is a one-line ValueError.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mpm.files import JsonRecord
from mpm.params import SETUP_RANGE_MM, Material, Setup
from surrogate.theta import ThetaMap, load

from poiseuille import hessian

from .belief import PRIOR_PRECISION
from .normals import loss_normals, perpendicularity, top_eigenvector
from .progress import first_line
from .space import EXTENT, candidate_setups

CRITERIA = ("perpendicularity", "eig")  # Theta-based, no simulation; "information": similarity.simulated_design
DEFAULT_INFORMATION_SCALE = 1.0e4  # c without a posterior: a setup pins its normal to ~1 % of the box


def estimation_cpu_minutes(facts: dict, setups, generations: int) -> float | None:
    """CPU minutes of one stage of Algorithm 1 (``generations`` x POPSIZE candidates) on ``setups`` at the model the
    ``facts`` were measured with; None when a setup was not measured."""
    from .cma_stage import POPSIZE

    per = [facts.get(str(s)) for s in setups]
    if any(f is None for f in per):
        return None
    return generations * POPSIZE * sum(f.cpu_seconds for f in per) / 60.0


@dataclass
class Candidate(JsonRecord):
    """One of the best candidates as `virheo design` and the report show it."""

    setup: str
    score: float
    volume_ml: float  # W x H x 40 mm
    cost_cpu_min: float | None  # an estimation stage with it at the criterion's model (None: not simulated)
    runout_mm: float | None  # flow of its footage at the estimate (None: not simulated)
    flags: list | None  # SetupFacts.flags (None: not simulated)


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
    criterion: str = "perpendicularity"  # "eig": expected information gain in nats; "information": log det gain
    information: np.ndarray | None = None  # "eig": Fisher information F_s (k, 3, 3) per candidate
    covariance: np.ndarray | None = None  # "eig": the current posterior covariance Sigma
    notes: tuple = ()  # one line per setup done that was left out (no normal at this material), or a fallback taken
    facts: dict | None = None  # "information": str(setup) -> SetupFacts of the setups done and the candidates
    check: object | None = None  # "information" with a posterior: its similarity.simulated_design.InformationCheck

    @property
    def nats(self) -> bool:
        """Whether the score is an expected information gain in nats (else a unitless score, or S_p): ``eig``'s, and
        ``information``'s with a posterior whose nats the simulated Hessians were calibrated to."""
        return self.criterion == "eig" or (self.check is not None and self.check.scale is not None)

    def __len__(self) -> int:
        return len(self.score)

    @property
    def higher_is_better(self) -> bool:
        return self.criterion != "perpendicularity"

    def best(self) -> tuple[Setup, float]:
        """(setup, score) of the best candidate: the first minimum of S_p, or the first maximum of the gain."""
        i = int(np.nanargmax(self.score)) if self.higher_is_better else int(np.argmin(self.score))
        return Setup(float(self.width_mm[i]), float(self.height_mm[i])), float(self.score[i])

    def setups(self) -> list[Setup]:
        return [Setup(float(w), float(h)) for w, h in zip(self.width_mm, self.height_mm)]

    def order(self) -> np.ndarray:
        """Candidate indices, best first."""
        return np.argsort(-self.score if self.higher_is_better else self.score, kind="stable")

    def costs(self, generations: int) -> list:
        """Per candidate, the CPU minutes of an estimation stage on the setups done and it
        (:func:`estimation_cpu_minutes`); None where not measured (every entry without ``facts``)."""
        if self.facts is None:
            return [None] * len(self)
        return [estimation_cpu_minutes(self.facts, [*self.done, c], generations) for c in self.setups()]

    def top(self, k: int, generations: int) -> list[Candidate]:
        """The ``k`` best candidates with the material they need, their estimation cost (``generations`` per stage)
        and, where simulated, the flow of their footage at the estimate."""
        setups, costs = self.setups(), self.costs(generations)
        out = []
        for i in self.order()[:k]:
            s = setups[i]
            facts = None if self.facts is None else self.facts.get(str(s))
            out.append(Candidate(str(s), float(self.score[i]), round(s.volume_ml(), 1),
                                 None if costs[i] is None else round(float(costs[i]), 2),
                                 None if facts is None else round(facts.runout_mm, 1),
                                 None if facts is None else facts.flags()))
        return out

    def subset(self, keep, note: str | None = None) -> "Ranking":
        """The candidates where ``keep`` (a boolean array) holds; ValueError when none is left."""
        from dataclasses import replace

        keep = np.asarray(keep, bool)
        if not keep.any():
            raise ValueError(f"no candidate setup is left{': ' + note if note else ''}")
        return replace(self, width_mm=self.width_mm[keep], height_mm=self.height_mm[keep], score=self.score[keep],
                       normals=self.normals[keep],
                       information=None if self.information is None else self.information[keep],
                       notes=self.notes + ((note,) if note and not keep.all() else ()))

    def grid(self) -> np.ndarray:
        """S_p on the 51 x 51 candidate grid, rows = height, columns = width; NaN where invalid."""
        lo, hi = SETUP_RANGE_MM
        size = hi - lo + 1
        out = np.full((size, size), np.nan)
        out[(self.height_mm - lo).astype(int), (self.width_mm - lo).astype(int)] = self.score
        return out


def _material(material) -> Material:
    return Material.of(material).check_in_space()


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


def no_flow_note(setup) -> str:
    """The line that says why a setup done is left out of a Theta-based criterion."""
    return f"no plane-Poiseuille flow in {setup} at this estimate: its normal is undefined"


def done_normals(material, done, theta, variant: str = "scaled") -> tuple[np.ndarray, tuple]:
    """(loss normals (m, 3) of the setups done that have one, a :func:`no_flow_note` per setup left out)."""
    q, valid = loss_normals(material, np.array([s.width_mm for s in done]), np.array([s.height_mm for s in done]),
                            theta, variant)
    valid &= np.all(np.isfinite(q), axis=-1)
    return q[valid], tuple(no_flow_note(s) for s, ok in zip(done, valid) if not ok)


def _no_candidate(material) -> ValueError:
    return ValueError(f"no candidate setup makes {material} flow in Theta's plane-Poiseuille model")


def unit_hessians(material, width_mm, height_mm, theta):
    """(H^ = A H A / tr(A H A) (k, 3, 3) of the plane-Poiseuille loss for setups, their validity (P L > sigma_y),
    their loss normals (k, 3): the top eigenvectors of the same A H A, ``variant="scaled"``)."""
    m = _material(material).as_array()
    P, L = theta.pl(m[0], m[1], m[2], np.asarray(width_mm, float), np.asarray(height_mm, float))
    valid = P * L > m[2]
    h = hessian(m[0], m[1], m[2], P, L) * EXTENT[:, None] * EXTENT[None, :]  # A H A, eqs. 29-42
    tr = np.trace(h, axis1=-2, axis2=-1)
    valid &= tr > 0
    return h / np.where(valid, tr, 1.0)[..., None, None], valid, top_eigenvector(h)


def expected_information_gain(covariance, fisher) -> np.ndarray:
    """EIG = 1/2 log det(I + Sigma F) in nats, for one Sigma (d, d) and Fisher matrices F (..., d, d)."""
    cov = np.asarray(covariance, float)
    f = np.asarray(fisher, float)
    m = np.eye(cov.shape[0]) + cov @ f
    sign, logdet = np.linalg.slogdet(m)
    return 0.5 * np.where(sign > 0, logdet, np.nan)


def information_scale(covariance, done_hessians) -> float:
    """Least-squares c with Sigma^-1 ~= c sum_d H^_d (Frobenius); positive."""
    g = np.sum(np.asarray(done_hessians, float), axis=0)
    prec = np.linalg.inv(np.asarray(covariance, float))
    c = float(np.sum(prec * g) / np.sum(g * g))
    if not np.isfinite(c) or c <= 0:
        raise ValueError("the posterior covariance is not explained by the setups done (no positive information scale)")
    return c


def _rank_eig(material, done, theta, covariance, scale) -> Ranking:
    wd = np.array([s.width_mm for s in done])
    hd = np.array([s.height_mm for s in done])
    h_done, ok_done, q_done = unit_hessians(material, wd, hd, theta)
    notes = [no_flow_note(s) for s, ok in zip(done, ok_done) if not ok]
    h_done, q_done = h_done[ok_done], q_done[ok_done]  # a setup without flow adds no information: left out
    if covariance is None:
        c = float(scale) if scale is not None else DEFAULT_INFORMATION_SCALE
        covariance = np.linalg.inv(PRIOR_PRECISION * np.eye(3) + c * h_done.sum(axis=0))
    else:
        covariance = np.asarray(covariance, float)
        if covariance.shape != (3, 3) or not np.all(np.isfinite(covariance)):
            raise ValueError("covariance must be a finite 3 x 3 matrix (normalised material space)")
        c = float(scale) if scale is not None else None
        if c is None and len(h_done):
            try:
                c = information_scale(covariance, h_done)
            except ValueError as exc:
                notes.append(f"{first_line(exc)}: the default scale {DEFAULT_INFORMATION_SCALE:g} is used")
        elif c is None:
            notes.append(f"no setup done has plane-Poiseuille flow to fit the information scale to: the default "
                         f"scale {DEFAULT_INFORMATION_SCALE:g} is used")
        c = DEFAULT_INFORMATION_SCALE if c is None else c
    width, height = candidate_setups()
    h, valid, q = unit_hessians(material, width, height, theta)
    eig = np.full(len(width), np.nan)
    eig[valid] = expected_information_gain(covariance, c * h[valid])
    valid &= np.isfinite(eig) & np.all(np.isfinite(q), axis=-1)
    if not np.any(valid):
        raise _no_candidate(material)
    return Ranking(material, done, width[valid], height[valid], eig[valid], q[valid], q_done, "eig", c * h[valid],
                   covariance, tuple(notes))


def rank_setups(material, done, theta="reference", variant: str = "scaled", criterion: str = "perpendicularity",
                covariance=None, information_scale: float | None = None) -> Ranking:
    """Score every valid candidate setup (vectorised over all 2601) against the setups ``done``.

    ``criterion="perpendicularity"`` (default, section 6): S_p, lower is better.  ``criterion="eig"``:
    expected information gain in nats, higher is better (module docstring), from the posterior
    ``covariance`` in the normalised space when given.
    """
    if criterion not in CRITERIA:
        raise ValueError(f"criterion='{criterion}' must be one of {', '.join(CRITERIA)}")
    if criterion == "eig":
        theta = theta if isinstance(theta, ThetaMap) else load(theta)
        return _rank_eig(_material(material), _setups(done), theta, covariance, information_scale)
    material = _material(material)
    done = _setups(done)
    theta = theta if isinstance(theta, ThetaMap) else load(theta)
    q_done, notes = done_normals(material, done, theta, variant)
    if not len(q_done):
        raise ValueError(f"{'; '.join(notes)}, so perpendicularity (section 6) has nothing to be perpendicular to")
    width, height = candidate_setups()
    q, valid = loss_normals(material, width, height, theta, variant)
    valid &= np.all(np.isfinite(q), axis=-1)
    if not np.any(valid):
        raise _no_candidate(material)
    q = q[valid]
    return Ranking(material, done, width[valid], height[valid], perpendicularity(q_done, q), q, q_done, notes=notes)


def next_setup(material, done, theta="reference", criterion: str = "perpendicularity", covariance=None) -> Setup:
    """The next setup: the valid candidate whose loss normal is most perpendicular to those of ``done``
    (or, with ``criterion="eig"``, the one of largest expected information gain)."""
    return rank_setups(material, done, theta, criterion=criterion, covariance=covariance).best()[0]


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
