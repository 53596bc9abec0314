"""Simulation store: stable keys, round trip of packed silhouettes, failures, losses, checkpoints."""
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from mpm.model import MODEL_FIELDS, ForwardModel
from mpm.store import SimRequest, SimResult, Store, pack, unpack


def _req(**kw):
    """A request; the model's fields among ``kw`` go into its model."""
    base = dict(eta=1.5, n=0.7, sigma_y=10.0, width_mm=30.0, height_mm=40.0, density=1025.0,
                camera='{"fov_deg":36.0}', cell_mm=5.0, simulator="fake_forward:simulate", code_version="v1")
    base.update(kw)
    model = ForwardModel(**{k: base.pop(k) for k in MODEL_FIELDS if k in base})
    return SimRequest(**base, model=model)


def test_key_is_stable_and_sensitive_to_every_field():
    r = _req()
    assert r.key == _req().key
    assert SimRequest.from_dict(r.to_dict()).key == r.key
    for change in (dict(eta=1.5000001), dict(n=0.71), dict(sigma_y=10.5), dict(width_mm=31.0), dict(height_mm=41.0),
                   dict(density=1000.0), dict(depth_mm=41.5), dict(camera='{"fov_deg":36.1}'), dict(cell_mm=2.5),
                   dict(ppc=2),
                   dict(dim=2), dict(flow_rule="yue2015"), dict(precision="f64"), dict(image_size=(480, 270)),
                   dict(simulator="x:y"), dict(code_version="v2"), dict(engine="native")):
        assert _req(**change).key != r.key, change
    assert _req(engine="native").key != _req(engine="taichi-cpu").key


def test_a_request_stored_before_engines_loads_keeps_its_key_and_matches_no_new_request(tmp_path):
    """A request written before requests named their engine (no "engine" field) reads back with engine None, under
    the key it was stored with (so that an index rebuilt from the array files finds it); a request naming any
    engine differs from it, so no engine is served another's, or an unknown engine's, results."""
    from mpm.files import digest

    old = {k: v for k, v in _req().to_dict().items() if k != "engine"}
    loaded = SimRequest.from_dict(old)
    assert loaded.model.engine is None and loaded.key == digest(old)
    store = Store(tmp_path)
    store.put(loaded, SimResult(None, np.zeros(8), np.arange(1, 9) / 24, {"steps": 1}))
    for engine in ("native", "taichi-cpu", "cuda"):
        assert store.get(_req(engine=engine)) is None
    store.close()
    (tmp_path / "index.sqlite").unlink()  # the index rebuilt from the array file finds the old request again
    with pytest.warns(UserWarning, match="rebuilt from 1 intact"):
        rebuilt = Store(tmp_path)
    assert rebuilt.get(loaded).stats == {"steps": 1} and rebuilt.requests() == [loaded]


def test_pack_round_trip():
    rng = np.random.default_rng(0)
    s = rng.random((8, 54, 97)) > 0.6  # width not a multiple of 8
    assert np.array_equal(unpack(*pack(s)), s)


def test_saved_arrays_read_back_as_npz_and_compress_sparse_silhouettes(tmp_path):
    from mpm.files import save_arrays

    sil = np.zeros((8, 90, 160), bool)
    sil[:, 60:, 20:70] = True
    packed, shape = pack(sil)
    arrays = dict(silhouettes=packed, shape=np.asarray(shape), stats=np.asarray('{"cpu_s":1.5}'))
    path = tmp_path / "a.npz"
    with open(path, "wb") as fh:
        save_arrays(fh, **arrays)
    with np.load(path) as z:
        assert sorted(z.files) == sorted(arrays)
        assert all(np.array_equal(z[k], v) for k, v in arrays.items())
        assert np.array_equal(unpack(z["silhouettes"], z["shape"]), sil)
    assert path.stat().st_size < packed.nbytes / 5


def test_put_get_hit_and_failure(tmp_path):
    store = Store(tmp_path)
    rng = np.random.default_rng(1)
    sil = rng.random((8, 540, 960)) > 0.97
    r = _req()
    assert store.get(r) is None
    store.put(r, SimResult(sil, np.linspace(0.03, 0.05, 8), np.arange(1, 9) / 24, {"steps": 667}, wall_seconds=1.5))
    hit = Store(tmp_path).get(r)  # a fresh connection sees it
    assert hit.ok and np.array_equal(hit.silhouettes, sil) and hit.stats == {"steps": 667}
    assert np.allclose(hit.front_m, np.linspace(0.03, 0.05, 8)) and hit.wall_seconds == 1.5
    # compressed on disk: far below the 4.1 MB of the raw bool array
    files = list((tmp_path / "sims").rglob("*.npz"))
    assert len(files) == 1 and files[0].stat().st_size < 300_000
    bad = _req(eta=29.0)
    store.put(bad, SimResult(None, error="SimulationError: blow-up"))
    got = store.get(bad)
    assert not got.ok and "blow-up" in got.error
    assert store.count() == 2 and store.count("failed") == 1
    assert store.timings() == [(r, 1.5)]  # the successful simulation's wall time only
    store.put_loss(r, "exp1", 0.0123)
    store.put_loss(bad, "exp1", float("nan"))
    assert store.get_loss(r, "exp1") == pytest.approx(0.0123)
    assert np.isnan(store.get_loss(bad, "exp1"))
    assert store.get_loss(r, "exp2") is None


def test_checkpoint_atomic_replace(tmp_path):
    store = Store(tmp_path)
    assert store.load_checkpoint("run") is None
    store.save_checkpoint("run", {"generation": 1})
    store.save_checkpoint("run", {"generation": 2})
    assert store.load_checkpoint("run") == {"generation": 2}
    assert not list((tmp_path / "checkpoints").glob("*.tmp"))


def test_kill_during_writes_leaves_a_consistent_store(tmp_path):
    """SIGKILL a process that writes results in a loop: every indexed row is readable afterwards."""
    script = textwrap.dedent(f"""
        import sys, numpy as np
        sys.path.insert(0, {os.getcwd()!r})
        from mpm.store import SimRequest, SimResult, Store
        s = Store({str(tmp_path)!r})
        rng = np.random.default_rng(0)
        i = 0
        while True:
            r = SimRequest(eta=1.0 + i, n=0.5, sigma_y=1.0, width_mm=30, height_mm=30, density=1000.0)
            s.put(r, SimResult(rng.random((8, 540, 960)) > 0.9, np.zeros(8), np.zeros(8), {{"i": i}}))
            s.save_checkpoint("run", {{"i": i, "pad": bytes(200000)}})
            i += 1
            print(i, flush=True)
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    for _ in range(4):
        proc.stdout.readline()
    proc.kill()
    proc.wait()
    store = Store(tmp_path)
    reqs = store.requests()
    assert len(reqs) >= 4
    for r in reqs:
        assert store.get(r) is not None and store.get(r).silhouettes.shape == (8, 540, 960)
    ck = store.load_checkpoint("run")
    assert ck["i"] >= 3
