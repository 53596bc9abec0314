"""Landscape studies: FD Hessian, Poisson-disk sampling, resuming a killed study, bad input."""
import json

import numpy as np
import pytest

import fake_forward
from mpm import batch
from mpm.forward import Forward
from mpm.store import Store
from similarity.fd_hessian import angle_deg, fd_hessian, hessian_from_stencil, spectrum, stencil
from studies import landscapes as LS
from studies.cli import main

SIM = "fake_forward:simulate"


def test_fd_hessian_recovers_a_known_quadratic():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(3, 3))
    h_true = a @ a.T + np.diag([0.5, 2.0, 7.0])
    g = rng.normal(size=3)
    x0 = np.array([0.3, 0.6, 0.2])

    def quadratic(x):  # 1.3 + g.dx + 1/2 dx^T H dx: central differences are exact
        d = np.atleast_2d(x) - x0
        return 1.3 + d @ g + 0.5 * np.einsum("ki,ij,kj->k", d, h_true, d)

    for step in (0.01, 0.05, 0.1):
        np.testing.assert_allclose(fd_hessian(quadratic, x0, step), h_true, rtol=1e-7, atol=1e-7)


def test_spectrum_gives_top_normal_and_condition():
    q = np.array([1.0, 2.0, 2.0]) / 3.0
    basis = np.linalg.qr(np.column_stack([q, [1, 0, 0], [0, 1, 0]]))[0]
    h = basis @ np.diag([50.0, 2.0, 0.5]) @ basis.T
    s = spectrum(h)
    assert angle_deg(s.q_max, q) < 1e-6
    assert s.condition == pytest.approx(100.0)
    np.testing.assert_allclose(s.eigenvalues, [0.5, 2.0, 50.0])
    # a stencil of a pure |q . dx| cone (the silhouette loss grows ~ linearly) still points along q
    offsets = stencil(0.05)
    cone = np.abs(offsets @ q) + 0.01 * np.linalg.norm(offsets, axis=1)
    assert angle_deg(spectrum(hessian_from_stencil(cone, 0.05)).q_max, q) < 10


def test_stencil_is_the_block_without_corners():
    s = stencil(0.1)
    assert s.shape == (18, 3)
    assert len({tuple(np.round(r, 12)) for r in s}) == 18
    assert set(np.round(np.abs(s).sum(axis=1), 12)) == {0.1, 0.2}  # 6 faces, 12 edges, no corners


@pytest.mark.parametrize("count,seed,margin", [(10, 0, 0.07), (20, 3, 0.0), (40, 1, 0.1)])
def test_poisson_disk_respects_the_minimum_distance(count, seed, margin):
    pts, r = LS.poisson_disk(count, seed=seed, margin=margin)
    assert pts.shape == (count, 3)
    assert np.all(pts >= margin - 1e-12) and np.all(pts <= 1 - margin + 1e-12)
    d = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
    assert np.min(d[np.triu_indices(count, 1)]) >= r * (1 - 1e-9)


def test_grid_offsets():
    g = LS.grid_offsets(3, 0.05)
    assert g.shape == (27, 3)
    assert np.allclose(g[13], 0) and np.isclose(np.abs(g).max(), 0.05)
    with pytest.raises(ValueError):
        LS.grid_offsets(1, 0.05)


def test_killed_study_resumes_without_recomputing(tmp_path, monkeypatch):
    config = LS.StudyConfig(materials=1, setups_per_material=2, grid=2, half_width=0.05, fd_step=0.05)
    store = Store(tmp_path / "store")
    done: list[str] = []
    real = fake_forward.simulate

    def dying(req):
        if len(done) == 20:
            raise KeyboardInterrupt  # a kill half-way through the probes
        done.append(req.key)
        return real(req)

    monkeypatch.setattr(fake_forward, "simulate", dying)
    with pytest.raises(KeyboardInterrupt):
        LS.run(tmp_path / "study", config, forward=Forward(store, simulator=SIM), plots=0)
    assert not (tmp_path / "study" / LS.RESULT_FILE).exists()
    first = list(done)
    done.clear()
    monkeypatch.setattr(fake_forward, "simulate", lambda req: (done.append(req.key), real(req))[1])
    res = LS.run(tmp_path / "study", config, forward=Forward(store, simulator=SIM), plots=1)
    assert not set(first) & set(done)  # nothing finished before the kill ran again
    assert len(first) + len(done) == res["simulations"] == 2 * (8 + 18 + 1)
    again = LS.run(tmp_path / "study", config, forward=Forward(store, simulator=SIM), plots=0)
    assert len(first) + len(done) == again["simulations"]  # third run: everything from the store
    # pair by pair on the Study skeleton: one case.json per pair, the table beside the JSON
    assert sorted(p.parent.name for p in (tmp_path / "study").glob("cases/*/case.json")) == ["pair_000", "pair_001"]
    assert res["summary"]["pairs"] == 2 and "| pair |" in (tmp_path / "study" / "landscapes.md").read_text()
    assert (tmp_path / "study" / "landscape_00.png").stat().st_size > 1000
    rec = res["pairs"][0]
    assert len(rec["losses"]) == 8 and len(rec["q_max"]) == 3 and rec["match"]["C_Pa"] > 0
    # a different configuration in the same folder is refused
    with pytest.raises(ValueError, match="another configuration"):
        LS.run(tmp_path / "study", LS.StudyConfig(materials=2, grid=2), forward=Forward(store, simulator=SIM))


def _one_line_exit_2(capsys, argv):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err
    return err


def test_bad_input_exits_2(tmp_path, capsys):
    err = _one_line_exit_2(capsys, ["study", "landscapes", "--grid", "1", "--out", str(tmp_path / "x"), "--quiet"])
    assert "grid" in err
    err = _one_line_exit_2(capsys, ["study", "conditioning", "--material", "1,0.5,2", "--steps", "1",
                                    "--out", str(tmp_path / "c"), "--quiet"])
    assert "steps" in err
    err = _one_line_exit_2(capsys, ["study", "conditioning", "--material", "3.14,0.74,1.24", "--workers", "0",
                                    "--out", str(tmp_path / "c"), "--quiet"])  # sigma_y within the FD step of 0
    assert "boundary" in err
    (tmp_path / "notastudy").mkdir()
    err = _one_line_exit_2(capsys, ["theta", "fit", str(tmp_path / "notastudy"), "--out", str(tmp_path / "t.json")])
    assert "not a finished landscape study" in err
    (tmp_path / "notastudy" / LS.RESULT_FILE).write_text(json.dumps({"format": "something else"}))
    err = _one_line_exit_2(capsys, ["theta", "fit", str(tmp_path / "notastudy"), "--out", str(tmp_path / "t.json")])
    assert "not a landscape study" in err


def test_conditioning_holds_one_footage_at_a_time_and_resumes_per_setup(tmp_path, monkeypatch):
    # the paper's 51 x 51 setup grid is 2601 footages of ~4 MB: the study emulates one setup per case, keeps each
    # finished setup, and its condition numbers are those of the stored stencil losses
    from similarity import emulation
    from similarity.fd_hessian import hessian_from_stencil, spectrum
    from mpm.params import Material
    from studies import conditioning as C

    sizes, emulate = [], emulation.emulate

    def counting(material, setups, **kw):
        sizes.append(len(setups))
        return emulate(material, setups, **kw)

    monkeypatch.setattr(emulation, "emulate", counting)
    m, store = Material(3.14, 0.74, 6.0), Store(tmp_path / "store")
    res = C.conditioning(tmp_path / "c", m, steps=4, forward=Forward(store, simulator=SIM))
    assert sizes == [1] * 16 and res["simulations"] == 16 * 19 and np.all(np.isfinite(res["condition"]))
    for case, cond in zip(res["cases"], np.ravel(res["condition"])):
        assert cond == spectrum(hessian_from_stencil(np.array(case["stencil_losses"]), 0.05)).condition
    assert res["setups"][1] == "37x20"  # rows = height, columns = width
    sizes.clear()
    for k in (3, 7):  # a run killed before these setups finished: only they run again
        (tmp_path / "c" / "cases" / res["setups"][k] / "case.json").unlink()
    again = C.conditioning(tmp_path / "c", m, steps=4, forward=Forward(store, simulator=SIM))
    assert sizes == [1, 1] and again["condition"] == res["condition"]
    assert json.loads((tmp_path / "c" / "conditioning.json").read_text())["condition"] == res["condition"]
    assert (tmp_path / "c" / "conditioning.png").stat().st_size > 5000

