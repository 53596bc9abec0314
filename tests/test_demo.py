"""`virheo demo` and `virheo estimate` end to end (shortened), and their input checks."""
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from mpm.params import Material
from mpm.runtime import ENGINES, engine_name
from similarity.estimate import bound_warnings
from similarity.presets import PRESETS
from similarity.space import e_rel
from studies.cli import main

TESTS = Path(__file__).resolve().parent


def _png(path):
    from PIL import Image

    with Image.open(path) as im:
        return np.asarray(im.convert("L"))


def test_demo_shortened_with_fake_forward_model(tmp_path):
    out = tmp_path / "demo"
    env = dict(os.environ, PYTHONPATH=f"{TESTS}{os.pathsep}{TESTS.parent}", VIRHEO_SIMULATOR="fake_forward:simulate")
    proc = subprocess.run([sys.executable, "-m", "studies.cli", "demo", "--out", str(out), "--generations", "3",
                           "--workers", "0", "--quiet"],
                          env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    result = json.loads((out / "result.json").read_text())
    for who in ("truth", "estimate"):
        assert set(result[who]) == {"eta", "n", "sigma_y"}
    assert result["truth"] == {"eta": 3.0, "n": 0.5, "sigma_y": 15.0}
    truth, estimate = Material(**result["truth"]), Material(**result["estimate"])
    assert result["e_rel"] == pytest.approx(e_rel(truth, estimate), rel=1e-12)
    assert len(result["e_rel_per_stage"]) == 2 and result["e_rel_per_stage"][-1] == result["e_rel"]
    assert result["preset"] == "demo" and result["seed"] == 0
    demo = PRESETS["demo"]
    assert result["model"] == {"cell_mm": demo.cell_mm, "ppc": demo.ppc, "slip_length_m": 0.0,
                               "density_correction": False, "flow_rule": "paper", "engine": None}
    assert result["warnings"] == bound_warnings(estimate)
    assert result["setups"][0] == "40x50" and len(result["setups"]) == 2
    assert result["simulations_run"] == result["simulations"]  # a fresh run: every simulation was run now
    assert result["engine"] == engine_name() and result["engine"] in ENGINES  # its figures depend on the engine
    curve = _png(out / "flow_curve.png")
    assert curve.shape[0] > 100 and curve.shape[1] > 100 and curve.std() > 0  # a drawn figure, not a blank
    assert len(list((out / "overlays").glob("*.png"))) == 8 * len(result["setups"])
    assert "E_rel" in proc.stdout


@pytest.mark.parametrize("argv, needle", [
    (["demo", "--material", "1,0.5"], "three numbers"),
    (["demo", "--material", "100,0.5,1"], "outside the material space"),
    (["demo", "--setup", "10x50"], "outside the setup space"),
    (["demo", "--generations", "0"], "must be >= 1"),
])
def test_demo_bad_input_is_one_line(argv, needle, tmp_path, capsys):
    assert main(argv + ["--out", str(tmp_path / "d")]) == 2
    err = capsys.readouterr().err.strip()
    assert needle in err and len(err.splitlines()) == 1


def test_estimate_refuses_malformed_folder_before_any_work(tmp_path, capsys, shared_data):
    good = shared_data / "real_world" / "ref_Lotion_2.5_5.1_1"
    bad = tmp_path / "ref_Broken_2.0_2.0_1"
    shutil.copytree(good, bad)
    (bad / "config_05.png").unlink()
    out = tmp_path / "out"
    assert main(["estimate", str(good), str(bad), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "config_05" in err, err
    assert not out.exists()  # nothing was started
    assert main(["estimate", str(tmp_path / "missing"), "--out", str(out)]) == 2
    assert "not found" in capsys.readouterr().err
    assert main(["estimate", str(good), "--out", str(out), "--generations", "0"]) == 2
    assert not out.exists()


@pytest.mark.slow
def test_demo_real_solver_one_generation(tmp_path):
    """The real `virheo demo` pipeline (MPM, camera, silhouettes, design) with one generation per stage."""
    out = tmp_path / "demo"
    env = dict(os.environ, VIRHEO_THREADS="1")
    proc = subprocess.run([sys.executable, "-m", "studies.cli", "demo", "--out", str(out), "--generations", "1",
                           "--workers", "1", "--quiet"], env=env, capture_output=True, text=True, timeout=600,
                          cwd=str(TESTS.parent))
    assert proc.returncode == 0, proc.stderr[-2000:]
    result = json.loads((out / "result.json").read_text())
    # 7 + 14 CMA-ES simulations plus the re-scoring of up to 7 stage-1 candidates on setup 2
    assert 7 + 14 < result["simulations"] <= 7 + 14 + 7 and len(result["setups"]) == 2
    for e in result["experiments"]:  # the estimate's own simulation, re-read from the store, has the reported loss
        assert 0 < e["loss"] < 0.2 and len(e["frame_losses"]) == 8
    assert result["loss"] == pytest.approx(np.mean([e["loss"] for e in result["experiments"]]))
