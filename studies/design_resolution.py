"""Does the ``information`` criterion's measure survive a finer model?  The log det gain of a fixed set of candidates
after setup 1, computed at several MPM discretisations, compared with the finest.

The ``information`` criterion (:func:`similarity.simulated_design.rank_by_simulation`) ranks setups by the log det
gain of their FD loss Hessians (:func:`similarity.information.predicted_gains`) computed with one forward model. At
5 mm cells a 20 mm box is 4 cells across and heights come in 5 mm bands, so its ranking may be the coarse model's
and not the material's. This study computes exactly that measure for the same materials and setups at several
models:

* **materials** (:data:`MATERIALS`): four materials of the interior of the space (every FD probe at the pinned step
  is a material of the space), modelled on Table 1's sauces and creams: two runny ones with sigma_y < 5 Pa, a
  shear-thinning cream (n = 0.42) and a thicker sauce, each with a first setup of the shared footage;
* **setups**: setup 1, then the :data:`CANDIDATES`: the four corners of 20..70 mm, the middle and three more;
* **per (material, model, setup)** one case: the footage emulated at the material with the model, the 18-point FD
  stencil around it (19 simulations), the PSD-projected Hessian (:func:`similarity.information.setup_hessian`);
* **per (material, model)**: each candidate's gain after setup 1 (:func:`similarity.information.log_det_gain`),
  the argmax, the trace ratio tr H(70x70) / tr H(20x20), the CPU seconds per simulation;
* **against the finest model** (the finest with any result; per material that has it): Spearman's rank correlation
  of the gains over the candidates both have and whether the argmax is the same.  A model *matches* the finest when
  on every such material the argmax is the same and Spearman >= :data:`MATCH_SPEARMAN`; the summary names the
  cheapest matching model (by CPU seconds per simulation), the one the criterion should use, only once every
  material that has the finest model has all its candidates there (until then ``pending`` names those that lack
  some: a partial finest model gives no verdict, and neither does a coarser one in its stead).  A model whose cases
  came from more than one engine is not compared.

Cases are kept in ``cases/<material>/<model>/<setup>/case.json``; the study's configuration does not hold the models,
so runs with different ``--models`` (and engines: each case records the engine that ran it) add to one ``--out``,
and the summary is over every finished case there.  Writes ``design_resolution.json`` and ``design_resolution.md``.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mpm.files import JsonRecord
from mpm.model import ForwardModel
from mpm.params import Material, Setup
from similarity import information as I
from studies.study import Study

MATCH_SPEARMAN = 0.8  # a model matches the finest when the argmax agrees and the gains' Spearman is at least this


@dataclass(frozen=True)
class Probe:
    """A material of the study: its slug, what it is modelled on, the material and its first setup."""

    slug: str
    like: str
    material: Material
    first: Setup


MATERIALS = (
    Probe("runny", "Worcestershire sauce, eta raised to the space's interior", Material(1.5, 0.81, 2.0), Setup(21, 40)),
    Probe("cream", "lotion (n < 0.5)", Material(9.76, 0.42, 2.0), Setup(51, 25)),
    Probe("sauce", "cabbage pancake sauce", Material(2.62, 0.76, 11.58), Setup(42, 38)),
    Probe("paste", "a thick paste", Material(12.0, 0.6, 25.0), Setup(29, 59)),
)
CANDIDATES = tuple(Setup(w, h) for w, h in ((20, 20), (70, 20), (20, 70), (70, 70), (45, 45), (32, 32), (58, 32),
                                            (32, 58)))
DEFAULT_MODELS = (ForwardModel(5.0, 1), ForwardModel(3.5, 1), ForwardModel(2.5, 1), ForwardModel(2.5, 2),
                  ForwardModel(1.26, 2))


def model_label(model: ForwardModel) -> str:
    return f"{model.cell_mm:g}mm-{model.ppc}p"


def parse_model(text: str) -> ForwardModel:
    """'CELL_MM:PPC' (e.g. 2.5:2) as a forward model with sticking walls; ValueError (one line) otherwise."""
    parts = str(text).split(":")
    try:
        if len(parts) != 2:
            raise ValueError
        cell, ppc = float(parts[0]), float(parts[1])
    except ValueError:
        raise ValueError(f"model '{text}' must be CELL_MM:PPC, e.g. 2.5:2") from None
    return ForwardModel(cell, int(ppc) if ppc == int(ppc) else ppc)


def setups_of(probe: Probe) -> list[Setup]:
    """Setup 1, then the candidates (those equal to setup 1 left out)."""
    return [probe.first] + [c for c in CANDIDATES if str(c) != str(probe.first)]


@dataclass
class ResolutionCase:
    """One setup of one material at one model: what :meth:`DesignResolution.run_case` computes."""

    probe: Probe
    model: ForwardModel
    setup: Setup
    folder: Path


@dataclass
class SetupRecord(JsonRecord):
    """One finished case: the stencil losses of one setup at one model, and the Hessian they give."""

    config: dict
    material: str  # the probe's slug
    truth: Material
    model: str  # model_label
    cell_mm: float
    ppc: int
    engine: str | None  # the engine that simulated (None: a fake simulator)
    setup: str
    stencil_losses: list  # 18, :func:`similarity.fd_hessian.stencil` order
    hessian: list | None  # (3, 3) PSD-projected, None when a simulation failed
    cpu_seconds: float  # summed over the simulations this case ran (0 when the store served them)
    simulations: int  # simulations run (not served from the store)
    wall_seconds: float

    READERS = {"truth": lambda d: Material(**d)}


@dataclass
class ModelScores(JsonRecord):
    """One material at one model."""

    model: str
    engine: str | None
    setups: list  # the candidates, in order
    gains: list  # log det gain after setup 1, per candidate (None: a failed simulation)
    argmax: str | None
    trace_ratio: float | None  # tr H(70x70) / tr H(20x20)
    cpu_seconds_per_simulation: float | None
    spearman_vs_finest: float | None
    argmax_as_finest: bool | None


@dataclass
class ResolutionSummary(JsonRecord):
    finest: str | None  # the finest model with any result
    materials: dict  # slug -> {model label -> ModelScores}
    matching: list  # models matching the finest on every material that has it, cheapest first
    cheapest_matching: str | None
    compared_materials: list  # slugs with the finest model's results
    pending: list = field(default_factory=list)  # of those, the ones still lacking candidates there: no verdict yet
    mixed_engines: list = field(default_factory=list)  # models whose cases came from more than one engine (left out)

    READERS = {"materials": lambda d: {m: {k: ModelScores.from_dict(v) for k, v in ms.items()} for m, ms in d.items()}}


def _finite(v) -> float | None:
    return float(v) if v is not None and np.isfinite(v) else None


def model_scores(recs: list[SetupRecord], probe: Probe) -> ModelScores | None:
    """The gains of one material at one model from its setup records; None while setup 1's case is missing."""
    by_setup = {r.setup: r for r in recs}
    first = by_setup.get(str(probe.first))
    if first is None or first.hessian is None:
        return None
    cands = [str(s) for s in setups_of(probe)[1:] if str(s) in by_setup]
    hessians = [None if by_setup[c].hessian is None else np.array(by_setup[c].hessian) for c in cands]
    try:
        gains = I.realised_gains(np.array(first.hessian), hessians) if cands else np.array([])
    except ValueError:  # setup 1 carries no information at this model: each candidate on its own (as design does)
        eps = I.candidates_ridge(hessians)
        gains = (I.realised_gains(np.array(first.hessian), hessians, eps=eps) if eps is not None
                 else np.full(len(cands), np.nan))
    ok = np.isfinite(gains)
    trace = {s: np.trace(np.array(r.hessian)) for s, r in by_setup.items() if r.hessian is not None}
    small, large = trace.get("20x20"), trace.get("70x70")
    runs = sum(r.simulations for r in recs)
    return ModelScores(recs[0].model, recs[0].engine, cands, [_finite(g) for g in gains],
                       cands[int(np.nanargmax(gains))] if ok.any() else None,
                       _finite(large / small) if small and large is not None else None,
                       sum(r.cpu_seconds for r in recs) / runs if runs else None, None, None)


def compare(coarse: ModelScores, fine: ModelScores) -> tuple[float | None, bool | None]:
    """(Spearman of the gains over the candidates both have, same argmax: None unless both have every candidate) of a
    model against the finest."""
    g_fine = dict(zip(fine.setups, fine.gains))
    pairs = [(g, g_fine[s]) for s, g in zip(coarse.setups, coarse.gains) if s in g_fine]
    if len(pairs) < 3:
        return None, None
    a, b = (np.array([np.nan if v is None else v for v in col], float) for col in zip(*pairs))
    same = coarse.argmax == fine.argmax if coarse.argmax and fine.argmax and coarse.setups == fine.setups else None
    return _finite(I.rank_agreement(a, b)), same


class DesignResolution(Study):
    name = "design_resolution"
    record = SetupRecord
    case_files = ("cases/*/*/*/case.json",)

    def __init__(self, out, config: dict | None = None, *, models=DEFAULT_MODELS, materials: int = len(MATERIALS)):
        super().__init__(out, config)
        self.models, self.materials = list(models), int(materials)

    def cases(self):
        """Model by model, the materials' setups from the smallest box up: a simulation's cost grows with the box, so
        a run stopped early has the most cases done (the order of the results does not depend on it)."""
        pairs = sorted(((probe, s) for probe in MATERIALS[:self.materials] for s in setups_of(probe)),
                       key=lambda p: p[1].width_mm * p[1].height_mm)
        for model in self.models:
            for probe, s in pairs:
                yield ResolutionCase(probe, model, s, self.out / "cases" / probe.slug / model_label(model) / str(s))

    def announce(self, case) -> str:
        return f"{case.probe.slug} {model_label(case.model)} {case.setup}"

    def run_case(self, case, *, forward, progress=None):
        from similarity.fd_hessian import stencil
        from similarity.emulation import emulate, probe_losses
        from similarity.presets import filming
        from similarity.progress import simulation_tick

        t0, cpu, engine = time.perf_counter(), [0.0], [None]
        ran_before = forward.simulations_run
        tick = simulation_tick(progress)

        def on_result(request, result, cached):
            engine[0] = request.model.engine
            if result is not None and not cached:
                cpu[0] += float(result.stats.get("cpu_s", result.wall_seconds))
            if tick:
                tick(request, result, cached)

        preset = filming("demo", case.model, f"resolution-{model_label(case.model)}")
        step = self.config["fd_step"]
        try:
            shot = emulate(case.probe.material, [case.setup], preset=preset, forward=forward, on_result=on_result)
            losses = probe_losses([(case.probe.material, shot[0])], stencil(step), preset.final, forward, on_result)[0]
        except RuntimeError:  # the footage failed: no information measured
            losses = np.full(len(stencil(step)), np.nan)
        hessian = I.setup_hessians([losses], step)[0]
        return SetupRecord(self.config, case.probe.slug, case.probe.material, model_label(case.model),
                           case.model.cell_mm, case.model.ppc, engine[0], str(case.setup),
                           [_finite(v) for v in losses], None if hessian is None else hessian.tolist(), cpu[0],
                           forward.simulations_run - ran_before, time.perf_counter() - t0)

    def summary(self, records):
        cells, ppcs = {r.model: r.cell_mm for r in records}, {r.model: r.ppc for r in records}
        per: dict = {}
        for probe in MATERIALS:
            mine = [r for r in records if r.material == probe.slug]
            scores = {}
            for label in sorted({r.model for r in mine}, key=lambda m: (-cells[m], ppcs[m])):
                s = model_scores([r for r in mine if r.model == label], probe)
                if s is not None:
                    scores[label] = s
            if scores:
                per[probe.slug] = scores
        engines: dict = {}
        for r in records:
            engines.setdefault(r.model, set()).add(r.engine)
        mixed = {m for m, e in engines.items() if len(e) > 1}
        labels = {m for ms in per.values() for m in ms} - mixed
        finest = min(labels, key=lambda m: (cells[m], -ppcs[m])) if labels else None
        compared = [slug for slug in per if finest in per[slug]]
        pending = [slug for slug in compared if len(per[slug][finest].setups) < len(setups_of(_probe(slug))) - 1]
        for slug in compared:
            for label, s in per[slug].items():
                if label != finest:
                    s.spearman_vs_finest, s.argmax_as_finest = compare(s, per[slug][finest])
        matching = [m for m in labels - {finest} if compared and not pending and all(
            m in per[slug] and per[slug][m].argmax_as_finest and (per[slug][m].spearman_vs_finest or -1) >= MATCH_SPEARMAN
            for slug in compared)]
        cost = {m: np.median([c for s in per if m in per[s] for c in [per[s][m].cpu_seconds_per_simulation]
                              if c is not None] or [np.inf]) for m in labels}
        matching.sort(key=lambda m: cost[m])
        return ResolutionSummary(finest, per, matching, matching[0] if matching else None, compared, pending,
                                 sorted(mixed))

    def table(self, records, summary) -> str:
        lines = ["# The information criterion's measure against the model's resolution", "",
                 f"Gains after setup 1 of the candidates; finest model: {summary.finest}; a model matches it with the "
                 f"same argmax and Spearman >= {MATCH_SPEARMAN:g} on every material that has it "
                 f"({', '.join(summary.compared_materials) or 'none yet'}).", "",
                 "| material | setup 1 | model | engine | candidates | argmax | Spearman vs finest | same argmax | "
                 "tr H 70x70 / 20x20 | CPU s per simulation |", "|---|---|---|---|---|---|---|---|---|---|"]
        for slug, ms in summary.materials.items():
            for label, s in ms.items():
                lines.append(f"| {slug} | {_probe(slug).first} | {label} | {s.engine} | {len(s.setups)} | {s.argmax} | "
                             f"{_fmt(s.spearman_vs_finest)} | {'' if s.argmax_as_finest is None else s.argmax_as_finest} "
                             f"| {_fmt(s.trace_ratio)} | {_fmt(s.cpu_seconds_per_simulation)} |")
        verdict = (f"Models matching {summary.finest}, cheapest first: {', '.join(summary.matching) or 'none'}." if
                   not summary.pending else f"No verdict yet: {', '.join(summary.pending)} still lack candidates at "
                   f"{summary.finest} (Spearman above on the candidates both models have).")
        if summary.mixed_engines:
            verdict += f" Left out, their cases from more than one engine: {', '.join(summary.mixed_engines)}."
        lines += ["", verdict, "",
                  "Log det gain after setup 1, per candidate:", ""]
        names = [str(c) for c in CANDIDATES]
        lines += ["| material | model | " + " | ".join(names) + " |", "|---|---|" + "---|" * len(names)]
        for slug, ms in summary.materials.items():
            for label, s in ms.items():
                g = dict(zip(s.setups, s.gains))
                lines.append(f"| {slug} | {label} | " + " | ".join(_fmt(g.get(c)) for c in names) + " |")
        return "\n".join(lines + [""])

    def plots(self, records, summary) -> None:
        return None


def _probe(slug: str) -> Probe:
    return next(p for p in MATERIALS if p.slug == slug)


def _fmt(v) -> str:
    return "" if v is None else f"{v:.3g}"


def run_study(out, *, models=DEFAULT_MODELS, materials: int = len(MATERIALS), fd_step: float = I.STEP,
              simulator: str | None = None, forward, progress=None) -> dict:
    """Run (or resume) every setup of the first ``materials`` materials at each of ``models`` in ``out``, then
    summarise every finished case there (runs with other models or materials add to it).  Returns what
    ``design_resolution.json`` holds."""
    if not 1 <= int(materials) <= len(MATERIALS):
        raise ValueError(f"--materials must be within 1..{len(MATERIALS)}")
    if not models:
        raise ValueError("name at least one model")
    config = {"fd_step": float(fd_step), "simulator": simulator,
              "materials": {p.slug: [str(p.material), *(str(s) for s in setups_of(p))] for p in MATERIALS}}
    return DesignResolution(out, config, models=models, materials=materials).run(forward=forward, progress=progress)
