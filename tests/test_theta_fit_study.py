"""Fitting Theta to landscape studies: materials drawn from a region, several studies fitted together."""
import json

import numpy as np
import pytest

from mpm.params import Material
from similarity.space import denormalize, normalize
from studies import landscapes as LS
from studies.cli import main
from studies.report import write_json


def test_region_draws_poisson_disk_materials_inside_the_box():
    config = LS.StudyConfig(materials=9, setups_per_material=1, seed=7, region=((0, 8), (0.3, 1), (0, 16))).check()
    lo, hi = config.region_box()
    pts, r = LS.poisson_disk(9, seed=7, box=(lo, hi))
    assert np.all(pts >= lo - 1e-12) and np.all(pts <= hi + 1e-12)
    d = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
    assert np.min(d[np.triu_indices(9, 1)]) >= r * (1 - 1e-9)
    m = np.array([p.material.as_array() for p in LS.sample_pairs(config)])
    assert np.all(m[:, 0] <= 8) and np.all(m[:, 2] <= 16)
    # every probe of the landscape block stays inside the material space
    assert np.all(normalize(m) - config.margin >= -1e-12)
    assert "region" in config.to_dict() and "region" not in LS.StudyConfig().to_dict()


def test_bad_region_exits_2(tmp_path, capsys):
    for region, word in (("0:8,0.3:1", "three ranges"), ("8:0,0.3:1,0:4", "lo < hi"), ("0:1,0.3:1,0:1", "no room")):
        try:  # argparse refuses a malformed option by SystemExit(2), the library by returning 2
            status = main(["study", "landscapes", "--region", region, "--out", str(tmp_path / "x"), "--quiet"])
        except SystemExit as exc:
            status = exc.code
        assert status == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and word in err


def _synthetic_study(folder, materials, seed, grid=3):
    """A finished study whose landscapes are cones around the plane-Poiseuille normal at a known
    wall stress C(M, S) = 20 Pa + 1.5 sigma_y + 600 Pa/m * H, with that normal as the FD normal."""
    rng = np.random.default_rng(seed)
    block = LS.grid_offsets(grid, 0.05)
    pairs = []
    for u in rng.uniform(0.1, 0.9, (materials, 3)):
        m = Material.from_array(denormalize(u))
        w, h = rng.integers(20, 71, 2)
        c = 20.0 + 1.5 * m.sigma_y + 600.0 * h * 1e-3
        q = LS.poiseuille_normals(m, [c])[0]
        pairs.append({"material": m.to_dict(), "setup": {"width_mm": float(w), "height_mm": float(h)},
                      "losses": (np.abs(block @ q) + 0.1 * np.linalg.norm(block, axis=1)).tolist(),
                      "q_max": q.tolist(), "match": {"C_Pa": 0.0}, "C_true": c})
    config = {"materials": materials, "setups_per_material": 1, "grid": grid, "half_width": 0.05, "fd_step": 0.05,
              "preset": "demo", "seed": seed, "density": 1000.0}
    folder.mkdir()
    write_json(folder / LS.RESULT_FILE, {"format": LS.FORMAT, "config": config, "pairs": pairs})
    return pairs


def test_fit_on_two_studies_recovers_a_known_map(tmp_path, capsys):
    a = _synthetic_study(tmp_path / "a", 12, seed=1)
    b = _synthetic_study(tmp_path / "b", 12, seed=2)
    out = tmp_path / "theta.json"
    assert main(["theta", "fit", str(tmp_path / "a"), str(tmp_path / "b"), "--out", str(out), "--compare", "0"]) == 0
    assert "of 17 materials" in capsys.readouterr().out  # 24 materials, 30 % held out
    report = json.loads(out.with_name("theta_report.json").read_text())
    assert len(report["test"]) == 7 and report["fit"]["cv"] == "leave one material out"
    truth = {json.dumps(p["material"], sort_keys=True): p["C_true"] for p in a + b}
    matched = np.array([r["C_matched_Pa"] / truth[json.dumps(r["material"], sort_keys=True)]
                        for r in report["landscapes"]])
    assert np.median(np.abs(matched - 1)) < 0.1  # eq. 43 on the refined block finds the cone's C
    test = report["median_angle_test"]
    assert test["fitted"] < 3.0 and test["invalid_fitted"] == 0  # unseen materials: normals within degrees
    # studies with different landscape blocks are not mixed
    _synthetic_study(tmp_path / "c", 4, seed=3, grid=2)
    assert main(["theta", "fit", str(tmp_path / "a"), str(tmp_path / "c"), "--out", str(out)]) == 2
    assert "differ in grid" in capsys.readouterr().err
