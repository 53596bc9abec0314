"""Second-setup criteria at equal budget: the archive belief against known quadratics, the random proposer,
the proposer protocol of the estimator, and a tiny study on the fake forward model that shares stage 1 and
resumes without simulating again."""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mpm.params import SETUP_RANGE_MM, Setup
from similarity.belief import PRIOR_PRECISION, archive_belief, frames_precision, psd_projection, quadratic_hessian
from similarity.estimate import _takes_stage
from similarity.likelihood import NoiseScale
from similarity.proposers import Eig, Random

TESTS = Path(__file__).resolve().parent
ENV = dict(os.environ, PYTHONPATH=f"{TESTS}{os.pathsep}{TESTS.parent}", VIRHEO_SIMULATOR="fake_forward:simulate")
GENERATIONS = 5  # 35 stage-1 evaluations: enough for the belief's fit (at least 30 points)


def _rotation(seed):
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return q


def _archive(h, centre, *, grad=(0.0, 0.0, 0.0), n=240, spread=0.05, seed=0, outliers=0):
    """Rows [x0, x1, x2, loss] of L = 0.01 + g.(x - c) + 1/2 (x - c)^T H (x - c) around c, plus far points of
    huge loss (which the fit must leave out)."""
    rng = np.random.default_rng(seed)
    x = centre + spread * rng.normal(size=(n, 3))
    d = x - centre
    f = 0.01 + d @ np.asarray(grad) + 0.5 * np.einsum("ij,jk,ik->i", d, h, d)
    rows = np.column_stack([x, f])
    if outliers:
        far = rng.uniform(0, 1, size=(outliers, 3))
        rows = np.vstack([rows, np.column_stack([far, 1e3 + rng.uniform(0, 1, outliers)])])
    return [list(map(float, r)) for r in rng.permutation(rows)]


def test_quadratic_fit_recovers_a_known_hessian():
    h = _rotation(1) @ np.diag([900.0, 40.0, 2.0]) @ _rotation(1).T
    x = np.random.default_rng(2).uniform(0.3, 0.4, size=(50, 3))
    d = x - 0.35
    f = 0.2 + d @ np.array([0.1, -0.3, 0.05]) + 0.5 * np.einsum("ij,jk,ik->i", d, h, d)
    np.testing.assert_allclose(quadratic_hessian(x, f), h, rtol=1e-8, atol=1e-8)
    with pytest.raises(ValueError, match="cannot determine"):
        quadratic_hessian(x[:9], f[:9])


@pytest.mark.parametrize("grad", [(0.0, 0.0, 0.0), (0.02, -0.01, 0.005)])
def test_archive_belief_is_the_inverse_hessian_over_tau(grad):
    h = _rotation(3) @ np.diag([2000.0, 150.0, 8.0]) @ _rotation(3).T
    tau = 400.0
    rows = _archive(h, np.array([0.4, 0.6, 0.3]), grad=grad, outliers=200)
    # without the prior the covariance is exactly (tau H)^-1; the far rows of huge loss are not used
    b = archive_belief(rows, tau, prior_precision=0.0)
    np.testing.assert_allclose(b.hessian, h, rtol=1e-7, atol=1e-6)
    np.testing.assert_allclose(b.covariance, np.linalg.inv(tau * h), rtol=1e-6)
    assert not b.projected and b.points == int(np.ceil(0.25 * len(rows)))
    # with the uniform prior's precision: (tau H + 12 I)^-1, and the centre is the best point evaluated
    b = archive_belief(rows, tau)
    np.testing.assert_allclose(b.covariance, np.linalg.inv(tau * h + PRIOR_PRECISION * np.eye(3)), rtol=1e-6)
    best = min(rows, key=lambda r: r[3])
    np.testing.assert_array_equal(b.center, best[:3])


def test_indefinite_hessian_is_projected_and_keeps_the_prior_variance():
    v = _rotation(5)
    h = v @ np.diag([500.0, 60.0, -30.0]) @ v.T  # the third direction curves down: no information along it
    tau = 100.0
    b = archive_belief(_archive(h, np.array([0.5, 0.5, 0.5])), tau)
    assert b.projected
    lam, vec = np.linalg.eigh(b.covariance)
    # along the negative direction the variance is the prior's, 1/12; along the others 1/(tau lambda + 12)
    var = {tuple(np.round(np.abs(v[:, k]), 6)): 1.0 / (tau * max(l, 0.0) + PRIOR_PRECISION)
           for k, l in enumerate([500.0, 60.0, -30.0])}
    for k in range(3):
        want = var[tuple(np.round(np.abs(vec[:, k]), 6))]
        assert lam[k] == pytest.approx(want, rel=1e-6)
    p, flagged = psd_projection(h)
    assert flagged and np.min(np.linalg.eigvalsh(p)) > -1e-9
    assert np.linalg.norm(p - h) == pytest.approx(30.0, rel=1e-9)  # Frobenius distance: the clipped eigenvalue


def test_belief_needs_enough_evaluations_and_a_positive_precision():
    rows = _archive(np.eye(3), np.array([0.5, 0.5, 0.5]), n=20)
    with pytest.raises(ValueError, match="at least 30"):
        archive_belief(rows, 1.0)
    with pytest.raises(ValueError, match="precision"):
        archive_belief(_archive(np.eye(3), np.array([0.5, 0.5, 0.5])), 0.0)


def test_precision_follows_the_likelihood_convention():
    tau = frames_precision(0.004, 16)
    assert tau == pytest.approx(16 / (2 * 0.004))
    assert tau == NoiseScale(1, 16.0, 0.004, 0.0, 0.0, 16).precision


def test_random_proposer_is_reproducible_on_the_grid_and_avoids_done_setups():
    lo, hi = SETUP_RANGE_MM
    done = [Setup(30, 40)]
    picks = [Random([7, i])(None, done) for i in range(300)]
    assert picks == [Random([7, i])(None, done) for i in range(300)]  # same seed, same setup
    w = np.array([s.width_mm for s in picks])
    h = np.array([s.height_mm for s in picks])
    assert np.all((w >= lo) & (w <= hi) & (h >= lo) & (h <= hi))
    assert np.all(w == np.round(w)) and np.all(h == np.round(h))  # the 1 mm grid
    assert w.min() <= lo + 2 and w.max() >= hi - 2 and h.min() <= lo + 2 and h.max() >= hi - 2  # the whole range
    assert len({str(s) for s in picks}) > 250  # uniform over 2601 setups: few repeats
    # a setup already done is never proposed again, and the draw depends on how many are done
    every = [Setup(float(a), float(b)) for a in range(lo, hi + 1) for b in range(lo, hi + 1)]
    last = Random(1)(None, [s for s in every if str(s) != "55x21"])
    assert str(last) == "55x21"


def test_estimator_hands_the_stage_only_to_proposers_that_take_it():
    def two(material, done):
        return None

    def keyword(material, done, *, stage=None):
        return None

    def anything(material, done, **kw):
        return None

    assert not _takes_stage(two) and _takes_stage(keyword) and _takes_stage(anything)
    assert not _takes_stage(Random(0)) and _takes_stage(Eig(8))


def _study(out, log, *extra):
    argv = [sys.executable, "-m", "studies.cli", "study", "design", "--cases", "2", "--generations", str(GENERATIONS),
            "--workers", "0", "--quiet", "--out", str(out), *extra]
    return subprocess.run(argv, env=dict(ENV, FAKE_FORWARD_LOG=str(log)), capture_output=True, text=True, timeout=300)


def _strip(rec):
    rec = json.loads(json.dumps(rec))
    rec.pop("wall_seconds")
    for v in rec["criteria"].values():
        v.pop("wall_seconds")
    return rec


def test_tiny_study_shares_stage_1_counts_and_resumes_without_simulating(tmp_path):
    out, log = tmp_path / "design", tmp_path / "sims.log"
    proc = _study(out, log)
    assert proc.returncode == 0, proc.stderr[-2000:]
    simulated = log.read_text().splitlines()
    assert len(simulated) == len(set(simulated)) > 0  # every simulation ran once: stage 1 was not repeated
    res = json.loads((out / "design.json").read_text())
    cases = res["cases"]
    assert len(cases) == 2 and res["config"]["criteria"] == ["perpendicularity", "eig", "random"]
    g = GENERATIONS
    for c in cases:
        assert c["stage_1_shared"] and c["stage_1"]["simulations"] == 7 * g
        runs = c["criteria"]
        assert {v["simulations"] for v in runs.values()} == {7 * g + 7 + 14 * g}  # equal budget
        assert all(v["simulations_stage_2"] == 7 + 14 * g for v in runs.values())
        # the first criterion pays for stage 1; the others only for their own stage 2 (and its footage)
        for name in ("eig", "random"):
            assert runs[name]["simulations_run"] <= 1 + runs[name]["simulations_stage_2"]
        assert all(Setup.parse(v["second_setup"]).in_space() and v["second_setup"] != c["first_setup"]
                   for v in runs.values())
        b = runs["eig"]["belief"]
        assert b is not None and b["points"] >= 30  # EIG ranked under stage 1's archive belief
        assert np.all(np.linalg.eigvalsh(np.array(b["covariance"])) > 0)
    # the footage of each first setup, then what each criterion's run simulated: the store's whole count
    assert len(simulated) == sum(1 + sum(v["simulations_run"] for v in c["criteria"].values()) for c in cases)
    s = res["summary"]
    md = (out / "design.md").read_text()
    for name, v in s["criteria"].items():
        good = sum(c["criteria"][name]["e_rel"] <= 0.1 for c in cases)
        assert v["good"] == good and v["fraction_good"] == good / 2 and v["cases"] == 2
        assert v["median_e_rel"] == pytest.approx(np.median([c["criteria"][name]["e_rel"] for c in cases]))
        assert f"| {name} | {good}/2 (" in md
    p = s["paired"]["eig vs perpendicularity"]
    assert p["better"] + p["equal"] + p["worse"] == 2
    assert s["stage_1_shared"] == 2 and s["equal_budget"] == 2
    assert (out / "e_rel.png").stat().st_size > 5000
    assert "E_rel <= 0.1 after two setups: perpendicularity" in proc.stdout
    # re-run: the finished cases are read back; a case killed after its simulations comes from the store
    before = [_strip(c) for c in cases]
    (out / "cases" / "case_01" / "case.json").unlink()
    proc = _study(out, log)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert log.read_text().splitlines() == simulated  # nothing simulated again
    again = json.loads((out / "design.json").read_text())["cases"]
    assert [_strip(c) for c in again][0] == before[0]
    rerun = _strip(again[1])
    for v in rerun["criteria"].values():
        v["simulations_run"] = None
    for v in before[1]["criteria"].values():
        v["simulations_run"] = None
    assert rerun == before[1]  # the same choices and estimates, from the store
    assert "0 simulations run" in proc.stdout
    # another configuration on the same folder: one line, exit 2, before any simulation
    proc = _study(out, log, "--seed", "1")
    assert proc.returncode == 2 and len(proc.stderr.strip().splitlines()) == 1 and "other settings" in proc.stderr
    assert log.read_text().splitlines() == simulated


@pytest.mark.parametrize("extra,needle", [(["--cases", "0"], "--cases"), (["--generations", "0"], "--generations"),
                                          (["--seed", "-1"], "--seed"), (["--cases", "two"], "whole number"),
                                          (["--preset", "fast"], "--preset")])
def test_bad_options_exit_2_with_one_line(tmp_path, extra, needle):
    argv = [sys.executable, "-m", "studies.cli", "study", "design", "--out", str(tmp_path / "o"), "--quiet", *extra]
    proc = subprocess.run(argv, env=ENV, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and needle in lines[0], proc.stderr
    assert not (tmp_path / "o" / "cases").exists()
