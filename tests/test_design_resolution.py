"""virheo study design-resolution on the fake forward model: the gains follow from the stored stencil losses, a model
compared with itself matches, runs with other models add to one folder, and a finished run resumes without
simulating."""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from similarity import information as I
from studies import design_resolution as R

TESTS = Path(__file__).resolve().parent
ENV = dict(os.environ, PYTHONPATH=f"{TESTS}{os.pathsep}{TESTS.parent}", VIRHEO_SIMULATOR="fake_forward:simulate")


def _study(out, log, *models, materials="1"):
    argv = [sys.executable, "-m", "studies.cli", "study", "design-resolution", "--models", *models, "--materials",
            materials, "--workers", "0", "--quiet", "--out", str(out)]
    proc = subprocess.run(argv, env=dict(ENV, FAKE_FORWARD_LOG=str(log)), capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc.stdout


def test_gains_follow_from_the_stencils_and_runs_add_to_one_folder(tmp_path):
    out, log = tmp_path / "dr", tmp_path / "sims.log"
    _study(out, log, "5:1")
    first = log.read_text().splitlines()
    probe = R.MATERIALS[0]
    assert len(first) == len(set(first)) == 19 * len(R.setups_of(probe))  # footage + 18 stencil points per setup
    stdout = _study(out, log, "4:1")
    res = json.loads((out / "design_resolution.json").read_text())
    recs = [R.SetupRecord.from_dict(c) for c in res["cases"]]
    assert {r.model for r in recs} == {"5mm-1p", "4mm-1p"}
    for label in ("5mm-1p", "4mm-1p"):
        mine = {r.setup: r for r in recs if r.model == label}
        assert set(mine) == {str(s) for s in R.setups_of(probe)}
        h = [I.setup_hessian(np.array(mine[str(s)].stencil_losses, float), I.STEP) for s in R.setups_of(probe)]
        np.testing.assert_allclose(mine[str(probe.first)].hessian, h[0], rtol=1e-12)
        gains = I.log_det_gain(h[0], np.array(h[1:]))
        scores = R.ModelScores.from_dict(res["summary"]["materials"][probe.slug][label])
        np.testing.assert_allclose(scores.gains, gains, rtol=1e-9)
        assert scores.argmax == scores.setups[int(np.argmax(gains))]
        assert scores.trace_ratio == pytest.approx(np.trace(h[4]) / np.trace(h[1]))  # 70x70 over 20x20
    s = res["summary"]
    assert s["finest"] == "4mm-1p" and s["compared_materials"] == [probe.slug]
    coarse = s["materials"][probe.slug]["5mm-1p"]
    # the fake forward model does not depend on the discretisation: the coarse model ranks as the fine one
    assert coarse["spearman_vs_finest"] == pytest.approx(1.0) and coarse["argmax_as_finest"] is True
    assert s["matching"] == ["5mm-1p"] and s["cheapest_matching"] == "5mm-1p"
    assert "cheapest model matching 4mm-1p: 5mm-1p" in stdout
    before = log.read_text().splitlines()
    _study(out, log, "5:1", "4:1")  # finished: read back, nothing simulated again
    assert log.read_text().splitlines() == before


def test_a_malformed_model_is_one_line_and_exit_2(tmp_path):
    argv = [sys.executable, "-m", "studies.cli", "study", "design-resolution", "--models", "2.5", "--out",
            str(tmp_path / "x")]
    proc = subprocess.run(argv, env=ENV, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "CELL_MM:PPC" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "x").exists()


def test_cases_run_model_by_model_from_the_smallest_box_and_cover_every_setup(tmp_path):
    models = [R.ForwardModel(5.0, 1), R.ForwardModel(2.5, 2)]
    planned = list(R.DesignResolution(tmp_path, {}, models=models, materials=2).cases())
    expected = {(p.slug, R.model_label(m), str(s)) for m in models for p in R.MATERIALS[:2] for s in R.setups_of(p)}
    keys = [(c.probe.slug, R.model_label(c.model), str(c.setup)) for c in planned]
    assert len(keys) == len(expected) and set(keys) == expected
    labels = [R.model_label(c.model) for c in planned]
    assert labels == sorted(labels, key=[R.model_label(m) for m in models].index)  # one model after the other
    for m in models:
        areas = [c.setup.width_mm * c.setup.height_mm for c in planned if c.model == m]
        assert areas == sorted(areas)


def _records(slug, label, cell, setups, scale=1.0, engine="native", first_scale=1.0):
    """Synthetic cases: each setup's Hessian grows with its box (setup 1's times ``first_scale``)."""
    probe = R._probe(slug)
    out = []
    for s in setups:
        area = s.width_mm * s.height_mm / 400.0
        h = np.diag([area, 0.5 * area, 0.2 * area]) * scale * (first_scale if str(s) == str(probe.first) else 1.0)
        out.append(R.SetupRecord({}, slug, probe.material, label, cell, 1, engine, str(s), [0.0] * 18, h.tolist(), 1.0,
                                 19, 1.0))
    return out


def test_a_partial_finest_model_gives_no_verdict_and_no_coarser_one_stands_in():
    """While the finest model lacks candidates for a material that has it, the summary names that material as
    pending and gives no cheapest matching model, although coarser models are complete; with every candidate it
    gives the verdict.  A model whose cases came from two engines is left out; a setup 1 without information at a
    model scores the candidates on their own instead of stopping the summary."""
    study = R.DesignResolution("unused", {})
    a, b = R.MATERIALS[0].slug, R.MATERIALS[1].slug
    full = {slug: R.setups_of(R._probe(slug)) for slug in (a, b)}
    coarse = [r for slug in (a, b) for r in _records(slug, "5mm-1p", 5.0, full[slug])]
    partial = _records(a, "1.26mm-1p", 1.26, full[a]) + _records(b, "1.26mm-1p", 1.26, full[b][:4])
    s = study.summary(coarse + partial)
    assert s.finest == "1.26mm-1p" and s.compared_materials == [a, b] and s.pending == [b]
    assert s.cheapest_matching is None and s.matching == []
    assert s.materials[a]["5mm-1p"].spearman_vs_finest == pytest.approx(1.0)
    done = coarse + _records(a, "1.26mm-1p", 1.26, full[a]) + _records(b, "1.26mm-1p", 1.26, full[b])
    s = study.summary(done)
    assert s.pending == [] and s.cheapest_matching == "5mm-1p"
    mixed = done + _records(a, "2.5mm-1p", 2.5, full[a][:3]) + _records(a, "2.5mm-1p", 2.5, full[a][3:], engine="cuda")
    s = study.summary(mixed)
    assert s.mixed_engines == ["2.5mm-1p"] and "2.5mm-1p" not in s.matching and s.cheapest_matching == "5mm-1p"
    stiff = [r for slug in (a, b) for r in _records(slug, "5mm-1p", 5.0, full[slug], first_scale=0.0)]
    s = study.summary(stiff)
    assert all(np.isfinite(g) for g in s.materials[a]["5mm-1p"].gains) and s.materials[a]["5mm-1p"].argmax == "70x70"
