"""Algorithm 1 on a cheap deterministic forward model: reproducibility, best-ever candidate, NaN, kill -9,
coarse-to-fine finishing stage, bound warnings."""
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from mpm import batch
from mpm.forward import Forward
from mpm.params import Material, Setup
from mpm.store import Store
from similarity import cma_stage
from similarity import estimate as E
from similarity.presets import PAPER_MODEL, setup_of
from similarity.progress import GenerationDone
from similarity.space import denormalize, e_rel

SIM = "fake_forward:simulate"
TRUTH = Material(3.0, 0.6, 12.0)
SIZE = (192, 108)
TESTS = Path(__file__).resolve().parent
DEMO = E.get_preset("demo")
GENS = 40  # at 12 the elitist strategy ends farther than the centre on this toy


def _footage(store, setups=((30, 50), (60, 25)), truth=TRUTH):
    return E.emulate(truth, [Setup(*s) for s in setups], forward=Forward(store, simulator=SIM), image_size=SIZE)


def _fixed(material, done):
    return Setup(60, 25)


def test_same_seed_same_estimate_and_best_evaluated_candidate(tmp_path):
    exps = _footage(Store(tmp_path / "truth"))
    runs = []
    for name in ("a", "b"):
        store = Store(tmp_path / name)
        runs.append((E.estimate(exps, preset=DEMO, seed=7, forward=Forward(store, simulator=SIM), generations=GENS,
                                propose=_fixed),
                     store))
    (a, store_a), (b, _) = runs
    assert a.material == b.material and a.loss == b.loss
    screened = a.stages[1].screened
    assert 2 <= len(screened) <= 7  # stage 2 starts by re-scoring stage 1's best distinct candidates
    assert [s.evaluations for s in a.stages] == [GENS * 7, GENS * 7 + len(screened)]  # no NaN: no resampling
    assert a.simulations == GENS * 7 * 1 + GENS * 7 * 2 + len(screened)
    # the previous estimate is among them, and the others are the best of stage 1's archive, spread out
    assert screened[0][:3] == pytest.approx(list(E.normalize(a.stages[0].material.as_array())))
    xs = np.array([r[:3] for r in screened])
    assert min(np.linalg.norm(p - q) for i, p in enumerate(xs) for q in xs[:i]) >= E.WARM_START_SPACING
    # ... and stage 2 starts from the one that fits both setups best
    assert a.stages[1].x0 == pytest.approx(min(screened, key=lambda r: r[3])[:3])
    # the returned candidate is the best evaluated one of the final stage, recomputed from the store
    eids = [batch.experiment_id(e.frames, e.name) for e in exps]
    fw = Forward(store_a, simulator=SIM)
    best = min(
        np.mean([store_a.get_loss(fw.request(Material.from_array(denormalize(h)), e, DEMO.search), eid)
                 for e, eid in zip(exps, eids)])
        for h in [gen.best_x for gen in a.stages[1].history] + [r[:3] for r in screened]
    )
    assert a.loss == pytest.approx(best)
    assert a.stages[1].sigma0 == pytest.approx(a.stages[0].sigma0 * 2 / 3)
    assert a.next_setup == Setup(60, 25)
    # stage losses never increase along a stage's history; two setups pin the fake model down
    hist = [h.best_loss for h in a.stages[1].history]
    assert all(x >= y for x, y in zip(hist, hist[1:]))
    assert e_rel(TRUTH, a.material) < e_rel(TRUTH, E.center())


def test_nan_from_failed_simulations_is_resampled(tmp_path):
    store = Store(tmp_path)
    exps = _footage(store, setups=((30, 50),))
    est = E.estimate(exps, preset=DEMO, seed=3, forward=Forward(store, simulator="fake_forward:simulate_flaky"),
                     generations=10, propose=_fixed)
    doomed = [r for r in store.requests() if int(r.key[:8], 16) % 4 == 0]  # the ones simulate_flaky fails
    assert len(doomed) > 0 and store.count("failed") == len(doomed)
    assert np.isfinite(est.loss) and est.material.in_space()
    stage = est.stages[0]
    assert stage.generations == 10 and stage.evaluations > 10 * 7  # failed candidates were redrawn
    assert est.loss < 0.05


def test_propose_chains_setups_with_acquire(tmp_path):
    store = Store(tmp_path)
    est, filmed = E.emulate_virheometry(TRUTH, Setup(30, 50), n_setups=2, seed=1,
                                        forward=Forward(store, simulator=SIM), generations=4, propose=_fixed)
    assert [str(setup_of(f)) for f in filmed] == ["30x50", "60x25"]
    assert [f.path for f in filmed] == [None, None] and [f.name for f in filmed] == ["emulated_30x50", "emulated_60x25"]
    assert est.setups == ["30x50", "60x25"] and [s.setups for s in est.stages] == [["30x50"], ["30x50", "60x25"]]
    assert est.preset == "demo" and (est.model.cell_mm, est.model.ppc) == (DEMO.cell_mm, DEMO.ppc)


class _Interrupt(Exception):
    pass


def _stage(exps, store, generations, progress=None):
    return E.run_stage(exps, x0=E.normalize(E.center().as_array()), sigma0=0.2, model=DEMO.search, seed=5,
                       generations=generations, forward=Forward(store, simulator=SIM), progress=progress)


def test_a_fraction_of_a_generation_ends_the_stage_on_a_partial_one(tmp_path):
    """A budget of 3 + 3/7 generations draws 24 candidates: three generations as a whole-generation stage of 3 draws
    them (the same CMA-ES, the same best so far), then a partial fourth of 3 draws; its id is its own."""
    exps = _footage(Store(tmp_path / "truth"), setups=((30, 50),))
    whole = _stage(exps, Store(tmp_path / "whole"), 3)
    part = _stage(exps, Store(tmp_path / "part"), 3 + 3 / 7)
    assert whole.evaluations == 21 and part.evaluations == 24 and part.history[-1].drawn == 24
    assert [h.best_x for h in part.history[:3]] == [h.best_x for h in whole.history]
    assert part.loss <= whole.loss
    kw = dict(x0=[0.5] * 3, sigma0=0.2, seed=5, search_space="linear", shape=None)
    objective = cma_stage.Objective(exps, DEMO.search, Forward(Store(tmp_path / "ids"), simulator=SIM), None)
    ids = {cma_stage._stage_id(objective, generations=g, **kw) for g in (3, 3.0, np.int64(3), 3 + 3 / 7)}
    assert len(ids) == 2  # whole generations keep the ids they always had, however the number is typed


def test_ipop_restarts_keep_the_budget_the_best_and_resume(tmp_path, monkeypatch):
    exps = _footage(Store(tmp_path / "truth"), setups=((30, 50),))
    plain = _stage(exps, Store(tmp_path / "plain"), 30)  # STALL_DRAWS = 20 generations: no restart on this toy
    assert {h.restarts for h in plain.history} == {0}
    monkeypatch.setattr(cma_stage, "STALL_DRAWS", 3 * 7)
    shown = []
    ref = _stage(exps, Store(tmp_path / "ref"), 30,
                 progress=lambda ev: shown.append(ev.generation) if isinstance(ev, GenerationDone) else None)
    # the progress bar, the stage record (result.json) and the budget agree; CMA-ES iterations are fewer
    assert shown[-1] == ref.generations == 30 and ref.cma_iterations == len(ref.history) < 30
    draws = np.diff([0] + [h.drawn for h in ref.history])
    restarts = [h.restarts for h in ref.history]
    assert max(restarts) >= 1
    assert all(d == 7 * 2**r for d, r in zip(draws[:-1], restarts))  # IPOP: each restart doubles the population
    assert draws[-1] <= 7 * 2 ** restarts[-1]  # the last generation may be cut short by the budget ...
    assert ref.history[-1].drawn == ref.evaluations == 30 * 7  # ... which is spent exactly (no NaN here)
    # until the first restart both runs are the same CMA-ES; the restarts can only improve on what it had found
    first = restarts.index(1)
    assert [h.best_x for h in ref.history[:first]] == [h.best_x for h in plain.history[:first]]
    assert ref.loss <= ref.history[first - 1].best_loss
    # interrupted after a restart and run again: the same stage as the uninterrupted run
    store = Store(tmp_path / "killed")

    def stop(event):
        if isinstance(event, GenerationDone) and event.generation * 7 > ref.history[first].drawn:
            raise _Interrupt

    with pytest.raises(_Interrupt):
        _stage(exps, store, 30, progress=stop)
    resumed = _stage(exps, store, 30)
    assert resumed.material == ref.material and resumed.loss == ref.loss
    assert [h.drawn for h in resumed.history] == [h.drawn for h in ref.history]


_RUNNER = textwrap.dedent("""
    import json, sys
    sys.path[:0] = [{repo!r}, {tests!r}]
    from mpm.store import Store
    from similarity import estimate as E
    from mpm.params import Material, Setup
    from mpm.forward import Forward
    forward = Forward(Store(sys.argv[1]), simulator="fake_forward:simulate")
    exps = E.emulate(Material(3.0, 0.6, 12.0), [Setup(30, 50), Setup(60, 25)], forward=forward,
                     image_size=(192, 108))
    est = E.estimate(exps, preset="demo", seed=11, forward=forward, generations=10, propose=lambda m, d: Setup(60, 25))
    print(json.dumps(est.material.to_dict()), flush=True)
""")


def _run(store_dir, log, *, kill_after=None):
    env = dict(os.environ, FAKE_FORWARD_LOG=str(log), FAKE_FORWARD_DELAY="0.004")
    code = _RUNNER.format(repo=str(TESTS.parent), tests=str(TESTS))
    proc = subprocess.Popen([sys.executable, "-c", code, str(store_dir)], env=env, stdout=subprocess.PIPE, text=True)
    if kill_after is None:
        out, _ = proc.communicate(timeout=120)
        assert proc.returncode == 0
        return json.loads(out.strip().splitlines()[-1])
    deadline = time.time() + 60
    while time.time() < deadline:  # wait until the second stage is under way
        if log.exists() and len(log.read_text().split()) >= kill_after:
            break
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert proc.returncode == -signal.SIGKILL
    return None


def test_kill_9_and_resume(tmp_path):
    reference = _run(tmp_path / "uninterrupted", tmp_path / "ref.log")
    store_dir, log1, log2 = tmp_path / "killed", tmp_path / "first.log", tmp_path / "second.log"
    _run(store_dir, log1, kill_after=7 * 10 + 40)  # stage 1 done (70 sims), stage 2 part-way
    finished = {r.key for r in Store(store_dir).requests()}
    assert 70 < len(finished) < 2 + 70 + 140
    resumed = _run(store_dir, log2)
    redone = set(log2.read_text().split()) & finished
    assert not redone, f"{len(redone)} finished simulations were run again"
    assert resumed == reference
    ref_count = len(set((tmp_path / "ref.log").read_text().split()))
    assert Store(store_dir).count() == ref_count  # same simulations in the end, none extra


@pytest.mark.slow
def test_real_solver_end_to_end_small(tmp_path, monkeypatch):
    """Real MPM at 7 mm cells: deterministic forward model, a short estimation improves on the start,
    and a rerun is served entirely from the store with the same estimate."""
    monkeypatch.setenv("VIRHEO_THREADS", "1")
    tiny = E.Preset("tiny", generations=2, cell_mm=7.0, sigma0=0.2)
    store = Store(tmp_path)
    forward = Forward(store)
    truth = Material(1.0, 0.7, 5.0)
    (exp,) = E.emulate(truth, [Setup(30, 30)], preset=tiny, forward=forward)
    assert exp.frames.shape == (8, 540, 960) and exp.frames.any()
    # determinism: simulating the ground truth again (bypassing the store) gives the same pictures
    again = batch.run_one(forward.request(truth, exp, tiny.search))
    assert np.array_equal(again.silhouettes, exp.frames)
    est = E.estimate([exp], preset=tiny, seed=0, forward=forward, propose=None)
    assert store.count() == 1 + est.simulations
    start = cma_stage.Objective([exp], tiny.search, forward, None)
    assert est.loss <= start([E.normalize(E.center().as_array())])[0]
    n = store.count()
    rerun = E.estimate([exp], preset=tiny, seed=0, forward=forward, propose=None)
    assert store.count() == n and rerun.material == est.material


def test_footage_preset_finishes_at_the_papers_discretisation(tmp_path):
    """Coarse-to-fine on two-particle models: stages 1..N on 2 mm cells, then a warm-started stage at the paper's
    1.26 mm cells; two particles per cell per axis and sticking walls throughout."""
    footage = E.get_preset("footage")
    assert (PAPER_MODEL.cell_mm, PAPER_MODEL.ppc) == (1.26, 2)
    assert footage.search.cell_mm > PAPER_MODEL.cell_mm and footage.ppc == 2 and footage.finish_generations > 0
    exps = _footage(Store(tmp_path / "truth"))
    store = Store(tmp_path / "run")
    forward = Forward(store, simulator=SIM)
    est = E.estimate(exps, preset=footage, seed=2, forward=forward, generations=3, propose=_fixed)
    coarse, fine = est.stages[:-1], est.stages[-1]
    assert [s.finish for s in est.stages] == [False, False, True]
    assert [(s.model.cell_mm, s.model.ppc) for s in coarse] == [(footage.cell_mm, footage.ppc)] * 2
    assert fine.setups == ["30x50", "60x25"] and fine.generations == footage.finish_generations
    assert fine.sigma0 == pytest.approx(coarse[-1].sigma0 * 2 / 3)
    # the stored requests: every simulation of the finishing stage (its warm start included) ran at the
    # paper's discretisation, and only those did
    stored = store.requests()
    finished = [r for r in stored if (r.model.cell_mm, r.model.ppc) == (PAPER_MODEL.cell_mm, PAPER_MODEL.ppc)]
    assert len(finished) == fine.simulations == 7 * 2 + footage.finish_generations * 7 * 2
    assert all((r.model.cell_mm, r.model.ppc) == (footage.cell_mm, footage.ppc) for r in stored if r not in finished)
    # ... and no stage slips or corrects the density
    assert {r.model.slip_length_m for r in stored} == {None}
    assert not any(r.model.density_correction for r in stored)
    # the answer and its loss are the finishing stage's, recomputed from the store at that discretisation
    assert est.material == fine.material and est.model == footage.final.resolved() == fine.model
    assert (est.model.cell_mm, est.model.ppc) == (PAPER_MODEL.cell_mm, PAPER_MODEL.ppc)
    eids = [batch.experiment_id(e.frames, e.name) for e in exps]
    assert est.loss == pytest.approx(np.mean([store.get_loss(forward.request(est.material, e, est.model), eid)
                                              for e, eid in zip(exps, eids)]))
    # it starts from the coarse estimate's re-scored neighbourhood and can only improve on it there
    assert fine.screened[0][:3] == pytest.approx(list(E.normalize(coarse[-1].material.as_array())))
    assert est.loss <= min(r[3] for r in fine.screened)
    d = est.to_dict()
    assert d["model"] == {"cell_mm": PAPER_MODEL.cell_mm, "ppc": PAPER_MODEL.ppc, "slip_length_m": 0.0,
                          "density_correction": False, "flow_rule": "paper", "engine": None}
    assert [s["model"] for s in d["stages"]] == [s.model.to_dict() for s in est.stages]
    assert d["warnings"] == E.bound_warnings(est.material)
    # one slip length for all stages (virheo estimate --slip-mm): the finishing stage takes it too
    assert replace(footage, slip_length_m=1e-3).final == replace(PAPER_MODEL, slip_length_m=1e-3)
    # the density correction (virheo estimate --density-correction) likewise reaches every stage
    corrected = replace(footage, density_correction=True)
    assert corrected.search.density_correction and corrected.final == replace(footage.final, density_correction=True)


@pytest.mark.parametrize("material, expected", [
    (Material(5.0, 0.6, 10.0), []),
    (Material(1e-4, 0.6, 0.0), []),  # eta and sigma_y cannot lie below their lower bounds
    (Material(29.5, 0.6, 10.0), ["eta upper"]),
    (Material(5.0, 0.31, 39.9), ["n lower", "sigma_y upper"]),
    (Material(5.0, 0.995, 10.0), ["n upper"]),
    (Material(5.0, 0.3 + 0.7 * 0.021, 10.0), []),  # just outside the margin
])
def test_bound_warnings_name_the_parameter_and_bound(material, expected):
    lines = E.bound_warnings(material)
    assert [" ".join(w.split()[:1] + [w.split("space's ")[1].split()[0]]) for w in lines] == expected
    assert all("may lie outside" in w for w in lines)


@pytest.mark.parametrize("recorded, slip, corrected", [
    ({}, 0.0, False), ({"slip_length_m": 0.0}, 0.0, False), ({"slip_length_m": 1e-3}, 1e-3, False),
    ({"density_correction": False}, 0.0, False), ({"slip_length_m": 0.0, "density_correction": True}, 0.0, True)])
def test_a_run_is_reread_with_the_model_it_was_estimated_with(tmp_path, shared_data, recorded, slip, corrected):
    """load_run takes the walls' slip length and the density correction from the run's result, not from today's
    preset: a run that does not say them (older runs) had sticking walls and no correction; its report and
    re-scoring must simulate that model, in every stage."""
    from mpm.solver import DEFAULT_CELL_MM, PARTICLES_PER_CELL
    from similarity.run_folder import load_run

    folder = shared_data / "real_world" / "ref_JapaneseThickenedWorcestershireSauce_2.0_3.0_2"
    disc = {"cell_mm": DEFAULT_CELL_MM, "ppc": PARTICLES_PER_CELL, **recorded}
    (tmp_path / "result.json").write_text(json.dumps({
        "estimate": {"eta": 1.0, "n": 0.6, "sigma_y": 2.0}, "preset": "footage", "folders": [str(folder)],
        "setups": ["30x20"], "discretisation": disc}))
    run = load_run(tmp_path)
    for model in (run.preset.search, run.preset.final):
        assert model.slip_length_m == slip and model.density_correction == corrected
    req = run.forward.request(run.estimate, run.experiments[0], run.preset.final)
    assert req.model.slip_length_m == (slip or None)  # sticking requests keep the store key they always had
    assert req.model.density_correction == corrected


def test_search_coordinates_are_log_eta_and_invert():
    from similarity.space import LOWER, UPPER, from_search, normalize, to_search

    x = np.random.default_rng(0).random((50, 3))
    for space in ("linear", "log-eta"):
        assert np.allclose(from_search(to_search(x, space), space), x, atol=1e-12)
    assert np.array_equal(to_search(x, "linear"), x)
    u = to_search(normalize([np.sqrt(LOWER[0] * UPPER[0]), 0.7, 3.0]), "log-eta")
    assert np.allclose(u, [0.5, 4 / 7, 3 / 40])  # the geometric middle of eta's range is the middle; n, sigma_y linear
    # equal steps in u are equal factors in eta
    etas = LOWER[0] + from_search([[0.2, 0.5, 0.5], [0.4, 0.5, 0.5], [0.6, 0.5, 0.5]], "log-eta")[:, 0] * (UPPER - LOWER)[0]
    assert np.isclose(etas[1] / etas[0], etas[2] / etas[1])
    with pytest.raises(ValueError, match="search space"):
        to_search(x, "log-n")


def test_a_log_eta_stage_records_the_normalised_space(tmp_path):
    runny = Material(0.6, 0.8, 2.0)
    exps = _footage(Store(tmp_path / "truth"), setups=((30, 50),), truth=runny)
    forward = Forward(Store(tmp_path / "s"), simulator=SIM)
    kw = dict(x0=E.normalize(E.center().as_array()), sigma0=0.2, model=DEMO.search, seed=5, generations=6,
              forward=forward)
    stage = E.run_stage(exps, search_space="log-eta", **kw)
    assert stage.search_space == "log-eta" and stage.to_dict()["search_space"] == "log-eta"
    rows = np.array(stage.archive)
    mats = [Material.from_array(denormalize(r[:3])) for r in rows]
    assert np.allclose(forward.losses(mats, exps, DEMO.search)[:, 0], rows[:, 3])  # rows are (x, loss) pairs
    best = rows[np.argmin(rows[:, 3])]
    assert np.allclose(stage.material.as_array(), denormalize(best[:3])) and stage.loss == best[3]
    # the draws are spread in log(eta): the 42 candidates span more than a decade of eta
    assert rows[:, 0].max() / max(rows[:, 0].min(), 1e-9) > 10
    linear = E.run_stage(exps, **kw)  # another stage (its own checkpoint), the paper's coordinates
    assert linear.search_space == "linear" and "search_space" not in linear.to_dict()
    assert not np.array_equal(np.array(linear.archive), rows)


def test_the_finishing_stage_carries_the_search_stages_covariance_shape(tmp_path):
    exps = _footage(Store(tmp_path / "truth"))
    carry = replace(DEMO, generations=12, finish_generations=2, finish=DEMO.search, carry_covariance=True)
    forward = Forward(Store(tmp_path / "s"), simulator=SIM)
    est = E.estimate(exps, preset=carry, seed=3, forward=forward, propose=None)
    one, two, fin = est.stages
    assert one.shape is None and two.shape is None  # a new setup changes the valley: those start as spheres
    assert fin.finish and fin.shape == two.end_shape and "shape" in fin.to_dict()
    axes = np.sqrt(np.linalg.eigvalsh(np.array(two.end_shape)))
    assert np.isclose(axes.max(), 1.0) and axes.min() < 0.5  # stage 2 learned an elongated, unit-scaled shape
    # the finish's first generation spreads along that shape: its draws' covariance shares the long axis
    X = np.array([r[:3] for r in fin.archive[:7]])
    long_axis = np.linalg.eigh(np.array(two.end_shape))[1][:, -1]
    spread = np.linalg.eigh(np.cov(X.T))[1][:, -1]
    assert abs(spread @ long_axis) > 0.7
    again = E.estimate(exps, preset=carry, seed=3, forward=forward, propose=None)  # from the store's checkpoints
    assert again.material == est.material and again.simulations == est.simulations
    plain = E.estimate(exps, preset=replace(carry, carry_covariance=False), seed=3, forward=forward, propose=None)
    assert plain.stages[-1].shape is None and "shape" not in plain.stages[-1].to_dict()
