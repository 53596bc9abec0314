"""Typed records read the files written before they existed: study case files, a run's stage history, posterior.json
and pickled checkpoints of a running stage.

The fixtures in ``fixtures/before_typed_records`` were written by the code at commit 35447d0 (dict records) with
the fake forward model (``VIRHEO_SIMULATOR=fake_forward:simulate``, ``--workers 0``):
``design_case.json``: ``virheo study design --cases 1 --generations 5``, case 0;
``calibration_case.json``: ``virheo study calibration --cases 1 --setting same --generations 3
--new-simulations 12 --half-width 0.5 --min-ess 100 --max-steps 500``, case 0;
``demo_result.json``: ``virheo demo --generations 3``; ``demo_posterior.json``: ``virheo report`` of that run
(``--new-simulations 8 --min-ess 300 --half-width 0.5 --no-discretisation``), its EIG grid and flow band cut short.
``design_information/`` was written by the code at commit 7a5399b (dict records, before the study skeleton), the
same way: ``virheo study design-information --materials 2 --held-out 1 --candidates 2 --generations 3 --maps 1
--map-steps 2 --posterior-check 1``, its outputs and parts (figures left out).
"""
import json
import pickle
import shutil
from pathlib import Path

import numpy as np
import pytest

from mpm.forward import ForwardModel
from mpm.params import Material, Setup
from similarity.cma_stage import Generation, Stage, StageState, _strategy
from similarity.posterior_summary import PosteriorSummary, read_posterior
from studies import calibration as C
from studies import credible as CR
from studies import design_information as DI
from studies import design_study as D

BEFORE = Path(__file__).resolve().parent / "fixtures" / "before_typed_records"


def _fixture(name) -> dict:
    return json.loads((BEFORE / name).read_text())


class _NoForward:
    """Fails the test if a case that should be read back is run."""

    store = None

    def __getattr__(self, name):
        raise AssertionError(f"a finished case was run again (forward.{name})")


def _case_folder(tmp_path, name, rel) -> Path:
    folder = tmp_path / rel
    folder.mkdir(parents=True)
    (folder / "case.json").write_text((BEFORE / name).read_text())
    return folder


def test_design_case_file_from_before_is_finished_and_loads(tmp_path):
    old = _fixture("design_case.json")
    out = tmp_path / "design"
    folder = _case_folder(out, "design_case.json", "cases/case_00")
    study = D.DesignStudy(out, old["config"], cases=1)
    planned = list(study.cases())
    # the study plans the same case the old code ran, in the same folder ...
    assert len(planned) == 1 and planned[0].folder == folder
    assert planned[0].truth.to_dict() == old["truth"] and str(planned[0].first) == old["first_setup"]
    # ... finds it finished and reads it back without simulating
    rec = study.case(planned[0], forward=_NoForward())
    assert isinstance(rec, D.DesignRecord) and isinstance(rec.truth, Material)
    assert isinstance(rec.stage_1, D.StageOne) and all(isinstance(v, D.CriterionRun) for v in rec.criteria.values())
    assert rec.to_dict() == old  # the same JSON: old and new case files are one format
    # the study's outputs from it: its case as it was, a summary that counts it
    res = study.write()
    assert res["cases"] == [old] and res["summary"]["cases"] == 1
    good = sum(v["e_rel"] <= D.GOOD for v in old["criteria"].values())
    assert sum(v["good"] for v in res["summary"]["criteria"].values()) == good
    assert D.DesignSummary.from_dict(res["summary"]).to_dict() == res["summary"]  # design.json's summary reads back
    # another configuration is told in one line, before anything runs
    other = D.DesignStudy(out, old["config"] | {"seed": 1}, cases=1)
    with pytest.raises(ValueError, match="other settings"):
        other.case(planned[0], forward=_NoForward())


def test_calibration_case_file_from_before_is_finished_and_loads(tmp_path):
    old = _fixture("calibration_case.json")
    out = tmp_path / "cal"
    folder = _case_folder(out, "calibration_case.json", "cases/same/case_00")
    study = C.CalibrationStudy(out, old["config"], cases=1, settings=("same",))
    (planned,) = study.cases()
    assert planned.folder == folder and planned.truth.to_dict() == old["truth"] and str(planned.setup) == old["setup"]
    rec = study.case(planned, forward=_NoForward())
    assert isinstance(rec, C.CalibrationRecord) and rec.width_90 is None  # no samples saved beside it
    assert rec.to_dict() == old
    summ = study.summary([rec])
    s = summ.settings["same"]
    assert s.cases == 1 and s.inside_90["hpd"] == int(old["credible_level"]["hpd"] <= CR.NOMINAL)
    assert summ.to_dict()["same"]["median_e_rel"] == old["e_rel"]


def _without_wall_time(result: dict) -> str:
    return json.dumps({k: v for k, v in result.items() if k != "wall_seconds"})  # key order kept


def test_design_information_run_from_before_is_finished_and_writes_the_same(tmp_path):
    out = tmp_path / "di"
    shutil.copytree(BEFORE / "design_information", out)
    old = {name: (out / name).read_text() for name in ("design_information.json", "design_information.md",
                                                        "design_validation.json")}
    for name in old:
        (out / name).unlink()
    before = json.loads(old["design_information.json"])
    study = DI.InformationStudy(out, before["config"], maps=1, map_steps=2, posterior_check=1)
    planned = list(study.cases())
    assert [c.folder for c in planned] == [out / "cases" / f"case_{i:02d}" for i in range(2)]
    # every material, the map and the posterior check are finished: read back without simulating
    recs = [study.case(c, forward=_NoForward()) for c in planned]
    assert all(isinstance(r, DI.InformationRecord) and isinstance(r.stage_1, DI.StageOne) for r in recs)
    assert [r.to_dict() for r in recs] == before["cases"]  # the same JSON: old and new case files are one format
    study.after_cases(recs, forward=_NoForward())
    # the outputs written from them are the ones the old code wrote (but its wall time)
    res = study.write()
    assert _without_wall_time(json.loads((out / "design_information.json").read_text())) == _without_wall_time(before)
    assert (out / "design_information.md").read_text() == old["design_information.md"]
    assert (out / "design_validation.json").read_text() == old["design_validation.json"]
    assert DI.InformationSummary.from_dict(res["summary"]).to_dict() == res["summary"]
    # the gains a record recomputes from its Hessians are the ones it stored
    for r in recs:
        for measure in ("gain", "gain_min_eig", "gain_shape"):
            np.testing.assert_allclose(r.realised(measure), np.array(getattr(r, measure), float), rtol=1e-12)
    other = DI.InformationStudy(out, before["config"] | {"candidates": 3})
    with pytest.raises(ValueError, match="other settings"):
        other.case(planned[0], forward=_NoForward())


def test_stage_history_of_a_result_file_from_before_loads():
    result = _fixture("demo_result.json")
    stages = [Stage.from_dict(s) for s in result["stages"]]
    assert [s.to_dict() for s in stages] == result["stages"]  # result.json's stages, written the same way
    for s in stages:
        assert all(isinstance(h, Generation) for h in s.history)
        assert [h.drawn for h in s.history] == sorted(h.drawn for h in s.history)
        best = [h.best_loss for h in s.history]
        assert best == sorted(best, reverse=True) and best[-1] == s.loss  # the stage's best, reached last
        assert s.history[-1].simulations == s.simulations


def _state_with_dict_history(history) -> StageState:
    """A StageState as pickled before the history was typed: its generations as dicts."""
    state = StageState(es=_strategy([0.5, 0.5, 0.5], 0.3, 7, 0), evaluations=14, simulations=14, screened=[])
    state.history = [h.to_dict() for h in history]
    return state


def test_a_checkpoint_pickled_with_a_dict_history_resumes_typed():
    history = [Generation(generation=k, simulations=7 * k, best_loss=1.0 / k, best_x=[0.1 * k, 0.2, 0.3],
                          mean_x=[0.5, 0.5, 0.5], sigma=0.3, drawn=7 * k, restarts=0, run_best=1.0 / k)
               for k in (1, 2)]
    state = _state_with_dict_history(history)
    state.result = Stage(setups=["40x50"], x0=[0.5] * 3, sigma0=0.3, material=Material(3.0, 0.5, 15.0), loss=0.5,
                         evaluations=14, simulations=14, generations=2, model=ForwardModel(),
                         history=[h.to_dict() for h in history])
    back = pickle.loads(pickle.dumps(state))
    assert back.history == history and back.result.history == history
    assert isinstance(back.es.mean, np.ndarray)  # the strategy comes back with it


def test_posterior_json_from_before_loads_and_writes_the_same():
    old = _fixture("demo_posterior.json")
    s = PosteriorSummary.from_dict(old)
    assert s.to_dict() == old
    assert isinstance(s.posterior.mean, Material) and s.posterior.cov.shape == (3, 3)
    assert s.truth == Material(**old["truth"]) and s.ellipsoid_laplace is not None
    # the ellipsoid's axes are unit columns, sorted thin to long
    assert np.allclose(np.linalg.norm(s.ellipsoid_posterior.axes, axis=0), 1.0)
    assert list(s.ellipsoid_posterior.lengths) == sorted(s.ellipsoid_posterior.lengths)
    q = s.posterior.quantiles
    for name in ("eta", "n", "sigma_y"):
        assert getattr(q["5"], name) <= getattr(q["50"], name) <= getattr(q["95"], name)
    assert Setup.parse(s.next_setups_eig[0]["setup"]).in_space()


def test_read_posterior_from_a_folder_and_its_one_line_errors(tmp_path):
    (tmp_path / "posterior.json").write_text((BEFORE / "demo_posterior.json").read_text())
    assert read_posterior(tmp_path).to_dict() == _fixture("demo_posterior.json")
    (tmp_path / "posterior.json").write_text(json.dumps({"posterior": {"mean": {"eta": 1}}}))
    with pytest.raises(ValueError, match="not a posterior summary"):
        read_posterior(tmp_path)
