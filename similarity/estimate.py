"""ViRheometry (Algorithm 1): CMA-ES estimation of Herschel-Bulkley parameters from dam-break footage.

Stage k optimises the mean video loss (eq. 3) over the first k setups with pycma in the normalised
material space [0, 1]^3 (bounded, population 7).  Stage 1 starts at the centre of the space, stage k
at the previous estimate.  Step size: the paper's Sigma = (2/3)^(k-1) is in the authors' internal
[0, 10]^3 box (REFERENCE_SPEC 4.2), i.e. sigma0 = 0.1 * (2/3)^(k-1) in [0, 1]^3; a preset may scale
it (``Preset.sigma0``).  The strategy is pycma's elitist CMA-ES (``CMA_ELITIST``).  A stage's budget
is ``generations x 7`` candidate draws; when a run converges (``TOLX``) or stalls (``STALL_DRAWS``)
before the budget is spent, it restarts from the stage's start with twice the population (IPOP).
We return the best *evaluated* candidate over the whole stage, restarts included (the reference
returned the best of the last generation, REFERENCE_SPEC 4.2 / 7.11).

Failed simulations give NaN.  NaN candidates are resampled from the same search distribution
(``es.ask(1)``, up to ``RESAMPLE`` times); if some stay NaN, pycma's ``tell`` replaces them by the
median of the finite values (it warns), so one failure never stops a run.

Every simulation goes through :mod:`mpm.batch` and the :class:`mpm.store.Store`; the CMA-ES object
(with its private RandomState) is checkpointed after every generation.  Re-running the same call
after a kill resumes from the last checkpoint, serves the interrupted generation's finished
simulations from the store, and -- for a deterministic forward model -- ends with the same estimate.
"""
from __future__ import annotations

import time
import warnings
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import cma
import numpy as np

from mpm import batch
from mpm.store import Store, digest
from similarity.space import Material, Setup, center, denormalize, e_rel, normalize

POPSIZE = 7  # = 4 + floor(3 ln 3) for 3 parameters (REFERENCE_SPEC 4.2)
RESAMPLE = 3  # rounds of resampling NaN candidates within one generation
PAPER_SIGMA0 = 0.1  # Sigma = 1.0 in the reference's [0, 10]^3 box
# pycma's CMA_elitist: the best point so far stays in the population (the loss is deterministic). On the MPM it lifted
# the 6 x 3 emulation study from 5/18 to 8/18 good with two setups; on the tests' smooth toy model it converges early
# (docs/estimation.md, "Session 5")
CMA_ELITIST = True
# IPOP restarts within a stage's budget of generations x popsize draws: when pycma's stopping rules fire or the best
# loss has not improved for STALL_DRAWS draws, CMA-ES starts again from the stage's x0 and sigma0 with twice the
# population (docs/estimation.md, "Session 6")
STALL_DRAWS = 20 * POPSIZE
TOLX = 1e-3  # a run has converged when its steps are below 0.1 % of the box (pycma's default, 1e-11, never fires)
WARM_START_SPACING = 0.03  # minimum distance in [0, 1]^3 between re-scored candidates of the previous stage


@dataclass(frozen=True)
class Preset:
    """Accuracy/time trade-off: CMA-ES budget and the forward model's resolution."""

    name: str
    generations: int  # CMA-ES generations per stage (paper: 100)
    cell_mm: float | None  # MPM cell width (None: solver default)
    ppc: int | None = None  # particles per cell per axis (None: solver default)
    dim: int = 3
    sigma0: float = PAPER_SIGMA0  # stage-1 step size in [0, 1]^3; stage k uses sigma0 * (2/3)^(k-1)
    flow_rule: str = "paper"
    precision: str = "f32"
    popsize: int = POPSIZE


PRESETS = {
    # the paper's budget and discretisation: 100 generations x 7 per stage, 1.26 mm cells, 2 particles
    # per cell per axis (REFERENCE_SPEC 2.1, 2.3)
    "paper": Preset("paper", generations=100, cell_mm=1.26, ppc=2),
    # tuned for `virheo demo` on a 2-core CPU (docs/estimation.md, "Session 4"; costs in docs/performance.md)
    "quick": Preset("quick", generations=40, cell_mm=5.0, sigma0=0.2),
}


def get_preset(preset) -> Preset:
    if isinstance(preset, Preset):
        return preset
    try:
        return PRESETS[str(preset)]
    except KeyError:
        raise ValueError(f"unknown preset '{preset}': choose one of {', '.join(PRESETS)}") from None


# -- experiments ---------------------------------------------------------------------------------------
@dataclass
class EmulatedExperiment:
    """Experiment-like footage simulated from a known material (same fields as mpm.experiment.Experiment)."""

    name: str
    width_mm: float
    height_mm: float
    depth_mm: float
    density: float
    camera: object
    frames: np.ndarray
    truth: Material
    initial_material: dict | None = None
    path: Path | None = None
    warnings: list = field(default_factory=list)

    @property
    def setup(self) -> Setup:
        return Setup(self.width_mm, self.height_mm)


def setup_of(experiment) -> Setup:
    return Setup(float(experiment.width_mm), float(experiment.height_mm))


def _image_size(experiment) -> tuple[int, int]:
    frames = np.asarray(experiment.frames)
    return int(frames.shape[-1]), int(frames.shape[-2])


def simulation_request(material, experiment, preset: Preset, simulator: str, image_size=None):
    """The store/batch request that simulates ``material`` in ``experiment``'s setup and camera with ``preset``."""
    return batch.request_for(
        material, setup_of(experiment), density=float(experiment.density), depth_mm=float(experiment.depth_mm),
        camera=experiment.camera, cell_mm=preset.cell_mm, ppc=preset.ppc, dim=preset.dim, flow_rule=preset.flow_rule,
        precision=preset.precision, image_size=image_size or _image_size(experiment), simulator=simulator,
    )


def _default_camera():
    from mpm.camera import Camera

    return Camera.default()


def emulate(material: Material, setups: Sequence[Setup], *, density: float = 1000.0, camera=None,
            depth_mm: float = 40.0, preset="quick", store: Store | None = None, executor=None,
            simulator: str = batch.DEFAULT_SIMULATOR, image_size=(960, 540)) -> list[EmulatedExperiment]:
    """Footage of ``material`` in each setup, simulated with the preset's forward model (ground truth M*).

    ``camera``: a Camera (e.g. ``mpm.experiment.load(dir).camera``) or None for ``Camera.default()``.
    """
    preset = get_preset(preset)
    camera = camera if camera is not None else _default_camera()
    shells = [EmulatedExperiment(f"emulated_{Setup(s.width_mm, s.height_mm)}", float(s.width_mm), float(s.height_mm),
                                 float(depth_mm), float(density), camera, np.zeros((0, 0, 0), bool), material)
              for s in setups]
    reqs = [simulation_request(material, e, preset, simulator, image_size) for e in shells]
    results = batch.evaluate(reqs, store=store, executor=executor)
    for e, r in zip(shells, results):
        if not r.ok or r.silhouettes is None:
            raise RuntimeError(f"ground-truth simulation of {e.name} failed: {r.error}")
        e.frames = r.silhouettes
    return shells


# -- results -------------------------------------------------------------------------------------------
@dataclass
class Stage:
    """One CMA-ES stage of Algorithm 1 (all setups so far)."""

    setups: list[str]
    x0: list[float]
    sigma0: float
    material: Material
    loss: float
    evaluations: int  # candidate evaluations (each costs len(setups) simulations)
    simulations: int
    generations: int
    history: list[dict] = field(default_factory=list)  # per generation: simulations, best loss, best x
    next_setup: str | None = None
    wall_seconds: float = 0.0
    archive: list[list[float]] = field(default_factory=list)  # every finite evaluation: [x0, x1, x2, loss]
    screened: list[list[float]] = field(default_factory=list)  # warm start: [x0, x1, x2, loss on these setups]

    def to_dict(self) -> dict:
        d = asdict(self)
        d["material"] = self.material.to_dict()
        d.pop("archive")  # hundreds of rows; the history keeps the path
        return d


@dataclass
class Estimate:
    material: Material
    loss: float
    stages: list[Stage]
    evaluations: int
    simulations: int
    wall_seconds: float
    next_setup: Setup | None
    preset: str
    seed: int
    setups: list[str]

    def to_dict(self) -> dict:
        return {
            "estimate": self.material.to_dict(),
            "loss": self.loss,
            "setups": self.setups,
            "next_setup": None if self.next_setup is None else str(self.next_setup),
            "evaluations": self.evaluations,
            "simulations": self.simulations,
            "wall_seconds": self.wall_seconds,
            "preset": self.preset,
            "seed": self.seed,
            "stages": [s.to_dict() for s in self.stages],
        }


def propose_next_setup(material: Material, done: Sequence[Setup]) -> Setup | None:
    """Section 6: the setup whose loss normal is most perpendicular to those of ``done`` (issue 2)."""
    try:
        from similarity.design import next_setup
    except ImportError:
        warnings.warn("similarity.design is not available: no next setup proposed", RuntimeWarning, stacklevel=2)
        return None
    return next_setup(material, list(done))


# -- Algorithm 1 ---------------------------------------------------------------------------------------
class _Objective:
    """Mean video loss over the stage's experiments for a batch of normalised candidates."""

    def __init__(self, experiments, preset, simulator, store, executor, progress):
        self.experiments = list(experiments)
        self.exp_ids = [batch.experiment_id(e.frames, e.name) for e in self.experiments]
        self.preset, self.simulator = preset, simulator
        self.store, self.executor, self.progress = store, executor, progress
        self.simulations = 0

    def requests(self, x):
        m = Material.from_array(denormalize(np.clip(x, 0.0, 1.0)))
        return [simulation_request(m, e, self.preset, self.simulator) for e in self.experiments]

    def __call__(self, X) -> np.ndarray:
        jobs = []
        for x in X:
            for req, eid, e in zip(self.requests(x), self.exp_ids, self.experiments):
                jobs.append((req, eid, e.frames))
        self.simulations += len(jobs)
        tick = (lambda req, res, cached: self.progress({"event": "simulation", "cached": cached})) if self.progress else None
        losses = batch.evaluate_losses(jobs, store=self.store, executor=self.executor, on_result=tick)
        return losses.reshape(len(X), len(self.experiments)).mean(axis=1)  # NaN if any setup failed


def _stage_id(objective: _Objective, x0, sigma0, seed, generations, preset: Preset) -> str:
    reqs = objective.requests(np.asarray(x0))
    return digest({
        "experiments": objective.exp_ids, "x0": [float(v) for v in x0], "sigma0": float(sigma0), "seed": int(seed),
        "generations": int(generations), "popsize": preset.popsize, "elitist": CMA_ELITIST,
        "restarts": f"ipop/{STALL_DRAWS}/{TOLX}",
        "forward": [r.to_dict() | {"eta": 0, "n": 0, "sigma_y": 0} for r in reqs],
    })[:32]


def _cma_options(generations: int, popsize: int, seed: int) -> dict:
    return {
        "bounds": [0.0, 1.0], "popsize": popsize, "maxiter": generations, "verbose": -9, "CMA_elitist": CMA_ELITIST,
        "randn": np.random.RandomState(seed).randn,  # private RNG: pickled with the strategy
        "seed": np.nan, "tolflatfitness": 10**9,  # flat silhouettes early on must not end the stage
        "tolx": TOLX,
    }


def run_stage(experiments, *, x0, sigma0: float, preset: Preset, seed: int, generations: int, store: Store,
              executor=None, simulator: str = batch.DEFAULT_SIMULATOR,
              progress: Callable[[dict], None] | None = None, stage_index: int = 1,
              screened: Sequence[Sequence[float]] = ()) -> Stage:
    """One CMA-ES run on ``experiments`` from mean ``x0`` (normalised) with step ``sigma0``; resumable.

    ``screened``: rows [x0, x1, x2, loss] already evaluated on these experiments (:func:`warm_start`);
    they count as the stage's evaluations (one new simulation each) and compete for its best candidate.
    """
    t0 = time.perf_counter()
    objective = _Objective(experiments, preset, simulator, store, executor, progress)
    run_id = _stage_id(objective, x0, sigma0, seed, generations, preset)
    state = store.load_checkpoint(run_id)
    if state is not None and state.get("stage") is not None:
        return state["stage"]
    if state is None:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            es = cma.CMAEvolutionStrategy(list(map(float, x0)), float(sigma0), _cma_options(generations, preset.popsize, seed))
        state = {"es": es, "generation": 0, "history": [], "best_x": None, "best_loss": np.inf,
                 "evaluations": len(screened), "simulations": len(screened),  # earlier setups: from the store
                 "wall_seconds": 0.0, "stage": None, "archive": [], "screened": [list(r) for r in screened],
                 "drawn": 0, "restarts": 0, "restart_drawn": 0, "run_best": np.inf}  # draws and IPOP restarts
        finite = [r for r in screened if np.isfinite(r[3])]
        if finite:
            top = min(finite, key=lambda r: r[3])
            state["best_x"], state["best_loss"] = np.asarray(top[:3], float), float(top[3])
    es = state["es"]
    setups = [str(setup_of(e)) for e in experiments]
    if progress:
        progress({"event": "stage", "stage": stage_index, "setups": setups, "generations": generations,
                  "generation": state["drawn"] // preset.popsize})
    budget = generations * preset.popsize  # candidate draws per stage, whatever the restarts' population
    while state["drawn"] < budget:
        if _stopped(es) or _stalled(state):
            es = _restart(state, x0, sigma0, preset.popsize, seed, generations)
        # the budget's last draws may not fill a restart's generation: sampled, never told
        left = budget - state["drawn"]
        X = [np.asarray(x, float) for x in (es.ask() if left >= es.popsize else es.ask(left))]
        state["drawn"] += len(X)
        F = objective(X)
        evaluations = len(X)
        for _ in range(RESAMPLE):
            bad = np.flatnonzero(~np.isfinite(F))
            if bad.size == 0:
                break
            for i in bad:
                X[i] = np.asarray(es.ask(1)[0], float)
            F[bad] = objective([X[i] for i in bad])
            evaluations += bad.size
        finite = np.isfinite(F)
        state.setdefault("archive", []).extend(
            [float(v) for v in np.clip(x, 0.0, 1.0)] + [float(f)] for x, f in zip(X, F) if np.isfinite(f))
        if finite.any():
            i = int(np.nanargmin(np.where(finite, F, np.inf)))
            state["run_best"] = min(state["run_best"], float(F[i]))
            if F[i] < state["best_loss"]:
                state["best_loss"], state["best_x"] = float(F[i]), X[i].copy()
        if finite.sum() >= 2 and len(X) == es.popsize:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # pycma warns when it replaces NaN by the median
                es.tell(X, [float(f) if np.isfinite(f) else np.nan for f in F])
        else:  # nothing to learn from this generation; keep the distribution, count the generation
            es.countiter += 1
        state["generation"] += 1
        state["evaluations"] += evaluations
        state["simulations"] += evaluations * len(experiments)
        state["history"].append({
            "generation": state["generation"], "simulations": state["simulations"],
            "best_loss": state["best_loss"],
            "best_x": None if state["best_x"] is None else [float(v) for v in state["best_x"]],
            "mean_x": [float(v) for v in es.mean], "sigma": float(es.sigma),
            "drawn": state["drawn"], "restarts": state["restarts"], "run_best": state["run_best"],
        })
        state["wall_seconds"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        store.save_checkpoint(run_id, state)
        if progress:
            progress({"event": "generation", "stage": stage_index, "generation": state["drawn"] // preset.popsize,
                      "generations": generations, "best_loss": state["best_loss"]})
    if state["best_x"] is None:
        raise RuntimeError(f"every simulation failed in stage {stage_index} ({', '.join(setups)})")
    stage = Stage(
        setups=setups, x0=[float(v) for v in x0], sigma0=float(sigma0),
        material=Material.from_array(denormalize(np.clip(state["best_x"], 0, 1))), loss=state["best_loss"],
        evaluations=state["evaluations"], simulations=state["simulations"], generations=state["generation"],
        history=state["history"], wall_seconds=state["wall_seconds"] + time.perf_counter() - t0,
        archive=state.get("archive", []), screened=state.get("screened", []),
    )
    state["stage"] = stage
    store.save_checkpoint(run_id, state)
    return stage


def warm_start(previous: Stage, experiments, *, preset: Preset, store: Store, executor=None,
               simulator: str = batch.DEFAULT_SIMULATOR, count: int | None = None,
               min_distance: float = WARM_START_SPACING,
               progress: Callable[[dict], None] | None = None) -> tuple[np.ndarray, list[list[float]]]:
    """Start of stage k: the previous stage's valley re-scored with the new setup (section 6).

    A setup's loss valley is long and flat (section 5): many candidates of stage k-1 fit its setups
    almost equally well, and the best of them need not be the one nearest the truth.  The new setup's
    valley crosses that one, so we take the ``count`` best distinct candidates of the previous stage
    (the previous estimate first, then the best at least ``min_distance`` apart in [0, 1]^3, topped up
    with the next best), evaluate all k setups on them (the old setups come from the store) and start
    from the best.  Costs one generation of the new setup.  Returns (x0, [[x, loss], ...]).
    """
    count = int(count or preset.popsize)
    rows = sorted(getattr(previous, "archive", []), key=lambda r: r[3])  # stages pickled before it existed: none
    picked: list[np.ndarray] = [normalize(previous.material.as_array())]
    for spacing in (min_distance, 1e-9):  # spread out first; fill up with the next best if the valley is small
        for r in rows:
            x = np.asarray(r[:3], float)
            if len(picked) < count and min(np.linalg.norm(x - q) for q in picked) >= spacing:
                picked.append(x)
    objective = _Objective(experiments, preset, simulator, store, executor, progress)
    F = objective(picked)
    if not np.isfinite(F).any():
        return picked[0], []
    best = int(np.nanargmin(np.where(np.isfinite(F), F, np.inf)))
    return picked[best], [[float(v) for v in x] + [float(f)] for x, f in zip(picked, F)]


def _stalled(state) -> bool:
    """True when the current run's best loss has not improved over its last ``STALL_DRAWS`` draws."""
    recent = [h for h in state["history"] if h["drawn"] > state["restart_drawn"]]
    old = [h["run_best"] for h in recent if h["drawn"] <= state["drawn"] - STALL_DRAWS]
    return bool(old) and not recent[-1]["run_best"] < old[-1]


def _restart(state, x0, sigma0: float, popsize: int, seed: int, generations: int):
    """IPOP restart (Auger & Hansen 2005): the stage's initial distribution again with twice the population."""
    restarts = state["restarts"] + 1
    lam = popsize * 2**restarts
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        es = cma.CMAEvolutionStrategy(list(map(float, x0)), float(sigma0),
                                      _cma_options(generations, lam, seed + 7919 * restarts))
    state.update(es=es, restarts=restarts, restart_drawn=state["drawn"], run_best=np.inf)
    return es


def _stopped(es) -> bool:
    stop = dict(es.stop())
    stop.pop("maxiter", None)  # the stage's budget of draws decides that
    return bool(stop)


def default_store() -> Store:
    return Store(Path.home() / ".cache" / "virheometry" / "store")


def estimate(experiments, *, preset="quick", seed: int = 0, executor=None, store: Store | None = None,
             generations: int | None = None, workers: int | None = None,
             simulator: str = batch.DEFAULT_SIMULATOR, progress: Callable[[dict], None] | None = None,
             n_setups: int | None = None, acquire: Callable[[Setup], object] | None = None,
             propose: Callable[[Material, list], Setup | None] = propose_next_setup) -> Estimate:
    """Algorithm 1 on ``experiments`` (objects like :class:`mpm.experiment.Experiment`), in order.

    Stage k fits the first k experiments.  After every stage the next setup is proposed with
    ``propose`` (default :func:`similarity.design.next_setup`); with ``acquire`` (a callable
    Setup -> experiment, e.g. an emulator) the proposed setup is filmed and added until
    ``n_setups`` are done.  ``executor``: any concurrent.futures Executor or dask Client; default:
    ``workers`` local processes (0: in-process).  Returns the best evaluated candidate.
    """
    experiments = list(experiments)
    if not experiments:
        raise ValueError("estimate needs at least one experiment")
    preset = get_preset(preset)
    generations = int(generations or preset.generations)
    if generations < 1:
        raise ValueError(f"generations={generations} must be >= 1")
    n_setups = int(n_setups or len(experiments))
    store = store if store is not None else default_store()
    own = executor is None and workers != 0
    ex = batch.local_executor(workers) if own else (batch.local_executor(0) if executor is None else executor)
    t0 = time.perf_counter()
    stages: list[Stage] = []
    x0 = normalize(center().as_array())
    try:
        k = 0
        while k < n_setups:
            k += 1
            if k > len(experiments):
                proposed = stages[-1].next_setup
                if acquire is None or proposed is None:
                    break
                experiments.append(acquire(Setup.parse(proposed)))
            sigma0 = preset.sigma0 * (2.0 / 3.0) ** (k - 1)
            screened = []
            if stages:
                x0, screened = warm_start(stages[-1], experiments[:k], preset=preset, store=store, executor=ex,
                                          simulator=simulator, progress=progress)
            stage = run_stage(experiments[:k], x0=x0, sigma0=sigma0, preset=preset, seed=seed + k - 1,
                              generations=generations, store=store, executor=ex, simulator=simulator,
                              progress=progress, stage_index=k, screened=screened)
            done = [setup_of(e) for e in experiments[:k]]
            nxt = propose(stage.material, done) if propose else None
            stage.next_setup = None if nxt is None else str(Setup(nxt.width_mm, nxt.height_mm))
            stages.append(stage)
            x0 = normalize(stage.material.as_array())
    finally:
        if own:
            batch.shutdown(ex)
    last = stages[-1]
    return Estimate(
        material=last.material, loss=last.loss, stages=stages,
        evaluations=sum(s.evaluations for s in stages), simulations=sum(s.simulations for s in stages),
        wall_seconds=time.perf_counter() - t0,
        next_setup=None if last.next_setup is None else Setup.parse(last.next_setup),
        preset=preset.name, seed=int(seed), setups=last.setups,
    )


def emulate_virheometry(truth: Material, first_setup: Setup, *, n_setups: int = 2, preset="quick", seed: int = 0,
                        density: float = 1000.0, camera=None, store: Store | None = None, executor=None,
                        workers: int | None = None, generations: int | None = None,
                        simulator: str = batch.DEFAULT_SIMULATOR, progress=None,
                        propose: Callable = propose_next_setup) -> tuple[Estimate, list[EmulatedExperiment]]:
    """Sequential ViRheometry on emulated footage: film ``first_setup``, fit, film the proposed setup, fit again.

    Returns the estimate and the emulated experiments (their ``truth`` is ``truth``).
    """
    preset = get_preset(preset)
    store = store if store is not None else default_store()
    own = executor is None and workers != 0
    ex = batch.local_executor(workers) if own else (batch.local_executor(0) if executor is None else executor)
    filmed: list[EmulatedExperiment] = []

    def acquire(setup: Setup):
        e = emulate(truth, [setup], density=density, camera=camera, preset=preset, store=store, executor=ex,
                    simulator=simulator)[0]
        filmed.append(e)
        return e

    try:
        first = acquire(first_setup)
        est = estimate([first], preset=preset, seed=seed, executor=ex, store=store, generations=generations,
                       simulator=simulator, progress=progress, n_setups=n_setups, acquire=acquire, propose=propose)
    finally:
        if own:
            batch.shutdown(ex)
    return est, filmed


def e_rel_history(stage: Stage, truth: Material) -> list[tuple[int, float]]:
    """(simulation count, E_rel of the best candidate so far) per generation (Fig. 10)."""
    out = []
    for h in stage.history:
        if h["best_x"] is not None:
            out.append((h["simulations"], e_rel(truth, Material.from_array(denormalize(h["best_x"])))))
    return out


def simulated_frames(material: Material, experiments, *, preset="quick", store: Store | None = None, executor=None,
                     simulator: str = batch.DEFAULT_SIMULATOR) -> list:
    """Silhouettes of ``material`` in each experiment's setup (None where the simulation failed).

    For an estimate's material these come straight from the store: the estimator simulated them.
    """
    preset = get_preset(preset)
    reqs = [simulation_request(material, e, preset, simulator) for e in experiments]
    ex = executor if executor is not None else batch.InlineExecutor()
    return [r.silhouettes if r.ok else None for r in batch.evaluate(reqs, store=store, executor=ex)]
