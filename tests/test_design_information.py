"""virheo study design-information on the fake forward model: candidates and picks as described, realised gains that
follow from the stored stencil losses, scores that follow from the gains, selection and held-out materials apart,
and a killed run that resumes without simulating again."""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mpm.params import Setup
from similarity import information as I

TESTS = Path(__file__).resolve().parent
ENV = dict(os.environ, PYTHONPATH=f"{TESTS}{os.pathsep}{TESTS.parent}", VIRHEO_SIMULATOR="fake_forward:simulate")


def _study(out, log, *extra):
    argv = [sys.executable, "-m", "studies.cli", "study", "design-information", "--materials", "3", "--held-out", "1",
            "--candidates", "3", "--generations", "3", "--maps", "1", "--map-steps", "2", "--posterior-check", "0",
            "--workers", "0", "--quiet", "--out", str(out), *extra]
    return subprocess.run(argv, env=dict(ENV, FAKE_FORWARD_LOG=str(log)), capture_output=True, text=True, timeout=300)


def _finished(out, log) -> tuple[str, list[str]]:
    """Run the tiny study to the end: (what it printed, every simulation logged so far)."""
    proc = _study(out, log)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc.stdout, log.read_text().splitlines()


def _cases(out) -> list[dict]:
    """The materials' records of a finished study, without their wall times."""
    recs = json.loads((out / "design_information.json").read_text())["cases"]
    return [{k: v for k, v in r.items() if k != "wall_seconds"} for r in recs]


def test_tiny_study_scores_follow_from_the_stencils_and_resume_without_simulating(tmp_path):
    from studies.design_information import CRITERIA, InformationRecord

    out, log = tmp_path / "di", tmp_path / "sims.log"
    stdout, simulated = _finished(out, log)
    assert len(simulated) == len(set(simulated)) > 0  # every simulation ran once
    res = json.loads((out / "design_information.json").read_text())
    cases = res["cases"]
    scores = [InformationRecord.from_dict(c).scores() for c in cases]
    assert len(cases) == 3 and res["config"]["criteria"] == list(CRITERIA)
    for c, sc in zip(cases, scores):
        cands = c["candidates"]
        seeded = cands[:c["seeded"]]
        assert c["seeded"] == 3 and len(set(seeded)) == 3 and c["first_setup"] not in cands
        assert set(c["picks"].values()) <= set(cands) and len(set(cands)) == len(cands)
        # the simulated criterion picks among its grid and predicts every candidate
        assert c["picks"]["information"] in {str(g) for g in I.grid_setups()} and "information" not in c["fallbacks"]
        assert all(p is not None and np.isfinite(p) for p in c["predicted"]["information"])
        pred = dict(zip(cands, c["predicted"]["information"]))
        assert pred[c["picks"]["information"]] == max(pred[str(g)] for g in I.grid_setups() if str(g) in pred)
        assert all(Setup.parse(s).in_space() for s in cands)
        # the gains are the log det gains of the PSD-projected FD Hessians of the stored stencil losses
        h = [I.setup_hessian(np.array(row, float), c["config"]["fd_step"]) for row in c["stencil_losses"]]
        np.testing.assert_allclose(c["gain"], I.log_det_gain(h[0], np.array(h[1:])), rtol=1e-9)
        assert np.all(np.array(c["gain"]) > -1e-9)  # information never shrinks
        g = np.array(c["gain"])
        for name, v in sc.items():
            k = cands.index(v.pick)
            assert v.gain == g[k]
            assert v.score == pytest.approx((g[k] - g[:3].mean()) / (g.max() - g[:3].mean()))
            if g[k] == g.max():
                assert v.score == pytest.approx(1.0)
    s = res["summary"]
    assert (s["selection"], s["held_out"]) == (2, 1)
    for name, v in s["gain"]["held_out"].items():
        assert v["scores"] == [scores[2][name].score]
    for name, v in s["gain"]["selection"].items():
        sc = [s[name].score for s in scores[:2]]
        assert v["scores"] == sc and v["beats_mean"] == sum(x > 0 for x in sc)
        assert v["within"] == sum(x >= 0.9 for x in sc)
    best = max((n for n in CRITERIA if CRITERIA[n]), key=lambda n: s["gain"]["selection"][n]["median_score"])
    assert s["recommended"] == (best if s["gain"]["selection"][best]["median_score"] > 0 else None)
    assert res["shipped"]["criteria"]["eig"]["materials"] == 1
    assert (out / "predicted_vs_realised.png").stat().st_size > 5000 and (out / "maps.png").stat().st_size > 5000
    assert "default criterion information on the held-out materials" in stdout
    # a killed run: the finished materials, map and posterior check are read back, a lost case.json comes from the store
    before = _cases(out)
    (out / "cases" / "case_01" / "case.json").unlink()
    stdout, again = _finished(out, log)
    assert again == simulated and _cases(out) == before
    assert "0 simulations run" in stdout
    # another configuration on the same folder: one line, exit 2, nothing simulated
    proc = _study(out, log, "--candidates", "4")
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1 and "other settings" in proc.stderr
    assert log.read_text().splitlines() == simulated


def test_posterior_check_gives_one_volume_per_candidate_and_is_read_back(tmp_path, monkeypatch):
    """The emcee posterior volume of each candidate's two-setup footage, on the fake forward model: a finite
    log-volume per candidate, smaller than the prior box's, the same result read back without simulating."""
    from mpm.forward import Forward
    from studies import design_information as D
    from studies.design_information import checks
    from studies.calibration import design
    from studies.design_study import DesignCase
    from surrogate.theta import load

    monkeypatch.syspath_prepend(str(TESTS))
    log = tmp_path / "sims.log"
    monkeypatch.setenv("FAKE_FORWARD_LOG", str(log))
    config = D._config(1, 0, 2, "demo", 2, 0.05, 0, "fake_forward:simulate")
    with Forward(tmp_path / "store", workers=0, simulator="fake_forward:simulate") as forward:
        truth, first = design(1, 0)[0]
        rec = D.run_case(DesignCase(0, truth, first, tmp_path / "case"), config=config, forward=forward,
                         thetas={t: load(t) for t in ("reference", "fitted")})
        check = checks.posterior_volume(tmp_path, rec, forward=forward, points=24, min_ess=100, max_steps=1500)
        n = len(log.read_text().splitlines())
        assert checks.posterior_volume(tmp_path, rec, forward=forward, points=24) == check
        assert len(log.read_text().splitlines()) == n
    vol = np.array(check.log_volume)
    assert len(vol) == len(rec.candidates) and np.all(np.isfinite(vol))
    assert np.all(vol < 0.5 * np.sum(np.log((2 * 0.15) ** 2 / 12)))  # narrower than the uniform box of +-0.15
    rho = checks.volume_agreement(check, rec)
    assert set(rho) == set(I.MEASURES) and all(-1 <= v <= 1 for v in rho.values() if np.isfinite(v))


@pytest.mark.parametrize("extra,needle", [(["--held-out", "12"], "--held-out"), (["--candidates", "1"], "--candidates"),
                                          (["--fd-step", "0.1"], "--fd-step"), (["--materials", "x"], "whole number")])
def test_bad_options_exit_2_with_one_line(tmp_path, extra, needle):
    argv = [sys.executable, "-m", "studies.cli", "study", "design-information", "--materials", "12",
            "--out", str(tmp_path / "o"), "--quiet", "--workers", "0", *extra]
    proc = subprocess.run(argv, env=ENV, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0], proc.stderr
    assert not (tmp_path / "o").exists()  # checked before any folder is made
