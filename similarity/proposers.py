"""Ways to choose the next setup after a stage of Algorithm 1, for ``estimate(..., propose=...)``.

A proposer is called as ``propose(material, done)`` with the stage's estimate and the setups done so far;
one that takes a keyword ``stage`` also receives the finished :class:`similarity.cma_stage.Stage`.

* ``perpendicularity``: section 6, the setup whose loss normal is most perpendicular to those done
  (:func:`similarity.design.next_setup`);
* ``eig``: the largest expected information gain (:func:`similarity.design.rank_setups`,
  ``criterion="eig"``) under the belief the stage's own evaluations imply (:mod:`similarity.belief`);
* ``random``: a uniformly random setup of the 1 mm grid in ``SETUP_RANGE_MM``, other than those done,
  drawn from a generator seeded by (seed, number of setups done), so a case gets the same setups on
  every run.
"""
from __future__ import annotations

import numpy as np

from mpm.params import SETUP_RANGE_MM, Material, Setup
from similarity.belief import Belief, stage_belief

CRITERIA = ("perpendicularity", "eig", "random")


class Perpendicularity:
    """Section 6 (the default of :func:`similarity.estimate.estimate`)."""

    name = "perpendicularity"

    def __init__(self, theta="reference"):
        self.theta = theta

    def __call__(self, material: Material, done) -> Setup:
        from similarity.design import next_setup

        return next_setup(material, list(done), theta=self.theta)


class Eig:
    """Largest expected information gain under the stage's archive belief.

    ``beliefs`` keeps the belief behind each proposal, keyed by the number of setups done.  Without a stage,
    or when its archive cannot carry a quadratic fit (``without_belief`` says why), the belief is the
    plane-Poiseuille Laplace one of :func:`similarity.design.rank_setups`.
    """

    name = "eig"

    def __init__(self, frames_per_setup: int, theta="reference"):
        if frames_per_setup < 1:
            raise ValueError(f"frames_per_setup={frames_per_setup} must be >= 1")
        self.frames_per_setup = int(frames_per_setup)
        self.theta = theta
        self.beliefs: dict[int, Belief] = {}
        self.without_belief: dict[int, str] = {}

    def __call__(self, material: Material, done, *, stage=None) -> Setup:
        from similarity.design import next_setup

        covariance = None
        if stage is not None:
            try:
                belief = stage_belief(stage, self.frames_per_setup)
            except ValueError as exc:  # too few or degenerate evaluations: the setups' own Laplace belief
                self.without_belief[len(done)] = str(exc).splitlines()[0]
            else:
                self.beliefs[len(done)] = belief
                covariance = belief.covariance
        return next_setup(material, list(done), theta=self.theta, criterion="eig", covariance=covariance)


class Random:
    """A uniformly random setup of the 1 mm grid, reproducible per (seed, number of setups done)."""

    name = "random"

    def __init__(self, seed):
        self.seed = [int(v) for v in np.atleast_1d(seed)]

    def __call__(self, material: Material, done) -> Setup:
        lo, hi = SETUP_RANGE_MM
        done = [str(s) for s in done]
        rng = np.random.default_rng(self.seed + [len(done)])
        while True:
            w, h = rng.integers(int(lo), int(hi) + 1, size=2)
            s = Setup(float(w), float(h))
            if str(s) not in done:
                return s
