"""The seam between the inverse problem and the forward model (mpm.forward): the model value and its old layouts,
losses and store queries through the service, and result files written before the seam."""
import json
import pickle
import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pytest

from mpm import batch, runtime
from mpm.forward import Forward, ForwardModel, blank_experiment
from mpm.store import SimRequest, Store
from similarity.cma_stage import Stage
from mpm.params import Material, Setup

SIM = "fake_forward:simulate"
SIZE = (96, 54)
FIXTURE = Path(__file__).resolve().parent / "fixtures" / "run_1d40755"


def _shots(forward, truth=Material(3.0, 0.6, 12.0), setups=((30, 50), (60, 25))):
    from mpm.camera import Camera

    shells = [blank_experiment(Setup(*s), density=1000.0, camera=Camera.default(), image_size=SIZE, name=f"e{s}")
              for s in setups]
    for e, frames in zip(shells, forward.silhouettes(truth, shells, ForwardModel(5.0, 1))):
        e.frames = frames
    return shells


def test_model_round_trip_and_the_layouts_of_older_result_files():
    from mpm.solver import DEFAULT_CELL_MM, PARTICLES_PER_CELL, SLIP_LENGTH_M

    m = ForwardModel(3.0, 1, 1e-3, True, "yue2015", "native")
    assert ForwardModel.from_dict(json.loads(json.dumps(m.to_dict()))) == m
    assert ForwardModel.from_dict({"cell_mm": 5.0, "ppc": 1, "slip_length_m": 0.0, "density_correction": False}) \
        == ForwardModel(5.0, 1, 0.0, False)  # the Discretisation dict of result.json before the seam
    new = {"model": m.to_dict(), "discretisation": {"cell_mm": 9.0}}
    assert ForwardModel.of_record(new) == m  # the nested model wins
    assert ForwardModel.of_record({"discretisation": {"cell_mm": 5.0, "ppc": 1}}) == ForwardModel(5.0, 1)
    stage = {"setups": ["30x50"], "cell_mm": 3.0, "ppc": 1, "slip_length_m": 0.0, "density_correction": True,
             "loss": 0.1}  # a stage of the history before the seam: four loose fields among others
    assert ForwardModel.of_record(stage) == ForwardModel(3.0, 1, 0.0, True)
    assert ForwardModel.of_record({"estimate": {}}) == ForwardModel()  # runs that say nothing: the defaults
    full = ForwardModel(engine="taichi-cpu").resolved()
    assert full == ForwardModel(DEFAULT_CELL_MM, PARTICLES_PER_CELL, SLIP_LENGTH_M, False, "paper", "taichi-cpu")
    assert full.resolved() == full
    for bad, needle in (({"cell": 1.0}, "unknown key"), ({"engine": "gpu"}, "unknown engine"),
                        ({"cell_mm": 0.0}, "cell_mm 0 mm lies outside the accepted range"), ({"flow_rule": "x"}, "unknown flow rule")):
        with pytest.raises(ValueError, match=needle):
            ForwardModel.from_dict(bad)


def test_a_stage_checkpointed_before_the_seam_unpickles_with_its_model():
    stage = Stage(["30x50"], [0.5] * 3, 0.2, Material(1.0, 0.5, 5.0), 0.1, 7, 7, 1, ForwardModel(5.0, 1, 0.0, False))
    state = dict(stage.__dict__)
    state.pop("model")
    state |= {"cell_mm": 5.0, "ppc": 1, "slip_length_m": 0.0, "density_correction": False}
    old = Stage.__new__(Stage)
    old.__setstate__(state)
    assert old == stage and pickle.loads(pickle.dumps(stage)) == stage


def test_requests_name_the_model_and_the_engine(tmp_path):
    forward = Forward(simulator=SIM)
    shot = _shots(forward)[0]
    m = Material(2.0, 0.5, 5.0)
    req = forward.request(m, shot, ForwardModel(5.0))
    # the seam's request is the one batch.request_for builds from the resolved model (store keys unchanged)
    assert req == batch.request_for(m, shot, density=1000.0, camera=shot.camera, model=ForwardModel(5.0, 1),
                                    image_size=SIZE, simulator=SIM)
    assert req.model.engine == runtime.engine_for("f32") and req.model.slip_length_m is None and req.model.flow_rule == "paper"
    pinned = forward.request(m, shot, ForwardModel(5.0, engine="taichi-cpu", slip_length_m=1e-3))
    assert pinned.model.engine == "taichi-cpu" and pinned.model.slip_length_m == 1e-3 and pinned.key != req.key
    assert forward.with_simulator(None).request(m, shot, ForwardModel(5.0)).simulator == batch.DEFAULT_SIMULATOR


def test_losses_through_the_seam_equal_batch_evaluate_losses(tmp_path):
    truth_side = Forward(tmp_path / "truth", simulator=SIM)
    shots = _shots(truth_side)
    model = ForwardModel(5.0, 1)
    materials = [Material(eta, n, sy) for eta, n, sy in ((1.0, 0.5, 5.0), (3.0, 0.6, 12.0), (8.0, 0.9, 1.0))]
    seen = []
    with Forward(Store(tmp_path / "seam"), simulator=SIM) as forward:
        grid = forward.losses(materials, shots, model, on_result=lambda req, res, cached: seen.append(cached))
    jobs = [(batch.request_for(m, e, density=e.density, camera=e.camera, model=ForwardModel(5.0, 1), image_size=SIZE,
                               simulator=SIM), batch.experiment_id(e.frames, e.name), e.frames)
            for m in materials for e in shots]
    direct = batch.evaluate_losses(jobs, store=Store(tmp_path / "direct"), executor=batch.InlineExecutor())
    assert grid.shape == (3, 2) and np.array_equal(grid.ravel(), direct)
    assert grid[1].tolist() == [0.0, 0.0] and np.all(grid[[0, 2]] > 0)  # the truth fits its own footage exactly
    assert seen == [False] * 6 and forward.simulations_run == 6
    again = Forward(tmp_path / "seam", simulator=SIM)  # from the store, nothing simulated
    assert np.array_equal(again.losses(materials, shots, model, on_result=lambda *a: seen.append(a[2])), grid)
    assert seen[6:] == [True] * 6 and again.simulations_run == 0
    # a copy with another simulator counts into the same total; a simulation served by the store counts nothing
    other = again.with_simulator(SIM)
    other.results(Material(2.0, 0.7, 3.0), shots[:1], model)
    other.results(Material(2.0, 0.7, 3.0), shots[:1], model)
    assert again.simulations_run == other.simulations_run == 1


def _brute_force(store, forward, experiments, model):
    """The materials simulated in every experiment with ``model``, by reading every stored request."""
    templates = {json.dumps({k: v for k, v in forward.request(Material(1.0, 1.0, 0.0), e, model).to_dict().items()
                             if k not in ("eta", "n", "sigma_y")}, sort_keys=True) for e in experiments}
    counts = {}
    for r in store.requests():
        d = r.to_dict()
        mat = (d.pop("eta"), d.pop("n"), d.pop("sigma_y"))
        if json.dumps(d, sort_keys=True) in templates:
            counts.setdefault(mat, set()).add(json.dumps(d, sort_keys=True))
    return [m for m, where in counts.items() if len(where) == len(templates)]


def test_what_the_store_holds_near_x_matches_a_scan_of_every_request(tmp_path):
    store = Store(tmp_path / "store")
    forward = Forward(store, simulator="fake_forward:simulate_flaky")
    shots = _shots(Forward(simulator=SIM))
    coarse, fine = ForwardModel(5.0, 1), ForwardModel(2.5, 1)
    rng = np.random.default_rng(3)
    mats = [Material(float(a), float(b), float(c)) for a, b, c in
            zip(rng.uniform(0.1, 30, 40), rng.uniform(0.3, 1.0, 40), rng.uniform(0, 40, 40))]
    forward.losses(mats[:25], shots, coarse)  # in both setups (a quarter of them failed: they count too)
    forward.losses(mats[20:32], shots[:1], coarse)  # in one setup only
    forward.losses(mats[28:], shots, fine)  # at another model
    assert store.count("failed") > 0
    for experiments, model in ((shots, coarse), (shots[:1], coarse), (shots[1:], coarse), (shots, fine),
                               (shots[:1], fine), (shots, ForwardModel(7.0))):
        found = forward.simulated(experiments, model)
        assert [tuple(m) for m in found] == _brute_force(store, forward, experiments, model)
    assert len(forward.simulated(shots, coarse)) == 25 and len(forward.simulated(shots[:1], coarse)) == 32
    assert forward.with_simulator(SIM).simulated(shots, coarse).shape == (0, 3)  # another simulator's store rows
    assert Forward().simulated(shots, coarse).shape == (0, 3)  # no store, nothing simulated


def test_an_index_written_before_the_setting_columns_is_upgraded_on_open(tmp_path):
    forward = Forward(tmp_path / "store", simulator=SIM)
    shots = _shots(forward)
    model = ForwardModel(5.0, 1)
    forward.losses([Material(2.0, 0.5, 5.0)], shots, model)
    forward.close()
    db = sqlite3.connect(tmp_path / "store" / "index.sqlite")  # back to the table of stores before the seam
    for column in ("setting", "eta", "n", "sigma_y"):
        db.execute("DROP INDEX IF EXISTS sims_setting")
        db.execute(f"ALTER TABLE sims DROP COLUMN {column}")
    db.commit()
    db.close()
    reopened = Forward(tmp_path / "store", simulator=SIM)
    # the footage's own material first: simulated first
    assert reopened.simulated(shots, model).tolist() == [[3.0, 0.6, 12.0], [2.0, 0.5, 5.0]]
    assert reopened.store.get(reopened.request(Material(2.0, 0.5, 5.0), shots[0], model)).ok


def test_a_result_written_before_the_seam_loads_and_means_what_it_meant(tmp_path):
    """A fake-model demo's result.json written at 1d40755 (loose discretisation fields, stages with four loose
    fields): its model reads back, and the footage and loss it names are reproduced through the seam."""
    from similarity.run_folder import load_run

    folder = tmp_path / "run"
    shutil.copytree(FIXTURE, folder)
    result = json.loads((folder / "result.json").read_text())
    assert "model" not in result and "discretisation" in result
    run = load_run(folder)  # an empty store: the emulated footage is simulated again
    model = ForwardModel(5.0, 1, 0.0, False)
    assert run.preset.final.resolved() == model == ForwardModel.of_record(result)
    assert [ForwardModel.of_record(s) for s in result["stages"]] == [model] * 2
    assert run.forward.simulator == SIM and [str(s) for s in run.setups] == result["setups"]
    loss = run.forward.losses([run.estimate], run.experiments, run.preset.final).mean()
    assert loss == result["loss"]


def test_forward_closes_only_what_it_opened(tmp_path):
    store = Store(tmp_path / "s")
    with Forward(store, simulator=SIM) as forward:
        assert forward.store is store
    assert store.count() == 0  # still open
    (tmp_path / "file").write_text("x")
    with pytest.raises(NotADirectoryError):
        Forward(tmp_path / "file")
    assert isinstance(Forward(workers=0).executor, batch.InlineExecutor)


@pytest.mark.parametrize("kwargs, message", [
    (dict(ppc=99), "ppc=99 must be a whole number of particles per cell per axis within 1..4"),
    (dict(ppc=0), "ppc=0 must be a whole number"),
    (dict(ppc=1.5), "ppc=1.5 must be a whole number"),
    (dict(cell_mm=0.01), "cell_mm 0.01 mm lies outside the accepted range 0.2..10 mm"),
    (dict(cell_mm=11.0), "cell_mm 11 mm lies outside"),
    (dict(cell_mm=float("nan")), "cell_mm nan mm lies outside"),
    (dict(slip_length_m=-1e-3), "slip length -0.001 m lies outside the accepted range 0..1 m"),
    (dict(engine="gpu9000"), "unknown engine 'gpu9000'"),
    (dict(flow_rule="nope"), "nope"),
])
def test_a_model_is_validated_once_at_construction_with_the_scenes_bounds(kwargs, message):
    """Every bound the scene enforces holds at construction, as one line, so a bad model never reaches a worker;
    the bounds at the edges of the accepted ranges construct and build a scene."""
    from mpm.ranges import CELL_MM_RANGE, PPC_RANGE
    from mpm.scene import DamBreak

    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(".", r"\.")) as info:
        ForwardModel(**kwargs)
    assert "\n" not in str(info.value)
    for cell in CELL_MM_RANGE:
        for ppc in PPC_RANGE:
            ForwardModel(cell, ppc)  # the edges of the ranges are accepted
    if "cell_mm" in kwargs or "ppc" in kwargs:  # and the scene refuses what the model refuses, with the same line
        with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(".", r"\.")):
            DamBreak.build(Setup(30, 30), density=1000.0, **{"cell_mm": 5.0, "ppc": 1, **kwargs})


def test_the_cli_reports_an_out_of_range_model_as_one_line(capsys, tmp_path):
    from studies.cli import main

    for option, value, message in (("--ppc", "99", "--ppc=99 must be a whole number"),
                                   ("--cell-mm", "0.01", "--cell-mm 0.01 mm lies outside")):
        assert main(["simulate", "--material", "1,0.5,1", "--setup", "30x30", option, value,
                     "--out", str(tmp_path / "o")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith(f"virheo simulate: error: {message}"), err


def test_the_model_carries_the_elastic_moduli_to_the_worker(tmp_path):
    """kappa and mu are fields of the model: the paper's values keep the keys requests always had, others travel in
    the request to the scene the worker builds (its P-wave speed, eq. of mpm.scene.elastic_wave_speed)."""
    from mpm.camera import Camera
    from mpm.scene import KAPPA_PA, MU_PA, elastic_wave_speed

    forward = Forward(None)
    shot = blank_experiment(Setup(20, 20), density=1000.0, camera=Camera.default(), image_size=SIZE)
    m = Material(3.0, 0.6, 12.0)
    default = forward.request(m, shot, ForwardModel(5.0, 1))
    assert "kappa_pa" not in default.to_dict() and "kappa_pa" not in ForwardModel(5.0, 1).to_dict()
    assert forward.request(m, shot, ForwardModel(5.0, 1, kappa_pa=KAPPA_PA, mu_pa=MU_PA)).key == default.key
    stiff_model = ForwardModel(5.0, 1, kappa_pa=10 * KAPPA_PA, mu_pa=10 * MU_PA)
    assert ForwardModel.from_dict(stiff_model.to_dict()) == stiff_model
    stiff = forward.request(m, shot, stiff_model)
    assert (stiff.model.kappa_pa, stiff.model.mu_pa) == (1e5, 1e4) and stiff.key != default.key
    # the model travels whole: the request holds it keyed, and the stored JSON gives the same request back
    assert stiff.model == stiff_model.keyed() and SimRequest.from_dict(stiff.to_dict()) == stiff
    with pytest.raises(ValueError, match=r"kappa_pa 1e\+09 Pa lies outside the accepted range 100\.\.1e\+06 Pa"):
        ForwardModel(kappa_pa=1e9)
    soft, hard = (batch.run_one(r) for r in (default, stiff))
    assert soft.ok and hard.ok
    assert soft.stats["wave_speed"] == pytest.approx(elastic_wave_speed(1000.0))
    assert hard.stats["wave_speed"] == pytest.approx(elastic_wave_speed(1000.0, 1e5, 1e4))
    assert hard.stats["steps"] > 2 * soft.stats["steps"]  # the explicit step shrinks with the wave speed
