"""Emulation study (section 7.1) on the fake forward model: equal simulation counts, reports."""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from similarity.space import normalize
from studies.emulation import poisson_materials

TESTS = Path(__file__).resolve().parent


def test_poisson_materials_are_spread_and_in_space():
    mats = poisson_materials(6, seed=0)
    x = np.array([normalize(m.as_array()) for m in mats])
    assert len(mats) == 6 and all(m.in_space() for m in mats)
    d = np.linalg.norm(x[:, None] - x[None], axis=-1)[np.triu_indices(6, 1)]
    assert d.min() > 0.1  # Poisson-disk: no two materials close together
    assert [m.to_dict() for m in poisson_materials(6, seed=0)] == [m.to_dict() for m in mats]


def test_a_smaller_study_is_the_first_cases_of_a_larger_one():
    # Fig. 10's full panels (1 material x 3 runs) are the first three cases of the 6 x 3 study (run_study draws
    # each material's first setups in turn from one generator), so the two share their simulations in a store.
    for seed in (0, 1, 7):
        assert poisson_materials(1, seed=seed)[0].to_dict() == poisson_materials(6, seed=seed)[0].to_dict()


def _study(out, log):
    env = dict(os.environ, PYTHONPATH=f"{TESTS}{os.pathsep}{TESTS.parent}", VIRHEO_SIMULATOR="fake_forward:simulate",
               FAKE_FORWARD_LOG=str(log))
    return subprocess.run([sys.executable, "-m", "studies.cli", "study", "emulation", "--materials", "2", "--runs", "1",
                           "--generations", "3", "--workers", "0", "--quiet", "--out", str(out)], env=env,
                          capture_output=True, text=True, timeout=300)


def test_study_cli_one_vs_two_setups_at_equal_cost(tmp_path):
    out, log = tmp_path / "emu", tmp_path / "sims.log"
    proc = _study(out, log)
    assert proc.returncode == 0, proc.stderr[-2000:]
    result = json.loads((out / "emulation.json").read_text())
    assert result["summary"]["cases"] == 2
    for case in result["cases"]:
        assert case["single"]["simulations"] == (3 * 3 + 1) * 7  # 3G + 1 generations: the re-scoring costs one
        assert len(case["setups"]) == 2 and case["setups"][0] == case["first_setup"]
        assert case["two_setups"]["simulations"] == case["single"]["simulations"]
        sims = [s for s, _ in case["curves"]["single"]]
        assert sims == sorted(sims) and sims[-1] == case["single"]["simulations"]
    from PIL import Image

    with Image.open(out / "errors_vs_simulations.png") as im:
        plot = np.asarray(im.convert("L"))
    assert plot.shape[0] > 100 and plot.std() > 0  # a drawn figure, not a blank
    assert result["settings"]["preset"] == "demo"
    # killed after the simulations of case 2 but before its record: re-run, nothing is simulated again
    simulated = log.read_text().splitlines()
    assert len(simulated) == len(set(simulated)) > 0
    (out / "cases" / "case_01_00" / "case.json").unlink()
    proc = _study(out, log)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert log.read_text().splitlines() == simulated
    again = json.loads((out / "emulation.json").read_text())
    assert again["cases"] == result["cases"] and again["summary"] == result["summary"]
    assert "Good (E_rel <= 0.1)" in (out / "emulation.md").read_text()
