"""`virheo report RUN` end to end on a shortened demo with the fake forward model, and its input checks."""
import html
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from studies.cli import main

TESTS = Path(__file__).resolve().parent
ENV = dict(os.environ, PYTHONPATH=f"{TESTS}{os.pathsep}{TESTS.parent}", VIRHEO_SIMULATOR="fake_forward:simulate")


def _cli(*argv):
    return subprocess.run([sys.executable, "-m", "studies.cli", *argv], env=ENV, capture_output=True, text=True,
                          timeout=600)


@pytest.fixture(scope="module")
def reported(tmp_path_factory):
    run = tmp_path_factory.mktemp("report") / "demo"
    proc = _cli("demo", "--out", str(run), "--generations", "3", "--workers", "0", "--quiet")
    assert proc.returncode == 0, proc.stderr
    proc = _cli("report", str(run), "--workers", "0", "--new-simulations", "8", "--min-ess", "300", "--half-width", "0.5",
                "--no-discretisation", "--quiet")
    assert proc.returncode == 0, proc.stderr
    return run, proc


def test_report_page_references_only_existing_local_files(reported):
    run, proc = reported
    page = run / "report" / "index.html"
    assert f"report: {page}" in proc.stdout
    text = page.read_text()
    refs = re.findall(r'(?:src|href)\s*=\s*"([^"]*)"', text)
    assert len(refs) >= 6  # intervals, corner, flow band, ellipsoids, EIG map, one overlay per setup
    for ref in refs:
        assert not re.match(r"^[a-z]+:", ref), ref  # no http:, https:, data: or file: URLs: opens offline
        assert (page.parent / ref).is_file() and (page.parent / ref).stat().st_size > 1000, ref
    assert not re.search(r"<script|<link|@import|url\(", text)
    # the best simulated fit stands under the estimate's table where it beats the estimate by a nat
    from similarity.best_fit import NOTE_NATS
    fit = json.loads((run / "posterior.json").read_text())["best_fit"]
    assert ("A better fit than the estimate was simulated" in text) == (fit["nats"] >= NOTE_NATS)


def test_posterior_summary_is_coherent(reported):
    run, proc = reported
    s = json.loads((run / "posterior.json").read_text())
    post = s["posterior"]
    assert post["ess"] >= 300 and post["converged"]
    for k in ("eta", "n", "sigma_y"):
        assert post["quantiles"]["5"][k] <= post["quantiles"]["50"][k] <= post["quantiles"]["95"][k]
    samples = np.load(run / "posterior_samples.npy")
    assert samples.shape[1] == 3 and np.all((samples >= 0) & (samples <= 1))
    band = s["flow_band"]
    assert np.all(np.asarray(band["5"]) <= np.asarray(band["95"]))
    assert s["noise"]["n_eff"] >= s["noise"]["frames"] and s["emulator"]["n_test"] >= 1
    # the emulator's box grew until the posterior no longer reaches an inner face (or covers the space): samples
    # there would be more than REACH_NATS below the best, where a Gaussian holds 0.1 % of its mass
    assert s["emulator"]["cut_fraction"] <= 0.005 or s["emulator"]["half_width"] == 1.0
    # the posterior was checked on simulated draws (8 per fit), each of them listed before it was simulated
    check = s["emulator"]["check"]
    from similarity.emulator_check import CHECK_NATS, CHECK_ROUNDS
    assert check["draws"] == 8 and 1 <= check["rounds"] <= CHECK_ROUNDS + 1
    assert check["passed"] == (check["failed"] == 0 and check["optimism_nats"] <= CHECK_NATS)
    assert len(np.load(run / "posterior_draws.npy")) >= 8 * check["rounds"]
    # its trust region is the nominal box, clipped to the material space (a face there never counts as cut)
    from surrogate.emulator import box
    lo, hi = box(s["estimate_normalised"], s["emulator"]["half_width"])
    assert np.allclose(s["emulator"]["trust_region"], [lo, hi])
    assert np.all(samples >= lo - 1e-12) and np.all(samples <= hi + 1e-12)
    # the best simulated fit: the estimate's own simulation is in the training set, so it fits no worse than that
    from similarity.best_fit import NOTE_NATS
    fit = s["best_fit"]
    assert fit["loss"] <= fit["estimate_loss"] and fit["nats"] >= 0.0
    from similarity.likelihood import NoiseScale
    tau = NoiseScale.from_dict(s["noise"]).with_emulator(0.0).precision  # eq. (1) between simulations: no e_emul
    assert np.isclose(fit["nats"], tau * (fit["estimate_loss"] - fit["loss"]))
    assert ("a better fit than the estimate was simulated" in proc.stdout) == (fit["nats"] >= NOTE_NATS)
    lengths = s["ellipsoid_posterior"]["lengths"]
    assert lengths == sorted(lengths) and lengths[0] > 0
    assert s["next_setups_eig"] and s["next_setups_eig"][0]["eig_nats"] >= s["next_setups_eig"][-1]["eig_nats"]
    # the simulated criterion: a setup of its grid, in nats (each setup weighted by its noise, the posterior's
    # covariance), with the check of the setups done, its best three
    from similarity.information import grid_setups
    info = s["next_setup_information"]
    assert info["setup"] in {str(g) for g in grid_setups()} and info["preset"] == "demo"
    assert "log_det_gain" not in info and info["eig_nats"] > 0
    assert info["check"]["posterior_nats"] > 0 and info["check"]["hessian_nats"] > 0
    assert [t["setup"] for t in info["top"]][0] == info["setup"] and info["top"][0]["score"] == info["eig_nats"]
    assert all(t["volume_ml"] > 0 and t["cost_cpu_min"] > 0 for t in info["top"])


def test_report_prints_the_simulated_next_setup(reported):
    run, proc = reported
    from similarity.posterior_summary import read_posterior
    s = read_posterior(run)
    i = int(np.argmin(np.abs(np.asarray(s.flow_band["shear_rate"]) - 10.0)))
    assert s.flow_band["shear_rate"][i] == pytest.approx(10.0)  # a point of the band's grid: no interpolation
    assert s.band_width(10.0) == pytest.approx(s.flow_band["95"][i] / s.flow_band["5"][i]) and s.band_width(10.0) >= 1
    assert f"{s.band_width(10.0):.2f} at 10," in proc.stdout
    assert re.search(r"emulator checked on 8 simulated posterior draws \(\d fits\): [+-]\d+\.\d\d nats optimistic, "
                     r"(trusted|NOT trusted)", proc.stdout)
    info = json.loads((run / "posterior.json").read_text())["next_setup_information"]
    assert s.again == (", a setup already filmed: film it again" if info["setup"] in s.setups else "")
    assert (f"next setup by simulated information: {info['setup']} mm ({info['eig_nats']:.3f} nats; demo preset's "
            f"model, each setup weighted by its own noise{s.again})") in proc.stdout
    import dataclasses
    repeat = dataclasses.replace(s, next_setup_information={**info, "setup": s.setups[-1]})
    assert repeat.again == ", a setup already filmed: film it again"
    assert f"{info['check']['posterior_nats']:.2f} nats in the posterior" in proc.stdout
    assert f"{info['top'][0]['volume_ml']:.0f} ml" in proc.stdout
    assert "Setup of largest simulated information" in (run / "report" / "index.html").read_text()


def test_design_from_the_posterior(reported, capsys):
    run, _ = reported
    assert main(["design", "--criterion", "eig", "--posterior", str(run), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    s = json.loads((run / "posterior.json").read_text())
    assert out["criterion"] == "eig" and out["score"] > 0
    assert f"{out['next']['width_mm']:g}x{out['next']['height_mm']:g}" == s["next_setups_eig"][0]["setup"]


def test_design_information_from_the_posterior_simulates_with_the_runs_model(reported, monkeypatch, capsys):
    """--posterior RUN: the information criterion simulates with the run's own forward model (here the demo's, so the
    shipped figures apply), at the posterior mean, with the run's setups done."""
    run, _ = reported
    monkeypatch.setenv("VIRHEO_SIMULATOR", ENV["VIRHEO_SIMULATOR"])
    monkeypatch.syspath_prepend(str(Path(__file__).resolve().parent))
    assert main(["design", "--posterior", str(run), "--json", "--workers", "0"]) == 0
    out = json.loads(capsys.readouterr().out)
    s = json.loads((run / "posterior.json").read_text())
    assert out["criterion"] == "information" and out["model"].startswith("the run's model (5 mm cells")
    assert [f"{d['width_mm']:g}x{d['height_mm']:g}" for d in out["done"]] == s["setups"]
    assert out["material"] == pytest.approx(s["posterior"]["mean"])
    assert out["validation"] is not None and out["top"][0]["cost_cpu_min"] > 0
    # with the posterior's covariance and noise the score is in nats, and the report shows the same ranking
    assert out["score_unit"].startswith("nats") and out["expected_gain_nats"] == out["score"] > 0
    assert out["information_check"] == s["next_setup_information"]["check"]
    assert [t["setup"] for t in out["top"]] == [t["setup"] for t in s["next_setup_information"]["top"]]
    assert out["score"] == pytest.approx(s["next_setup_information"]["eig_nats"], rel=1e-9)


def test_corrupt_backend_is_one_line_exit_2(reported, tmp_path, capsys):
    run, _ = reported
    copy = tmp_path / "run"
    shutil.copytree(run, copy)
    (copy / "posterior.h5").write_bytes(b"\x00garbage" * 100)
    argv = ["report", str(copy), "--workers", "0", "--new-simulations", "0", "--no-discretisation", "--quiet"]
    proc = _cli(*argv)
    assert proc.returncode == 2 and "corrupt posterior backend" in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


def test_too_few_simulations_for_the_emulator_is_one_line_exit_2(reported, tmp_path):
    """A box with too few stored candidates (a store made by another solver version: none of its simulations
    serve this one) and no new simulations (none either on the laws' faces) says what to raise."""
    run, _ = reported
    copy = tmp_path / "run"
    shutil.copytree(run, copy)
    (copy / "posterior.h5").unlink()
    proc = _cli("report", str(copy), "--workers", "0", "--new-simulations", "0", "--half-width", "0.001",
                "--store", str(tmp_path / "other-solver"), "--no-discretisation", "--quiet")
    assert proc.returncode == 2 and "raise --new-simulations" in proc.stderr, proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


def test_run_without_estimate_and_bad_rheometer_file(tmp_path, capsys):
    empty = tmp_path / "run"
    empty.mkdir()
    assert main(["report", str(empty)]) == 2
    assert "no result.json" in capsys.readouterr().err
    (empty / "result.json").write_text(json.dumps({"setups": ["40x50"]}))
    assert main(["report", str(empty)]) == 2
    err = capsys.readouterr().err.strip()
    assert "holds no estimate" in err and len(err.splitlines()) == 1
    (empty / "result.json").write_text(json.dumps({"estimate": {"eta": 1, "n": 0.5, "sigma_y": 2}}))
    csv = tmp_path / "curve.csv"
    csv.write_bytes(b"\xff\xfe" + "no units row\n".encode("utf-16-le"))
    assert main(["report", str(empty), "--rheometer", str(csv)]) == 2
    err = capsys.readouterr().err.strip()
    assert "rheometer export" in err and len(err.splitlines()) == 1
    assert main(["design", "--criterion", "eig", "--posterior", str(empty)]) == 2
    assert "posterior.json" in capsys.readouterr().err


def test_the_laws_evidence_in_posterior_json_terminal_and_page(reported):
    """The report grows its box to every law's face, checks the special laws' posteriors against the simulator and
    gives each law a finite evidence with a small Monte Carlo error; the verdicts are printed and on the page."""
    from similarity.evidence import LAWS
    from similarity.posterior_summary import read_posterior

    run, proc = reported
    s = read_posterior(run)
    ev = s.evidence
    assert [e.law for e in ev.laws] == list(LAWS)
    assert sum(ev.probabilities.values()) == pytest.approx(1.0)
    lo, hi = (np.asarray(v) for v in ev.trust_region)
    assert np.allclose([lo, hi], s.emulator.trust_region)
    for law in LAWS.values():
        assert law.on_face(lo, hi), law.name
    for e in ev.laws:
        assert np.isfinite(e.log_z) and 0 < e.log_z_err < 0.3 and e.ess > 100, e
    assert s.emulator.laws_check is not None and s.emulator.laws_check.draws > 0
    assert s.emulator.laws_check.worst_face_nats is not None
    # the face search's simulations trained the emulator on every special law's face (8 generations of 6 each)
    from similarity.evidence import N_ONE, SIGMA_Y_ZERO

    with np.load(run / "posterior_training.npz") as t:
        X = t["X"]
    on_n1, on_s0 = np.isclose(X[:, 1], N_ONE), np.isclose(X[:, 2], SIGMA_Y_ZERO)
    assert np.count_nonzero(on_n1 & ~on_s0) >= 40 and np.count_nonzero(on_s0 & ~on_n1) >= 40
    assert np.count_nonzero(on_n1 & on_s0) >= 8  # the Newtonian line
    assert [v.question for v in ev.verdicts] == ["yield stress", "shear thinning"]
    for v in ev.verdicts:
        assert v.text in proc.stdout
        assert v.log_bf == pytest.approx(ev.of("herschel-bulkley").log_z - ev.of(
            "power-law" if v.question == "yield stress" else "bingham").log_z)
    page = (run / "report" / "index.html").read_text()
    assert "Which law" in page and html.escape(ev.verdicts[0].text.split("(")[0].strip()) in page
    # how the verdicts fared at the run's preset in the shipped calibration (or that none calibrates it)
    from studies.law_validation import calibration_line

    line = calibration_line(json.loads((run / "result.json").read_text())["preset"])
    assert line in proc.stdout and html.escape(line) in page


def test_virheo_laws_gives_the_reports_evidence_again(reported, capsys):
    run, _ = reported
    assert main(["laws", str(run), "--json"]) == 0
    again = json.loads(capsys.readouterr().out)
    stored = json.loads((run / "posterior.json").read_text())["evidence"]
    assert [e["log_z"] for e in again["laws"]] == pytest.approx([e["log_z"] for e in stored["laws"]], abs=1e-9)
    assert main(["laws", str(run), "--laws", "newtonian"]) == 0
    out = capsys.readouterr().out
    assert "newtonian" in out and "bingham" not in out.replace("Bingham", "")
    assert "laws' calibration" in out


def test_laws_bad_input_is_one_line_exit_2(reported, tmp_path):
    run, _ = reported
    for argv in (["laws", str(run), "--laws", "bingham,casson"], ["report", str(run), "--laws", "casson"]):
        proc = _cli(*argv)
        assert proc.returncode == 2 and "unknown law 'casson'" in proc.stderr, proc.stderr
        assert len(proc.stderr.strip().splitlines()) == 1
    copy = tmp_path / "run"
    copy.mkdir()
    shutil.copy(run / "result.json", copy)
    shutil.copy(run / "posterior.json", copy)
    proc = _cli("laws", str(copy))
    assert proc.returncode == 2 and "no posterior_samples.npy" in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1
    proc = _cli("laws", str(tmp_path / "nowhere"))
    assert proc.returncode == 2 and "no posterior.json" in proc.stderr
    bad = tmp_path / "bad"
    shutil.copytree(run, bad, ignore=shutil.ignore_patterns("store", "report", "overlays"))
    with np.load(bad / "posterior_training.npz") as t:
        arrays = {k: t[k] for k in t.files}
    np.savez(bad / "posterior_training.npz", **{**arrays, "theta": arrays["theta"][:2]})
    proc = _cli("laws", str(bad))
    assert proc.returncode == 2 and "unreadable posterior_training.npz" in proc.stderr, proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1
