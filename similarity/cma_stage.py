"""One CMA-ES stage of Algorithm 1 (pycma, elitist, IPOP restarts), resumable, and its warm start.

A stage minimises the mean video loss (eq. 3) over its experiments in the normalised material space
[0, 1]^3 within a budget of ``generations x POPSIZE`` candidate draws, and returns the best candidate it
evaluated.  CMA-ES samples in the stage's search coordinates (:data:`similarity.space.SEARCH_SPACES`); every
candidate, mean and archive row it records is in the normalised space.  Its :class:`StageState` is checkpointed
in the store after every generation.
"""
from __future__ import annotations

import time
import warnings
from dataclasses import asdict, dataclass, field, fields
from typing import Callable, Sequence

import cma
import numpy as np

from mpm.files import JsonRecord, digest
from mpm.forward import Forward, ForwardModel
from mpm.params import Material
from similarity.presets import setup_of
from similarity.space import denormalize, from_search, normalize, to_search
from similarity.progress import GenerationDone, StageStarted, simulation_tick

POPSIZE = 7  # 4 + floor(3 ln 3) for 3 parameters
RESAMPLE = 3  # rounds of redrawing NaN candidates (failed simulations) within one generation
CMA_ELITIST = True  # the loss is deterministic: the best point so far stays in the population
STALL_DRAWS = 20 * POPSIZE  # IPOP restart when the run's best loss has not improved for this many draws
TOLX = 1e-3  # a run has converged when its steps are below 0.1 % of the box (pycma's default never fires)
WARM_START_SPACING = 0.03  # minimum distance in [0, 1]^3 between re-scored candidates of the previous stage
STATE_VERSION = 1  # of StageState; checkpoints of another version belong to another stage id


@dataclass
class Generation(JsonRecord):
    """One generation of a stage, as its history records it (result.json writes it as an object)."""

    generation: int  # CMA-ES iterations so far (all restarts)
    simulations: int  # simulations of the stage so far
    best_loss: float  # best loss of the stage so far
    best_x: list[float] | None  # its candidate (normalised); None while every simulation failed
    mean_x: list[float]  # the current run's mean
    sigma: float  # the current run's step size (in the stage's search coordinates)
    drawn: int  # candidate draws of the stage so far (its budget counts these)
    restarts: int  # IPOP restarts so far
    run_best: float  # best loss of the current run


def _generations(history) -> list[Generation]:
    """A history as :class:`Generation` values, also one of dicts (result.json, checkpoints before this type)."""
    return [h if isinstance(h, Generation) else Generation.from_dict(h) for h in history]


@dataclass
class Stage:
    """Result of one CMA-ES stage (all setups so far, or the finishing stage)."""

    setups: list[str]
    x0: list[float]
    sigma0: float
    material: Material
    loss: float
    evaluations: int  # candidate evaluations (each costs len(setups) simulations)
    simulations: int
    generations: int  # budget spent, in generations of POPSIZE draws (what the progress bar counts)
    model: ForwardModel  # the stage's forward model, its solver defaults filled in
    history: list[Generation] = field(default_factory=list)  # per generation: simulations, best loss, best x, ...
    next_setup: str | None = None
    wall_seconds: float = 0.0
    archive: list[list[float]] = field(default_factory=list)  # every finite evaluation: [x0, x1, x2, loss]
    screened: list[list[float]] = field(default_factory=list)  # warm start: [x0, x1, x2, loss on these setups]
    finish: bool = False  # the coarse-to-fine finishing stage
    cma_iterations: int = 0  # CMA-ES iterations over all restarts (fewer than ``generations`` once populations grow)
    search_space: str = "linear"  # the coordinates CMA-ES sampled in (x0 and history stay normalised)
    shape: list[list[float]] | None = None  # the start's covariance shape (search coordinates, largest axis 1); None: I
    end_shape: list[list[float]] | None = None  # the last CMA-ES run's covariance shape at the end (the next stage's start)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["material"] = self.material.to_dict()
        d["model"] = self.model.to_dict()
        d.pop("archive")  # hundreds of rows; the history keeps the path
        if self.search_space == "linear":  # the paper's coordinates: records name only another space
            d.pop("search_space")
        for key in ("shape", "end_shape"):
            if d[key] is None:  # records before covariance shapes read the same
                d.pop(key)
        return d

    @classmethod
    def from_dict(cls, data: dict) -> "Stage":
        """A stage as result.json holds it (:meth:`to_dict`; its model also in the layout before the seam)."""
        names = {f.name for f in fields(cls)} - {"material", "model", "history"}
        return cls(**{k: data[k] for k in names if k in data}, material=Material(**data["material"]),
                   model=ForwardModel.of_record(data), history=_generations(data.get("history", [])))

    def __setstate__(self, state: dict) -> None:
        """Unpickle, also a stage checkpointed before the model was one field (its four loose fields) or before
        its history was typed (dicts)."""
        if "model" not in state:
            loose = {k: state.pop(k) for k in ("cell_mm", "ppc", "slip_length_m", "density_correction") if k in state}
            state["model"] = ForwardModel(**loose)
        state["history"] = _generations(state.get("history", []))
        self.__dict__.update(state)


@dataclass
class StageState:
    """Everything a stage needs to resume after a kill (pickled in the store after every generation)."""

    es: cma.CMAEvolutionStrategy
    evaluations: int
    simulations: int
    screened: list[list[float]]
    best_x: np.ndarray | None = None
    best_loss: float = np.inf
    drawn: int = 0  # candidate draws of the stage (its budget counts these)
    generation: int = 0
    restarts: int = 0
    restart_drawn: int = 0  # draws when the current run started
    run_best: float = np.inf  # best loss of the current run
    wall_seconds: float = 0.0
    history: list[Generation] = field(default_factory=list)
    archive: list[list[float]] = field(default_factory=list)
    result: Stage | None = None
    version: int = STATE_VERSION
    search_space: str = "linear"
    shape: np.ndarray | None = None  # every CMA-ES run's initial covariance shape (None: identity)

    def __setstate__(self, state: dict) -> None:
        """Unpickle, also a checkpoint written before the history was typed (dicts): it resumes."""
        state["history"] = _generations(state.get("history", []))
        self.__dict__.update(state)

    def offer(self, x: np.ndarray, loss: float) -> None:
        if loss < self.best_loss:
            self.best_loss, self.best_x = float(loss), np.asarray(x, float).copy()


class Objective:
    """Mean video loss over the stage's experiments for a batch of normalised candidates (NaN if any failed)."""

    def __init__(self, experiments, model: ForwardModel, forward: Forward, progress):
        self.experiments = list(experiments)
        self.exp_ids = [forward.experiment_id(e) for e in self.experiments]
        self.model = model.resolved()
        self.forward, self.progress = forward, progress

    @staticmethod
    def material(x) -> Material:
        return Material.from_array(denormalize(np.clip(x, 0.0, 1.0)))

    def requests(self, x):
        return [self.forward.request(self.material(x), e, self.model) for e in self.experiments]

    def __call__(self, X) -> np.ndarray:
        losses = self.forward.losses([self.material(x) for x in X], self.experiments, self.model,
                                     on_result=simulation_tick(self.progress))
        return losses.mean(axis=1)


def _generations_key(generations: float):
    """A stage's budget in its id: whole generations as the int they always were, a fraction as a float."""
    g = float(generations)
    return int(g) if g.is_integer() else g


def _stage_id(objective: Objective, x0, sigma0, seed, generations, search_space: str, shape) -> str:
    space = {} if search_space == "linear" else {"search_space": search_space}  # linear: the ids before the option
    if shape is not None:
        space["shape"] = [round(float(v), 9) for v in np.ravel(shape)]
    return digest(space | {
        "experiments": objective.exp_ids, "x0": [float(v) for v in x0], "sigma0": float(sigma0), "seed": int(seed),
        "generations": _generations_key(generations), "popsize": POPSIZE, "elitist": CMA_ELITIST,
        "restarts": f"ipop/{STALL_DRAWS}/{TOLX}", "state": STATE_VERSION,
        "forward": [r.to_dict() | {"eta": 0, "n": 0, "sigma_y": 0} for r in objective.requests(np.asarray(x0))],
    })[:32]


def _strategy(x0, sigma0: float, popsize: int, seed: int, shape=None) -> cma.CMAEvolutionStrategy:
    """pycma's strategy from mean ``x0`` with step ``sigma0``, both in search coordinates, and initial covariance
    sigma0^2 ``shape`` (a symmetric positive definite matrix; None: the identity)."""
    options = {
        "bounds": [0.0, 1.0], "popsize": popsize, "verbose": -9, "CMA_elitist": CMA_ELITIST, "tolx": TOLX,
        "maxiter": np.inf,  # the stage's budget of draws ends it
        "randn": np.random.RandomState(seed).randn, "seed": np.nan,  # private RNG: pickled with the strategy
        "tolflatfitness": 10**9,  # flat silhouettes early on must not end the run
    }
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        es = cma.CMAEvolutionStrategy([float(v) for v in x0], float(sigma0), options)
    if shape is not None:
        es.sm.C = np.array(shape, dtype=float)  # pycma keeps C in its sampler; decomposed before the first draw
        es.sm._decompose_C()
    return es


def covariance_shape(es: cma.CMAEvolutionStrategy) -> list[list[float]]:
    """The covariance of ``es``'s sampling distribution scaled to a largest axis of 1 (search coordinates)."""
    C = np.asarray(es.sm.C, dtype=float)
    return (C / np.linalg.eigvalsh(C).max()).tolist()


def _stalled(state: StageState) -> bool:
    """True when the current run's best loss has not improved over its last ``STALL_DRAWS`` draws."""
    recent = [h for h in state.history if h.drawn > state.restart_drawn]
    old = [h.run_best for h in recent if h.drawn <= state.drawn - STALL_DRAWS]
    return bool(old) and not recent[-1].run_best < old[-1]


def _restart(state: StageState, x0, sigma0: float, seed: int) -> None:
    """IPOP restart (Auger & Hansen 2005): the stage's initial distribution again with twice the population."""
    state.restarts += 1
    state.es = _strategy(to_search(x0, state.search_space), sigma0, POPSIZE * 2**state.restarts,
                         seed + 7919 * state.restarts, state.shape)
    state.restart_drawn, state.run_best = state.drawn, np.inf


def _generation(state: StageState, objective: Objective, budget: int) -> None:
    """Draw, evaluate (redrawing failed candidates) and tell one generation."""
    es, space = state.es, state.search_space
    left = budget - state.drawn  # the budget's last draws may not fill a generation: sampled, never told
    U = [np.asarray(u, float) for u in (es.ask() if left >= es.popsize else es.ask(left))]  # search coordinates
    X = [from_search(u, space) for u in U]
    state.drawn += len(X)
    F = objective(X)
    evaluations = len(X)
    for _ in range(RESAMPLE):
        bad = np.flatnonzero(~np.isfinite(F))
        if bad.size == 0:
            break
        for i in bad:
            U[i] = np.asarray(es.ask(1)[0], float)
            X[i] = from_search(U[i], space)
        F[bad] = objective([X[i] for i in bad])
        evaluations += bad.size
    finite = np.isfinite(F)
    state.archive.extend([float(v) for v in np.clip(x, 0.0, 1.0)] + [float(f)] for x, f in zip(X, F) if np.isfinite(f))
    if finite.any():
        i = int(np.argmin(np.where(finite, F, np.inf)))
        state.run_best = min(state.run_best, float(F[i]))
        state.offer(X[i], F[i])
    if finite.sum() >= 2 and len(X) == es.popsize:  # else nothing to learn: the distribution stays as it is
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # pycma warns when it replaces NaN by the median of the finite values
            es.tell(U, [float(f) if np.isfinite(f) else np.nan for f in F])
    state.generation += 1
    state.evaluations += evaluations
    state.simulations += evaluations * len(objective.experiments)
    state.history.append(Generation(
        generation=state.generation, simulations=state.simulations, best_loss=state.best_loss,
        best_x=None if state.best_x is None else [float(v) for v in state.best_x],
        mean_x=[float(v) for v in from_search(es.mean, space)], sigma=float(es.sigma),
        drawn=state.drawn, restarts=state.restarts, run_best=state.run_best,
    ))


def run_stage(experiments, *, x0, sigma0: float, model: ForwardModel, seed: int, generations: float, forward: Forward,
              progress: Callable[[dict], None] | None = None, stage_index: int = 1,
              screened: Sequence[Sequence[float]] = (), screened_simulations: int | None = None,
              finish: bool = False, search_space: str = "linear", shape=None) -> Stage:
    """One CMA-ES run on ``experiments`` from mean ``x0`` (normalised) with step ``sigma0`` (in the
    ``search_space`` coordinates, :data:`similarity.space.SEARCH_SPACES`) and initial covariance shape ``shape``
    (e.g. the previous stage's ``end_shape``; None: isotropic); resumable.

    ``generations``: the budget, ``generations x POPSIZE`` candidate draws (rounded); a fraction of a generation ends
    the stage on a partial last one.
    ``screened``: rows [x0, x1, x2, loss] already evaluated on these experiments (:func:`warm_start`);
    they count as the stage's evaluations (``screened_simulations`` new simulations, by default one each)
    and compete for its best candidate.
    """
    t0 = time.perf_counter()
    objective = Objective(experiments, model, forward, progress)
    store = forward.store
    run_id = _stage_id(objective, x0, sigma0, seed, generations, search_space, shape)
    state = store.load_checkpoint(run_id)
    if isinstance(state, StageState) and state.result is not None:
        return state.result
    if not isinstance(state, StageState):
        sims = len(screened) if screened_simulations is None else int(screened_simulations)
        state = StageState(es=_strategy(to_search(x0, search_space), sigma0, POPSIZE, seed, shape),
                           evaluations=len(screened), simulations=sims, screened=[list(r) for r in screened],
                           search_space=search_space, shape=None if shape is None else np.array(shape, dtype=float))
        for r in screened:
            if np.isfinite(r[3]):
                state.offer(np.asarray(r[:3], float), r[3])
    setups = [str(setup_of(e)) for e in experiments]
    if progress:
        progress(StageStarted(stage_index, setups, generations, state.drawn // POPSIZE))
    budget = round(generations * POPSIZE)  # candidate draws per stage, whatever the restarts' population
    while state.drawn < budget:
        if state.es.stop() or _stalled(state):
            _restart(state, x0, sigma0, seed)
        _generation(state, objective, budget)
        state.wall_seconds += time.perf_counter() - t0
        t0 = time.perf_counter()
        store.save_checkpoint(run_id, state)
        if progress:
            progress(GenerationDone(stage_index, state.drawn // POPSIZE, generations, state.best_loss))
    if state.best_x is None:
        raise RuntimeError(f"every simulation failed in stage {stage_index} ({', '.join(setups)})")
    state.result = Stage(
        setups=setups, x0=[float(v) for v in x0], sigma0=float(sigma0),
        material=Material.from_array(denormalize(np.clip(state.best_x, 0, 1))), loss=state.best_loss,
        evaluations=state.evaluations, simulations=state.simulations, generations=state.drawn // POPSIZE,
        model=objective.model, history=state.history,
        wall_seconds=state.wall_seconds + time.perf_counter() - t0, archive=state.archive, screened=state.screened,
        finish=finish, cma_iterations=state.generation, search_space=search_space,
        shape=None if shape is None else np.asarray(shape, dtype=float).tolist(), end_shape=covariance_shape(state.es),
    )
    store.save_checkpoint(run_id, state)
    return state.result


def warm_start(previous: Stage, experiments, *, model: ForwardModel, forward: Forward, count: int = POPSIZE,
               min_distance: float = WARM_START_SPACING,
               progress: Callable[[dict], None] | None = None) -> tuple[np.ndarray, list[list[float]]]:
    """Start of the next stage: the previous stage's best distinct candidates re-scored on ``experiments``
    with ``model``, and the best of them.

    Picks the previous estimate, then the best candidates of its archive at least ``min_distance`` apart in
    [0, 1]^3 (topped up with the next best), ``count`` in all, and evaluates them (setups and models already
    simulated come from the store).  Returns (x0, [[x0, x1, x2, loss], ...]).
    """
    rows = sorted(previous.archive, key=lambda r: r[3])
    picked: list[np.ndarray] = [normalize(previous.material.as_array())]
    for spacing in (min_distance, 1e-9):  # spread out first; fill up with the next best if the valley is small
        for r in rows:
            x = np.asarray(r[:3], float)
            if len(picked) < count and min(np.linalg.norm(x - q) for q in picked) >= spacing:
                picked.append(x)
    F = Objective(experiments, model, forward, progress)(picked)
    if not np.isfinite(F).any():
        return picked[0], []
    best = int(np.argmin(np.where(np.isfinite(F), F, np.inf)))
    return picked[best], [[float(v) for v in x] + [float(f)] for x, f in zip(picked, F)]
