"""A damaged store heals: damaged index, truncated array, truncated checkpoint -> the same estimate."""
import os
import sqlite3

import pytest

from mpm.files import atomic_write
from mpm.forward import Forward
from mpm.params import Material, Setup
from mpm.store import Store, StoreWarning
from similarity import estimate as E

SIM = "fake_forward:simulate"
SIZE = (96, 54)
GENS = 5


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """Footage of a known material and an undamaged estimate of it."""
    root = tmp_path_factory.mktemp("heal")
    exps = E.emulate(Material(3.0, 0.6, 12.0), [Setup(30, 50)], forward=Forward(root / "truth", simulator=SIM),
                     image_size=SIZE)
    est = _estimate(exps, Store(root / "ref"))
    return exps, est


def _estimate(exps, store):
    return E.estimate(exps, preset="demo", seed=5, forward=Forward(store, simulator=SIM), generations=GENS,
                      propose=None)


def _fresh_store(tmp_path, exps, log, monkeypatch):
    store = Store(tmp_path / "store")
    est = _estimate(exps, store)
    store.close()
    monkeypatch.setenv("FAKE_FORWARD_LOG", str(log))
    return tmp_path / "store", est


def _simulated(log):
    return len(log.read_text().split()) if log.exists() else 0


def _drop_checkpoints(root):
    for p in (root / "checkpoints").glob("*.pkl"):
        p.unlink()


def test_damaged_index_is_moved_aside_and_rebuilt(tmp_path, reference, monkeypatch):
    exps, ref = reference
    log = tmp_path / "log.txt"
    root, _ = _fresh_store(tmp_path, exps, log, monkeypatch)
    n_before = Store(root).count()
    index = root / "index.sqlite"
    index.write_bytes(index.read_bytes()[:3000])  # a copy interrupted after 3 kB
    _drop_checkpoints(root)  # the optimiser must really re-run on the rebuilt index
    with pytest.warns(StoreWarning, match="damaged") as caught:
        store = Store(root)
    assert len(caught) == 1 and "rebuilt from" in str(caught[0].message)
    assert store.count() == n_before
    assert len([p for p in root.glob("index.sqlite.damaged-*") if p.name[-1].isdigit()]) == 1
    est = _estimate(exps, store)
    assert est.material == ref.material and est.loss == ref.loss
    assert _simulated(log) == 0  # every simulation came from the arrays on disk


def test_garbage_index_is_healed(tmp_path, reference, monkeypatch):
    exps, ref = reference
    log = tmp_path / "log.txt"
    root, _ = _fresh_store(tmp_path, exps, log, monkeypatch)
    n_before = Store(root).count()
    (root / "index.sqlite").write_bytes(b"this is not a database" * 100)
    with pytest.warns(StoreWarning, match="not a database"):
        store = Store(root)
    assert store.count() == n_before
    assert _estimate(exps, store).material == ref.material and _simulated(log) == 0


def test_truncated_array_is_simulated_again(tmp_path, reference, monkeypatch):
    exps, ref = reference
    log = tmp_path / "log.txt"
    root, _ = _fresh_store(tmp_path, exps, log, monkeypatch)
    victim = sorted((root / "sims").glob("*/*.npz"))[3]
    victim.write_bytes(victim.read_bytes()[: victim.stat().st_size // 2])
    _drop_checkpoints(root)
    store = Store(root)
    with sqlite3.connect(root / "index.sqlite") as db:  # cached losses would hide the array: drop them
        db.execute("DELETE FROM losses")
    with pytest.warns(StoreWarning, match=f"{victim.name} is unreadable") as caught:
        est = _estimate(exps, store)
    assert len([w for w in caught if issubclass(w.category, StoreWarning)]) == 1  # warned once
    assert est.material == ref.material and est.loss == ref.loss
    assert log.read_text().split() == [victim.stem]  # exactly the damaged one was simulated again


def test_truncated_checkpoint_falls_back(tmp_path, reference, monkeypatch):
    exps, ref = reference
    log = tmp_path / "log.txt"
    root, _ = _fresh_store(tmp_path, exps, log, monkeypatch)
    (ckpt,) = [p for p in (root / "checkpoints").glob("*.pkl") if not p.name.endswith(".prev.pkl")]
    ckpt.write_bytes(ckpt.read_bytes()[:100])
    with pytest.warns(StoreWarning, match="checkpoint .* is unreadable"):
        est = _estimate(exps, Store(root))  # resumes from the previous checkpoint
    assert est.material == ref.material and est.loss == ref.loss and _simulated(log) == 0
    for p in (root / "checkpoints").glob("*.pkl"):  # both damaged: start again, served from the store
        p.write_bytes(b"\x80\x05garbage")
    with pytest.warns(StoreWarning):
        est = _estimate(exps, Store(root))
    assert est.material == ref.material and est.loss == ref.loss and _simulated(log) == 0


def test_store_path_that_is_a_file(tmp_path):
    f = tmp_path / "store"
    f.write_text("x")
    with pytest.raises(NotADirectoryError, match="is a file, not a folder"):
        Store(f)


def test_atomic_write_keeps_the_old_file_and_uses_the_normal_mode(tmp_path):
    path = tmp_path / "a.json"
    atomic_write(path, lambda fh: fh.write("old"), mode="t")
    umask = os.umask(0o022)
    os.umask(umask)
    assert (path.stat().st_mode & 0o777) == 0o666 & ~umask

    def broken(fh):
        fh.write("half")
        raise OSError(28, "No space left on device")

    with pytest.raises(OSError):
        atomic_write(path, broken, mode="t")
    assert path.read_text() == "old" and [p.name for p in tmp_path.iterdir()] == ["a.json"]
