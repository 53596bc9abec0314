"""Calibration study: the credible-level bookkeeping (studies/credible.py) against a Gaussian with known regions,
the design, and a tiny study on the fake forward model that resumes without simulating again."""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2, norm

from similarity.space import normalize
from studies import calibration as C
from studies import credible as CR

TESTS = Path(__file__).resolve().parent
ENV = dict(os.environ, PYTHONPATH=f"{TESTS}{os.pathsep}{TESTS.parent}", VIRHEO_SIMULATOR="fake_forward:simulate")

MEAN = np.array([0.4, 0.5, 0.6])
COV = np.array([[4.0, 1.0, 0.0], [1.0, 2.0, -0.5], [0.0, -0.5, 1.0]]) * 1e-3


@pytest.fixture(scope="module")
def gaussian():
    rng = np.random.default_rng(1)
    x = rng.multivariate_normal(MEAN, COV, size=40000)
    prec = np.linalg.inv(COV)

    def log_density(y):
        d = np.atleast_2d(y) - MEAN
        return -0.5 * np.einsum("ij,jk,ik->i", d, prec, d)

    return x, log_density


def _at_mahalanobis(level):
    """A point whose Mahalanobis distance puts it on the boundary of the Gaussian's level-``level`` region."""
    lam, vec = np.linalg.eigh(COV)
    return MEAN + vec[:, 0] * np.sqrt(lam[0] * chi2.ppf(level, 3))


@pytest.mark.parametrize("level", [0.3, 0.5, 0.9])
def test_credible_level_of_a_point_on_a_known_region_boundary(gaussian, level):
    x, logp = gaussian
    lv = CR.credible_levels(x, _at_mahalanobis(level), log_density=logp)
    # for a Gaussian the HPD region and the Mahalanobis ellipsoid are the same set {d^2 <= chi2_3(level)}
    assert lv["hpd"] == pytest.approx(level, abs=0.01)
    assert lv["ellipsoid"] == pytest.approx(level, abs=0.01)


def test_truth_inside_and_outside_the_90_percent_region(gaussian):
    x, logp = gaussian
    inside = CR.credible_levels(x, _at_mahalanobis(0.8), log_density=logp)
    outside = CR.credible_levels(x, _at_mahalanobis(0.97), log_density=logp)
    assert inside["hpd"] <= CR.NOMINAL < outside["hpd"]
    # a truth where the posterior is zero (outside the emulator's trust region) lies in no region
    cut = CR.credible_levels(x, MEAN, log_density=lambda y: np.where(np.atleast_2d(y)[:, 0] > 0.39, -np.inf, 0.0))
    assert cut["hpd"] == 1.0 and cut["ellipsoid"] < 0.05


@pytest.mark.parametrize("k", [1.0, 2.0, 3.0])
@pytest.mark.parametrize("level", [0.2, 0.6])
def test_tempered_level_is_the_gaussians_at_k_times_the_precision(level, k):
    # N(0, I) samples with log p = -|x|^2 / 2; p^k is N(0, I / k), whose level at the radius r is chi2_3(k r^2)
    x = np.random.default_rng(2).standard_normal((200000, 3))
    lp = -0.5 * np.sum(x * x, axis=1)
    r2 = chi2.ppf(level, 3)
    got, ess = CR.tempered_level(lp, float(np.mean(lp > -0.5 * r2)), k)
    assert got == pytest.approx(chi2.cdf(k * r2, 3), abs=0.01)
    # Kish ESS of the weights p^(k-1): (E w)^2 / E w^2 = (k^2 / (2k - 1))^(-3/2) for this Gaussian
    assert ess == pytest.approx((k * k / (2 * k - 1)) ** -1.5, rel=0.05)
    assert CR.tempered_level(lp, 1.0, k)[0] == 1.0  # a truth outside the support stays outside


def test_per_parameter_interval_levels(gaussian):
    x, _ = gaussian
    sd = np.sqrt(np.diag(COV))
    # eta at its 97.5 % quantile: outside the 90 % central interval, inside the 96 % one; n, sigma_y at the median
    t = MEAN + np.array([norm.ppf(0.975) * sd[0], 0.0, 0.0])
    lv = CR.credible_levels(x, t)
    assert lv["hpd"] is None
    assert lv["per_parameter"]["eta"] == pytest.approx(0.95, abs=0.01)
    assert lv["per_parameter"]["n"] < 0.02 and lv["per_parameter"]["sigma_y"] < 0.02
    assert lv["intervals"] == lv["per_parameter"]["eta"]


def test_coverage_counts_levels_at_or_below_the_nominal():
    cov = CR.coverage([0.05, 0.5, 0.95, None], nominal=[0.1, 0.5, 0.9, 1.0])
    assert cov.tolist() == [0.25, 0.5, 0.5, 1.0]


def test_design_is_nested_spread_and_in_space():
    five = C.design(5, seed=3)
    assert [(m.to_dict(), str(s)) for m, s in C.design(3, seed=3)] == [(m.to_dict(), str(s)) for m, s in five[:3]]
    x = np.array([normalize(m.as_array()) for m, _ in C.design(16, seed=0)])
    assert np.all((x >= 0.05) & (x <= 0.95))
    for k in range(3):  # every parameter's range is visited: one point in each quarter of it
        assert len(np.unique(np.floor((x[:, k] - 0.05) / 0.9 * 4))) == 4


def test_finer_footage_halves_the_cell():
    same, fine = C.footage_preset("demo", "same"), C.footage_preset("demo", "finer")
    assert fine.final.resolved().cell_mm == pytest.approx(same.final.resolved().cell_mm / 2)
    assert fine.final.resolved().ppc == same.final.resolved().ppc
    with pytest.raises(ValueError, match="setting"):
        C.footage_preset("demo", "coarser")


def _study(out, log):
    argv = [sys.executable, "-m", "studies.cli", "study", "calibration", "--cases", "2", "--setting", "same",
            "--generations", "3", "--new-simulations", "12", "--half-width", "0.5", "--min-ess", "100", "--max-steps", "500",
            "--workers", "0", "--quiet", "--out", str(out)]
    return subprocess.run(argv, env=dict(ENV, FAKE_FORWARD_LOG=str(log)), capture_output=True, text=True, timeout=600)


def test_tiny_study_runs_and_resumes_without_simulating(tmp_path):
    out, log = tmp_path / "cal", tmp_path / "sims.log"
    proc = _study(out, log)
    assert proc.returncode == 0, proc.stderr[-2000:]
    simulated = log.read_text().splitlines()
    assert len(simulated) == len(set(simulated)) > 0  # every simulation ran once
    res = json.loads((out / "calibration.json").read_text())
    assert sum(c["simulations_run"] for c in res["cases"]) == len(simulated)
    s = res["summary"]["same"]
    assert s["cases"] == 2 and "finer" not in res["summary"]
    levels = [c["credible_level"] for c in res["cases"]]
    assert s["inside_90"]["hpd"] == sum(lv["hpd"] <= CR.NOMINAL for lv in levels)
    assert s["reliability"]["levels"] == pytest.approx(list(CR.LEVELS))
    assert all(np.diff(s["reliability"]["hpd"]) >= 0)  # coverage cannot fall as the level grows
    for c in res["cases"]:
        assert 0.0 <= c["credible_level"]["hpd"] <= 1.0 and c["posterior"]["ess"] > 0
        assert c["footage_cell_mm"] == 5.0 and c["noise"]["variance"] > 0
        assert c["tempered"]["1"][0] == pytest.approx(c["credible_level"]["hpd"])  # k = 1: the level as run
        assert c["tempered"]["4"][0] >= c["tempered"]["2"][0] - 1e-12  # a sharper posterior: the truth no nearer
    assert s["tempered"]["1"]["inside_90"] == s["inside_90"]["hpd"]
    assert (out / "reliability.png").stat().st_size > 5000
    assert "| same | 2 |" in (out / "calibration.md").read_text()
    assert "| same | 2 | 2 |" in (out / "calibration.md").read_text()  # the tempering table, k = 2
    # killed after the simulations of case 1 but before its record: nothing is simulated again
    (out / "cases" / "same" / "case_01" / "case.json").unlink()
    proc = _study(out, log)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert log.read_text().splitlines() == simulated
    again = json.loads((out / "calibration.json").read_text())
    assert [c["credible_level"] for c in again["cases"]] == levels
    assert again["cases"][1]["simulations_run"] == 0


def test_bad_options_are_one_line_exit_2(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "studies.cli", "study", "calibration", "--cases", "0", "--out",
                           str(tmp_path / "x")], env=ENV, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.strip().count("\n") == 0 and "--cases" in proc.stderr
