"""The progress events a long computation reports to its ``progress`` callback (estimation, studies, posteriors),
as typed values: the command line's progress bars and counters dispatch on their type; and ``first_line``, how an
exception becomes one line for the user."""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Message:
    """A line for the user."""

    text: str


@dataclass(frozen=True)
class Simulation:
    """One simulation finished (``cached``: served from the store instead of run)."""

    cached: bool


@dataclass(frozen=True)
class StageStarted:
    """A CMA-ES stage of Algorithm 1 starts (or resumes at ``generation``)."""

    stage: int
    setups: list
    generations: int
    generation: int = 0


@dataclass(frozen=True)
class GenerationDone:
    """A CMA-ES generation of a stage finished."""

    stage: int
    generation: int
    generations: int
    best_loss: float


@dataclass(frozen=True)
class Sampling:
    """An emcee checkpoint: iterations so far, the autocorrelation time and the effective sample size."""

    iteration: int
    tau: float
    ess: float


Event = Message | Simulation | StageStarted | GenerationDone | Sampling


def first_line(exc: BaseException) -> str:
    """An exception as one line for the user: its message's first line, or its type's name."""
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def simulation_tick(progress):
    """A ``Forward`` ``on_result`` callback that reports each finished simulation to ``progress`` (None: none)."""
    return (lambda request, result, cached: progress(Simulation(bool(cached)))) if progress else None
