"""`virheo study laws` (studies/law_calibration.py): the design of the true laws, the scoring of the verdicts, and
the quick mode end to end on the fake forward model, resumed without simulating again."""
import json
import os
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from mpm.params import Material
from similarity.evidence import QUESTIONS, RESOLVED
from studies.law_calibration import TRUE_LAWS, LawRecord, design, holds, summarise

TESTS = Path(__file__).resolve().parent
ENV = dict(os.environ, PYTHONPATH=f"{TESTS}{os.pathsep}{TESTS.parent}", VIRHEO_SIMULATOR="fake_forward:simulate")


def test_design_has_the_issued_mix_of_laws():
    cases = design()
    assert len(cases) >= 16 and [c[0] for c in cases] == list(TRUE_LAWS)
    by = {law: [m for l_, m, _ in cases if l_ == law] for law in set(TRUE_LAWS)}
    assert len(by["power-law"]) >= 4 and all(m.sigma_y == 0.0 and m.n < 1 for m in by["power-law"])
    assert len(by["bingham"]) >= 4 and all(m.n == 1.0 and m.sigma_y > 0 for m in by["bingham"])
    assert len(by["newtonian"]) >= 2 and all(m.n == 1.0 and m.sigma_y == 0.0 for m in by["newtonian"])
    hb = by["herschel-bulkley"]
    assert sum(0.5 <= m.sigma_y <= 2.0 for m in hb) >= 2 and sum(0.9 <= m.n <= 0.97 for m in hb) >= 2
    for _, m, s in cases:
        assert 20 <= s.width_mm <= 70 and 20 <= s.height_mm <= 70
    assert design() == cases  # seeded


def test_cases_run_one_of_each_law_in_turn():
    from studies.law_calibration import interleaved

    order = interleaved(TRUE_LAWS)
    assert sorted(order) == list(range(len(TRUE_LAWS)))  # every case once
    laws = [TRUE_LAWS[i] for i in order]
    assert set(laws[:4]) == set(TRUE_LAWS) and set(laws[4:8]) == set(TRUE_LAWS)  # every law in each of the first rounds
    for law in set(TRUE_LAWS):  # each law's cases in their own order
        mine = [i for i in order if TRUE_LAWS[i] == law]
        assert mine == sorted(mine)


def _record(law, truth, log_bf_yield, log_bf_thin):
    verdicts = [{"question": q.name, "log_bf": b, "log_bf_err": 0.1} for q, b in zip(QUESTIONS, (log_bf_yield, log_bf_thin))]
    return LawRecord(case=0, config={}, law=law, truth=truth, setups=["30x30", "70x70"], estimate=truth, e_rel=0.0,
                     evidence={"verdicts": verdicts, "probabilities": {law: 0.9, "newtonian": 0.1}},
                     wall_seconds={"total": 1.0}, simulations_run=0)


def test_scoring_counts_resolved_right_and_decisively_wrong():
    pl, hb = Material(1.0, 0.5, 0.0), Material(1.0, 0.5, 5.0)
    recs = [_record("power-law", pl, -3.0, 5.0),  # right, right
            _record("herschel-bulkley", hb, 5.0, 1.0),  # right, unresolved
            _record("power-law", pl, 4.7, 2.4),  # decisively wrong, right
            _record("herschel-bulkley", hb, RESOLVED - 1e-6, -2.5)]  # unresolved, wrong (not decisively)
    s = summarise(recs)
    y, t = s.questions
    assert (y.resolved, y.right, y.decisively_wrong, y.unresolved_by_law) == (3, 2, 1, {"herschel-bulkley": 1})
    assert not y.passed and y.right_share == pytest.approx(2 / 3)
    assert (t.resolved, t.right, t.decisively_wrong, t.unresolved_by_law) == (3, 2, 0, {"herschel-bulkley": 1})
    assert holds(QUESTIONS[0], hb) and not holds(QUESTIONS[0], pl) and holds(QUESTIONS[1], pl)
    assert s.most_probable_right == 4
    # the thresholds are ln 10 and ln 100, inclusive; a question with nothing resolved does not meet the target
    edge = summarise([_record("herschel-bulkley", hb, np.log(10.0), 0.0), _record("power-law", pl, np.log(100.0), 0.0)])
    assert (edge.questions[0].resolved, edge.questions[0].decisively_wrong) == (2, 1)
    assert edge.questions[1].resolved == 0 and edge.questions[1].right_share is None and not edge.questions[1].passed
    # the emulator's checks: a case with a failed one is scored like the others and counted
    failed = {"posterior": {"passed": True}, "laws": {"passed": False}}
    checked = [replace(r, checks=c) for r, c in zip(recs, (failed, {"posterior": {"passed": True}, "laws": None},
                                                           None, failed))]
    assert [r.trusted for r in checked] == [False, True, None, False]
    c = summarise(checked)
    assert c.untrusted == 2 and c.questions == s.questions


def _study(out, log):
    argv = [sys.executable, "-m", "studies.cli", "study", "laws", "--quick", "--generations", "3", "--new-simulations",
            "8", "--min-ess", "100", "--workers", "0", "--quiet", "--out", str(out)]
    return subprocess.run(argv, env=dict(ENV, FAKE_FORWARD_LOG=str(log)), capture_output=True, text=True, timeout=900)


def test_quick_study_runs_and_resumes_without_simulating(tmp_path):
    out, log = tmp_path / "laws", tmp_path / "sims.log"
    proc = _study(out, log)
    assert proc.returncode == 0, proc.stderr[-2000:]
    simulated = log.read_text().splitlines()
    res = json.loads((out / "laws.json").read_text())
    assert [c["law"] for c in res["cases"]] == ["power-law", "herschel-bulkley"]
    for c in res["cases"]:
        assert len(c["setups"]) == 2
        assert [v["question"] for v in c["evidence"]["verdicts"]] == ["yield stress", "shear thinning"]
        assert sum(c["evidence"]["probabilities"].values()) == pytest.approx(1.0)
    assert sum(c["simulations_run"] for c in res["cases"]) == len(simulated)
    for c in res["cases"]:  # each case keeps whether its emulator passed its checks, and the table says so
        assert set(c["checks"]) == {"posterior", "laws"} and LawRecord.from_dict(c).trusted is not None
    assert res["failed"] == [] and "| emulator checks |" in (out / "laws.md").read_text()
    assert "| yield stress | 2 |" in (out / "laws.md").read_text() and (out / "laws.png").stat().st_size > 5000
    assert "target" in proc.stdout
    (out / "cases" / "case_01" / "case.json").unlink()  # killed before its record: nothing simulated again
    proc = _study(out, log)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert log.read_text().splitlines() == simulated


def test_report_quotes_the_round_that_estimated_at_its_preset(tmp_path):
    from studies.law_validation import DATA, calibration_line, rounds

    pl, hb = Material(1.0, 0.5, 0.0), Material(1.0, 0.5, 5.0)
    recs = [_record("power-law", pl, -3.0, 5.0), _record("herschel-bulkley", hb, 5.0, 1.0),
            _record("power-law", pl, 4.7, 2.4)]
    laws = {"config": {"preset": "survey", "quick": False}, "summary": summarise(recs).to_dict(),
            "cases": [r.to_dict() for r in recs]}
    (tmp_path / "law_calibration_x").mkdir()
    (tmp_path / "law_calibration_x" / "laws.json").write_text(json.dumps(laws))
    (tmp_path / "law_calibration_q").mkdir()  # a quick round calibrates nothing
    (tmp_path / "law_calibration_q" / "laws.json").write_text(json.dumps({**laws, "config": {"preset": "demo", "quick": True}}))
    line = calibration_line("survey", data=tmp_path)
    assert "3 materials" in line and "yield stress resolved in 3 of 3, right in 2" in line
    assert "shear thinning resolved in 2 of 3, right in 2" in line and "1 decisively wrong" in line
    assert "most probable law: power law in 2 of 3, the true one in 3" in line
    assert calibration_line("demo", data=tmp_path).startswith("laws' calibration: none at the demo preset's model")
    # the shipped rounds: their summaries are what the scoring gives on their own cases
    shipped = rounds(DATA)
    assert shipped, "no shipped round of virheo study laws"
    for d in shipped:
        again = summarise([LawRecord.from_dict(c) for c in d["cases"]]).to_dict()
        assert again["questions"] == d["summary"]["questions"] and again["cases"] == len(d["cases"]) == 18
