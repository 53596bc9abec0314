"""ViRheometry (Algorithm 1): Herschel-Bulkley parameters from dam-break footage by staged CMA-ES.

Stage k fits the first k setups (:mod:`similarity.cma_stage`), starting from the previous stage's
re-scored candidates with step ``sigma0 * (2/3)^(k-1)``; a preset with a finishing stage then fits all
setups again at its final discretisation (coarse-to-fine).  Presets: :mod:`similarity.presets`;
emulated footage: :mod:`similarity.emulation`.  Every simulation goes through the store, so a killed
run resumes where it stopped.
"""
from __future__ import annotations

import inspect
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

from mpm.forward import Forward, ForwardModel
from mpm.params import DEFAULT_DENSITY_KG_M3, Material, Setup
from similarity.cma_stage import WARM_START_SPACING, Generation, Stage, run_stage, warm_start  # noqa: F401
from similarity.emulation import emulate, simulated_frames  # noqa: F401
from similarity.presets import PRESETS, Preset, get_preset, setup_of  # noqa: F401
from similarity.progress import Event, first_line
from similarity.proposers import Perpendicularity
from similarity.space import LOWER, UPPER, center, denormalize, e_rel, normalize

BOUND_MARGIN = 0.02  # an estimate this close to a bound (fraction of the parameter's range) gets a warning
log = logging.getLogger(__name__)


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
    model: ForwardModel  # the forward model at which ``loss`` was computed (the last stage's)
    warnings: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # one line per optional step skipped (a next-setup proposal)

    def to_dict(self) -> dict:
        return {
            "estimate": self.material.to_dict(),
            "loss": self.loss,
            "model": self.model.to_dict(),
            "warnings": list(self.warnings),
            "notes": list(self.notes),
            "setups": self.setups,
            "next_setup": None if self.next_setup is None else str(self.next_setup),
            "evaluations": self.evaluations,
            "simulations": self.simulations,
            "wall_seconds": self.wall_seconds,
            "preset": self.preset,
            "seed": self.seed,
            "stages": [s.to_dict() for s in self.stages],
        }


def bound_warnings(material: Material, margin: float = BOUND_MARGIN) -> list[str]:
    """One line per parameter within ``margin`` (fraction of its range) of a bound the answer may lie beyond.

    The lower bounds of eta and sigma_y are not checked: no material lies below them.
    """
    x = normalize(material.as_array())
    names = (("eta", "Pa s^n"), ("n", ""), ("sigma_y", "Pa"))
    out = []
    for i, (name, unit) in enumerate(names):
        for side, near, bound in (("lower", x[i] <= margin, LOWER[i]), ("upper", x[i] >= 1.0 - margin, UPPER[i])):
            if near and not (side == "lower" and name in ("eta", "sigma_y")):
                out.append(f"{name} = {getattr(material, name):.4g} {unit}".rstrip() + f" lies within "
                           f"{100 * margin:g} % of the material space's {side} bound {bound:g}: the answer may lie "
                           f"outside the space")
    return out


def propose_next_setup(material: Material, done: Sequence[Setup]) -> Setup | None:
    """Section 6: the setup whose loss normal is most perpendicular to those of ``done``; None, with a logged
    warning saying why, where there is none (no setup done has plane-Poiseuille flow at ``material``, or no
    candidate does).  Setups done without flow are left out of the score."""
    try:
        return Perpendicularity()(material, done)
    except ValueError as exc:
        log.warning("next-setup proposal skipped: %s", first_line(exc))
        return None


def skipped_proposal(stage_index: int, exc: BaseException) -> str:
    """The one line an estimate keeps when the proposal after a stage failed."""
    return f"next-setup proposal after stage {stage_index} skipped: {first_line(exc)}"


def _takes_stage(propose) -> bool:
    """Whether ``propose`` accepts a keyword ``stage`` (the finished stage, with its CMA-ES archive)."""
    try:
        params = inspect.signature(propose).parameters.values()
    except (TypeError, ValueError):
        return False
    return any(p.name == "stage" and p.kind != p.POSITIONAL_ONLY or p.kind == p.VAR_KEYWORD for p in params)


DEFAULT_STORE = Path.home() / ".cache" / "virheometry" / "store"


def _forward(forward: Forward | None) -> tuple[Forward, bool]:
    """(forward, whether we own it): the given one, else the default store with one worker per CPU core."""
    return (forward, False) if forward is not None else (Forward(DEFAULT_STORE, workers=None), True)


def estimate(experiments, *, preset="footage", seed: int = 0, forward: Forward | None = None,
             generations: float | Sequence[float] | None = None, progress: Callable[[Event], None] | None = None,
             n_setups: int | None = None, acquire: Callable[[Setup], object] | None = None,
             propose: Callable[[Material, list], Setup | None] | None = Perpendicularity(),
             start: Material | None = None) -> Estimate:
    """Algorithm 1 on ``experiments`` (:class:`mpm.experiment.Experiment`), in order.

    Stage k fits the first k experiments.  After every stage the next setup is proposed with
    ``propose(material, done)`` (default section 6's perpendicularity, :class:`similarity.proposers.Perpendicularity`;
    None: no proposal; a proposer that takes a keyword ``stage`` also gets the finished :class:`Stage`).  The
    proposal is optional: when it raises, the stage keeps no next setup, the estimate goes on and
    ``Estimate.notes`` says why (:func:`skipped_proposal`).  With ``acquire``
    (a callable Setup -> experiment, e.g. an emulator) the proposed setup is filmed and added until
    ``n_setups`` are done.  ``generations`` overrides the preset's per-stage count (not the finishing
    stage's); a sequence gives stage k its k-th entry (the last one for later stages); a fraction of a generation
    ends a stage on a partial last one (:func:`similarity.cma_stage.run_stage`).  ``forward``: the store and executor that simulate (default: the store under ~/.cache, one
    worker process per CPU core).  ``start``: stage 1's CMA-ES mean (default: the centre of the material space),
    e.g. a rheometer's fit or an earlier estimate.  Returns the best evaluated candidate of the last stage.
    """
    experiments = list(experiments)
    if not experiments:
        raise ValueError("estimate needs at least one experiment")
    preset = get_preset(preset)
    per_stage = [g if isinstance(g, int) else float(g) for g in
                 (generations if isinstance(generations, (list, tuple)) else [generations or preset.generations])]
    if not per_stage or min(per_stage) < 1:
        raise ValueError(f"generations={generations} must be >= 1")
    n_setups = int(n_setups or len(experiments))
    forward, own = _forward(forward)
    common = dict(forward=forward, progress=progress)
    t0 = time.perf_counter()
    stages: list[Stage] = []
    notes: list[str] = []
    x0 = normalize((center() if start is None else Material.of(start).check_in_space()).as_array())

    def finish_stage(stage: Stage, done: list[Setup]) -> None:
        stages.append(stage)
        try:
            if propose is None:
                nxt = None
            elif _takes_stage(propose):
                nxt = propose(stage.material, done, stage=stage)
            else:
                nxt = propose(stage.material, done)
        except Exception as exc:  # an optional step: the estimate goes on without it
            notes.append(skipped_proposal(len(stages), exc))
            nxt = None
        stage.next_setup = None if nxt is None else str(Setup(nxt.width_mm, nxt.height_mm))

    try:
        k = 0
        while k < n_setups:
            k += 1
            if k > len(experiments):
                proposed = stages[-1].next_setup
                if acquire is None or proposed is None:
                    break
                experiments.append(acquire(Setup.parse(proposed)))
            screened = []
            if stages:
                x0, screened = warm_start(stages[-1], experiments[:k], model=preset.search, **common)
            stage = run_stage(experiments[:k], x0=x0, sigma0=preset.sigma0 * (2.0 / 3.0) ** (k - 1),
                              model=preset.search, seed=seed + k - 1, generations=per_stage[min(k, len(per_stage)) - 1],
                              stage_index=k,
                              screened=screened, search_space=preset.search_space, **common)
            finish_stage(stage, [setup_of(e) for e in experiments[:k]])
            x0 = normalize(stage.material.as_array())
        if preset.finish_generations > 0:  # coarse-to-fine: the last stage at the final discretisation
            n = len(stages)
            x0, screened = warm_start(stages[-1], experiments[:n], model=preset.final, **common)
            stage = run_stage(experiments[:n], x0=x0, sigma0=preset.sigma0 * (2.0 / 3.0) ** n, model=preset.final,
                              seed=seed + n, generations=preset.finish_generations, stage_index=n + 1,
                              screened=screened, screened_simulations=n * len(screened), finish=True,
                              search_space=preset.search_space,
                              shape=stages[-1].end_shape if preset.carry_covariance else None, **common)
            finish_stage(stage, [setup_of(e) for e in experiments[:n]])
    finally:
        if own:
            forward.close()
    last = stages[-1]
    return Estimate(
        material=last.material, loss=last.loss, stages=stages,
        evaluations=sum(s.evaluations for s in stages), simulations=sum(s.simulations for s in stages),
        wall_seconds=time.perf_counter() - t0,
        next_setup=None if last.next_setup is None else Setup.parse(last.next_setup),
        preset=preset.name, seed=int(seed), setups=last.setups, model=last.model, warnings=bound_warnings(last.material),
        notes=notes,
    )


def emulate_virheometry(truth: Material, first_setup: Setup, *, n_setups: int = 2, preset="demo", seed: int = 0,
                        density: float = DEFAULT_DENSITY_KG_M3, camera=None, forward: Forward | None = None,
                        generations: int | None = None, progress=None,
                        propose: Callable | None = Perpendicularity()) -> tuple[Estimate, list]:
    """Sequential ViRheometry on emulated footage: film ``first_setup``, fit, film the proposed setup, fit again.

    Returns the estimate and the emulated experiments (:class:`mpm.experiment.Experiment`, in filming order).
    """
    preset = get_preset(preset)
    forward, own = _forward(forward)
    filmed: list = []

    def acquire(setup: Setup):
        e = emulate(truth, [setup], density=density, camera=camera, preset=preset, forward=forward)[0]
        filmed.append(e)
        return e

    try:
        first = acquire(first_setup)
        est = estimate([first], preset=preset, seed=seed, forward=forward, generations=generations,
                       progress=progress, n_setups=n_setups, acquire=acquire, propose=propose)
    finally:
        if own:
            forward.close()
    return est, filmed


def e_rel_history(stage: Stage, truth: Material) -> list[tuple[int, float]]:
    """(simulation count, E_rel of the best candidate so far) per generation (Fig. 10)."""
    return [(h.simulations, e_rel(truth, Material.from_array(denormalize(h.best_x))))
            for h in stage.history if h.best_x is not None]
