"""The design outcome study: the pre-registered draw, the equal budget, the outcomes and the test follow from their
definitions; the quick mode runs end to end on the fake forward model and resumes without simulating."""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mpm.params import Material, Setup
from similarity.space import flow_curve_error
from studies import design_outcome as O

TESTS = Path(__file__).resolve().parent
ENV = dict(os.environ, PYTHONPATH=f"{TESTS}{os.pathsep}{TESTS.parent}", VIRHEO_SIMULATOR="fake_forward:simulate")


def test_flow_curve_error_is_the_log_ratio_of_proportional_curves():
    truth = Material(2.0, 0.6, 5.0)
    for c in (0.5, 1.0, 3.0):  # eta and sigma_y scaled alike: the stress is c times the truth's at every rate
        assert flow_curve_error(truth, Material(2.0 * c, 0.6, 5.0 * c)) == pytest.approx(abs(np.log10(c)), abs=1e-12)
    # against quadrature of the squared log error over log-spaced rates
    est = Material(1.0, 0.8, 2.0)
    g = np.geomspace(1, 100, 50)
    r = np.log10(est.stress(g)) - np.log10(truth.stress(g))
    assert flow_curve_error(truth, est) == pytest.approx(np.sqrt(np.mean(r ** 2)), rel=1e-12)


def test_the_draw_is_the_registered_one():
    drawn = O.draw(8, 62)
    assert drawn == O.draw(8, 62) and drawn != O.draw(8, 63)
    for i, (m, s) in enumerate(drawn):
        (e0, e1), (n0, n1), (s0, s1) = O.RUNNY if i < 4 else O.PASTE
        assert e0 <= m.eta <= e1 and n0 <= m.n <= n1 and s0 <= m.sigma_y <= s1 and s.in_space()
    rng = np.random.default_rng(62)  # the order of the draws: eta, n, sigma_y, width, height per material
    eta = np.exp(rng.uniform(np.log(0.5), np.log(10.0)))
    assert drawn[0][0].eta == pytest.approx(eta)
    for i, (m, s) in enumerate(drawn):
        r = O.random_setups(62, i, s)
        assert len({str(x) for x in r}) == 2 and str(s) not in {str(x) for x in r}


def test_stage_2_gets_what_the_budget_leaves():
    """Each draw simulates both setups; the criterion's work and the warm start's POPSIZE simulations in the arm's
    setup come off the budget first; a partial last generation counts; at least one generation."""
    from similarity.cma_stage import POPSIZE

    assert O.stage_2_draws(150.0, 0.0, 1.0, 2.0) == (150 - POPSIZE * 2) // 3
    assert O.stage_2_draws(150.0, 60.0, 1.0, 2.0) == (90 - POPSIZE * 2) // 3
    assert O.stage_2_draws(10.0, 60.0, 1.0, 2.0) == POPSIZE
    # equal work: a dear second setup gets fewer draws, and every arm spends the budget to within one draw
    for c2 in (0.5, 2.0, 9.0):
        d = O.stage_2_draws(300.0, 10.0, 1.0, c2)
        spent = 10.0 + POPSIZE * c2 + d * (1.0 + c2)
        assert 300.0 - (1.0 + c2) < spent <= 300.0
    with pytest.raises(ValueError, match="no measured work"):
        O.stage_2_draws(150.0, 0.0, float("nan"), 2.0)


def test_a_run_without_an_estimate_is_left_out_and_counted():
    """An arm whose stage 2 failed keeps NaN outcomes (null in JSON); the per-material means and the tests leave it
    out, and the summary counts it."""
    ok = O.ArmRun("information", "30x30", None, 0.0, 1.0, 1.0, 7, True, Material(1, 1, 1), 0.2, 0.2, 1, 0.0)
    bad = O.ArmRun("information", "30x30", None, 0.0, 1.0, float("nan"), 0, False, None, float("nan"), float("nan"),
                   0, 0.0, failed="every simulation failed in stage 2 (20x20, 30x30)")
    rand = O.ArmRun("random_0", "40x40", "no Theta", 0.0, 1.0, 1.0, 7, True, Material(1, 1, 1), 0.4, 0.4, 1, 0.0)
    recs = [O.OutcomeRecord({}, 0, 0, Material(1, 1, 1), "20x20", Material(1, 1, 1), 0.0, 0.0, [ok, rand], 0.0),
            O.OutcomeRecord({}, 0, 1, Material(1, 1, 1), "20x20", Material(1, 1, 1), 0.0, 0.0, [bad, rand], 0.0),
            O.OutcomeRecord({}, 1, 0, Material(1, 1, 1), "20x20", Material(1, 1, 1), 0.0, 0.0, [bad, rand], 0.0)]
    recs = [O.OutcomeRecord.from_dict(json.loads(json.dumps(r.to_dict()))) for r in recs]  # NaN comes back as null
    flow = O.per_material(recs)
    assert flow["information"] == {0: 0.2} and flow["random"] == {0: 0.4, 1: 0.4}
    s = O.verdict(recs)
    assert s.arms["information"].failed == 2 and s.arms["random"].fallbacks == 3
    assert s.arms["information"].against["random"].materials == 1


def test_the_verdict_names_an_arm_that_beats_random_without_the_lowest_median(tmp_path):
    def record(m, errors):
        arms = [O.ArmRun(a, "30x30", None, 0.0, 1.0, 1.0, 7, True, Material(1, 1, 1), e, e, 1, 0.0)
                for a, e in errors.items()]
        return O.OutcomeRecord({}, m, 0, Material(1, 1, 1), "20x20", Material(1, 1, 1), 0.0, 0.0, arms, 0.0)

    # eig beats random in every material; largest has the lower median but loses to random in three materials
    recs = [record(m, {"information": 0.5, "eig": 0.2, "largest": (0.05 if m < 5 else 0.9),
                       "random_0": 0.3, "random_1": 0.3}) for m in range(8)]
    s = O.verdict(recs)
    assert s.best == "largest" and s.recommended is None and not s.default_passes
    assert s.verdict.startswith("eig beats random") and "lowest median error: largest" in s.verdict
    assert s.beat_random == ["eig"]
    # `virheo design` does not call that "no criterion beat random"
    from studies import design_validation as V

    path = tmp_path / "design_outcome.json"
    path.write_text(json.dumps({"config": {}, "summary": s.to_dict()}))
    line = V.reliability_line(V.validation("eig", "reference", outcome_path=path))
    assert "weak: the study recommends no criterion (eig beat a random second setup" in line
    assert "no criterion beat a random" not in line


def test_the_paired_test_and_the_pass_rule():
    lower = {m: 0.1 for m in range(8)}
    higher = {m: 0.3 + 0.01 * m for m in range(8)}
    c = O.compare(lower, higher, "random")
    from scipy.stats import wilcoxon

    assert c.median_difference == pytest.approx(-0.235) and c.interval[1] < 0
    assert c.wilcoxon_p == pytest.approx(wilcoxon(np.array(list(lower.values())) - np.array(list(higher.values())),
                                                  alternative="less").pvalue) and c.wilcoxon_p < 0.05

    def record(m, errors):
        arms = [O.ArmRun(a, "30x30", None, 0.0, 1.0, 1.0, 1, True, Material(1, 1, 1), e, e, 1, 0.0)
                for a, e in errors.items()]
        return O.OutcomeRecord({}, m, 0, Material(1, 1, 1), "20x20", Material(1, 1, 1), 0.0, 0.0, arms, 0.0)

    good = [record(m, {"information": 0.1, "perpendicularity": 0.3, "random_0": 0.3 + 0.01 * m,
                       "random_1": 0.3 + 0.01 * m}) for m in range(8)]
    s = O.verdict(good)
    assert s.default_passes and s.recommended == "information" and s.best == "information"
    tie = [record(m, {"information": 0.3, "perpendicularity": 0.3, "random_0": 0.3, "random_1": 0.3})
           for m in range(8)]
    s = O.verdict(tie)
    assert s.default_passes is False and s.recommended is None and "no arm beats random" in s.verdict


def test_virheo_design_quotes_the_shipped_outcome_for_its_criterion(tmp_path):
    """The reliability line of `virheo design` quotes the outcome study's figures of its criterion's arm; where the
    study found no arm better than random it says so; without the study's file it falls back to the held-out line."""
    from studies import design_validation as V

    def record(m, errors):
        arms = [O.ArmRun(a, "30x30", None, 0.0, 1.0, 1.0, 1, True, Material(1, 1, 1), e, e, 1, 0.0)
                for a, e in errors.items()]
        return O.OutcomeRecord({}, m, 0, Material(1, 1, 1), "20x20", Material(1, 1, 1), 0.0, 0.0, arms, 0.0)

    path = tmp_path / "design_outcome.json"
    good = O.verdict([record(m, {"information": 0.1, "perpendicularity": 0.3, "random_0": 0.3 + 0.01 * m,
                                 "random_1": 0.3 + 0.01 * m}) for m in range(8)])
    path.write_text(json.dumps({"config": {}, "summary": good.to_dict()}))
    o = V.outcome("information", path)
    vs = good.arms["information"].against["random"]
    assert o["median_flow_error"] == pytest.approx(0.1) and o["wilcoxon_p_vs_random"] == vs.wilcoxon_p
    v = V.validation("information", "reference", outcome_path=path)
    line = V.reliability_line(v)
    assert line.startswith("reliability by estimation outcome (virheo study design-outcome, 8 materials")
    assert f"Wilcoxon p = {vs.wilcoxon_p:.2g}" in line and good.verdict in line and "weak" not in line
    assert V.outcome("perpendicularity-fitted", path) is None  # the study used the published map only
    tie = O.verdict([record(m, {"information": 0.3, "perpendicularity": 0.3, "random_0": 0.3, "random_1": 0.3})
                     for m in range(8)])
    path.write_text(json.dumps({"config": {}, "summary": tie.to_dict()}))
    line = V.reliability_line(V.validation("information", "reference", outcome_path=path))
    assert "weak: no criterion beat a random second setup" in line
    other = next(a for a in ("perpendicularity", "eig") if a != tie.best)  # the registered fallback, named
    line = V.reliability_line(V.validation(other, "reference", outcome_path=path))
    assert f"lowest median error was {tie.best}'s" in line and V.ARM_ADVICE[tie.best] in line
    line = V.reliability_line(V.validation(tie.best, "reference", outcome_path=path))
    assert "this criterion had the study's lowest median error" in line
    missing = V.validation("information", "reference", outcome_path=tmp_path / "none.json")
    assert missing["outcome"] is None and "not validated by estimation outcome" in V.reliability_line(missing)


def test_quick_study_runs_every_arm_and_resumes_without_simulating(tmp_path):
    out, log = tmp_path / "do", tmp_path / "sims.log"
    argv = [sys.executable, "-m", "studies.cli", "study", "design-outcome", "--materials", "2", "--seeds", "1",
            "--footage-model", "5:1", "--preset", "demo", "--stage-1-generations", "2", "--budget-particle-steps", "2e8",
            "--posteriors", "0", "--workers", "0", "--quiet", "--out", str(out)]
    env = dict(ENV, FAKE_FORWARD_LOG=str(log))
    proc = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    res = json.loads((out / "design_outcome.json").read_text())
    recs = [O.OutcomeRecord.from_dict(c) for c in res["cases"]]
    assert len(recs) == 2
    for r in recs:
        arms = {a.arm: a for a in r.arms}
        assert set(arms) == {"information", "perpendicularity", "eig", "largest", "random_0", "random_1", "repeat"}
        assert arms["repeat"].second_setup == r.first_setup and arms["largest"].second_setup == "70x70"
        assert [arms[f"random_{d}"].second_setup for d in range(2)] == [
            str(s) for s in O.random_setups(62, r.material_index, Setup.parse(r.first_setup))]
        for a in r.arms:
            assert a.stage_1_shared
            assert a.flow_error == pytest.approx(flow_curve_error(r.truth, a.estimate))
            assert a.failed is None and a.draws == O.stage_2_draws(2e8, a.criterion_particle_steps, a.c_first,
                                                                    a.c_second)
        assert arms["information"].criterion_particle_steps > 0 and arms["perpendicularity"].criterion_particle_steps == 0
        # equal work: the arm in the dearer box gets fewer draws
        assert arms["largest"].c_second > arms["repeat"].c_second and arms["largest"].draws < arms["repeat"].draws
    flow = O.per_material(recs)
    assert flow["random"][0] == pytest.approx(np.mean([a.flow_error for a in recs[0].arms if a.arm.startswith("random")]))
    assert res["summary"]["arms"]["information"]["per_material"] == [flow["information"][m] for m in (0, 1)]
    table = (out / "design_outcome.md").read_text()
    assert "| runs with the first random draw (criterion failed) | runs without an estimate |" in table
    before = log.read_text().splitlines()
    proc = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0 and log.read_text().splitlines() == before
    assert "Verdict:" in proc.stdout
    # the posterior outcome of one arm: its run folder filmed and estimated as the case did, then analysed
    from mpm.forward import Forward

    rec = recs[0]
    arm = next(a for a in rec.arms if a.arm == "largest")
    config = res["config"]
    with Forward(out / "store", workers=0, simulator="fake_forward:simulate") as forward:
        p = O.posterior_outcome(rec, arm, config, tmp_path / "post", forward=forward)
        # the case's footage folders and the posterior's key the same simulations: the store serves the estimate
        from mpm.experiment import load
        from similarity.presets import get_preset

        model = get_preset(config["preset"]).search
        for setup in (rec.first_setup, "70x70"):
            case_exp = load(out / "cases" / f"m{rec.material_index:02d}_s0" / "footage" / f"footage_{setup}")
            post_exp = load(tmp_path / "post" / f"footage_{setup}")
            assert (forward.request(arm.estimate, case_exp, model).key
                    == forward.request(arm.estimate, post_exp, model).key)
    assert p.estimate == arm.estimate and p.same_estimate and p.setups == [rec.first_setup, "70x70"]
    from similarity.posterior_summary import read_posterior

    s = read_posterior(tmp_path / "post")
    assert p.band_width_10 == pytest.approx(s.band_width(10.0)) and p.band_width_10 >= 1.0
    # the Herschel-Bulkley posterior alone (as registered): no special law's evidence, so no face searched
    assert [e.law for e in s.evidence.laws] == ["herschel-bulkley"]
    assert O.posterior_materials(8) == [0, 1, 4, 5] and O.posterior_materials(2, 1) == [0]


def test_arms_with_the_same_run_share_one_posterior_analysis(tmp_path, monkeypatch):
    """Three arms that ran the same two-setup estimate (70x70 mm, as often happens) are analysed once, and each gets
    that analysis' outcome under its own name; a re-run analyses nothing, and only seed 0 of the chosen materials."""
    m, other = Material(3.0, 0.8, 4.0), Material(2.0, 0.9, 5.0)

    def arm(name, setup, g, est):
        return O.ArmRun(name, setup, None, 0.0, 1.0, 2.0, g, True, est, 0.1, 0.2, 10, 1.0)

    arms = [arm("information", "70x70", 1, m), arm("eig", "70x70", 1, m), arm("largest", "70x70", 1, m),
            arm("perpendicularity", "24x20", 4, other), arm("repeat", "31x34", 3, other)]
    recs = [O.OutcomeRecord({}, i, k, m, "31x34", m, 0.1, 0.2, arms, 1.0) for i, k in ((0, 0), (0, 1), (1, 0))]
    calls = []

    def fake_outcome(record, a, config, folder, *, forward):
        calls.append((record.material_index, record.seed_index, a.arm))
        return O.PosteriorOutcome(record.material_index, a.arm, [record.first_setup, a.second_setup], a.estimate,
                                  1.5 + len(calls), True, 7.0)

    monkeypatch.setattr(O, "posterior_outcome", fake_outcome)
    study = O.DesignOutcome(tmp_path, {"materials": 4}, posteriors=2)
    study.after_cases(recs, forward=None)
    assert calls == [(0, 0, "information"), (0, 0, "perpendicularity"), (0, 0, "repeat")]
    got = {p.arm: p for p in study.posteriors()}
    assert set(got) == {a.arm for a in arms}
    for name in ("eig", "largest"):
        assert got[name].band_width_10 == got["information"].band_width_10 and got[name].wall_seconds == 0.0
    assert len({got[n].band_width_10 for n in ("information", "perpendicularity", "repeat")}) == 3
    study.after_cases(recs, forward=None)
    assert len(calls) == 3
