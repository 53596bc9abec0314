"""Batch evaluation: store lookups first, local processes, dask LocalCluster, failures -> NaN."""
import numpy as np
import pytest

from mpm import batch
from mpm.params import Material, Setup
from mpm.store import Store

SIM = "fake_forward:simulate"


def _requests(simulator=SIM, n=6):
    mats = [Material(0.5 + 2 * i, 0.4 + 0.1 * i, 3.0 * i) for i in range(n)]
    return [batch.request_for(m, Setup(30, 40), density=1000.0, image_size=(96, 54), simulator=simulator) for m in mats]


def test_store_hit_is_not_simulated_again(tmp_path, monkeypatch):
    log = tmp_path / "log.txt"
    monkeypatch.setenv("FAKE_FORWARD_LOG", str(log))
    store = Store(tmp_path / "store")
    reqs = _requests()
    first = batch.evaluate(reqs + reqs[:2], store=store, executor=batch.InlineExecutor())
    assert len(log.read_text().split()) == len(reqs)  # duplicates simulated once
    again = batch.evaluate(reqs, store=store, executor=batch.InlineExecutor())
    assert len(log.read_text().split()) == len(reqs)  # all served from the store
    for a, b in zip(first, again):
        assert np.array_equal(a.silhouettes, b.silhouettes)


def test_failures_give_nan_losses_and_are_remembered(tmp_path):
    store = Store(tmp_path)
    reqs = _requests("fake_forward:simulate_flaky", n=12)
    ref = batch.run_one(_requests(n=1)[0]).silhouettes
    jobs = [(r, "exp", ref) for r in reqs]
    losses = batch.evaluate_losses(jobs, store=store, executor=batch.InlineExecutor())
    failed = np.array([int(r.key[:8], 16) % 4 == 0 for r in reqs])
    assert failed.any() and (~failed).any()
    assert np.all(np.isnan(losses[failed])) and np.all(np.isfinite(losses[~failed]))
    assert store.count("failed") == failed.sum()
    again = batch.evaluate_losses(jobs, store=store, executor=batch.InlineExecutor())
    assert np.array_equal(np.isnan(again), failed) and np.allclose(again[~failed], losses[~failed])


def test_process_pool_matches_inline(tmp_path):
    reqs = _requests()
    inline = batch.evaluate(reqs, executor=batch.InlineExecutor())
    with batch.local_executor(2) as ex:
        pooled = batch.evaluate(reqs, store=Store(tmp_path), executor=ex)
    for a, b in zip(inline, pooled):
        assert np.array_equal(a.silhouettes, b.silhouettes)


def test_losses_of_a_large_batch_do_not_keep_its_silhouettes(tmp_path):
    # a study of tens of thousands of simulations (Fig. 9 at the paper's 51 x 51 setups) keeps only losses:
    # each result is stored, scored and dropped as it completes
    import gc
    import weakref
    from concurrent.futures import ThreadPoolExecutor

    reqs = _requests(n=8)
    ref = batch.run_one(reqs[0]).silhouettes
    seen, held = [], []

    def on_result(req, res, cached):  # how many earlier results are still in memory when this one arrives
        gc.collect()
        held.append(sum(r() is not None for r in seen))
        seen.append(weakref.ref(res))

    with ThreadPoolExecutor(2) as ex:
        losses = batch.evaluate_losses([(r, "exp", ref) for r in reqs], store=Store(tmp_path), executor=ex,
                                       on_result=on_result)
    assert len(held) == len(reqs) and max(held) <= 1  # at most the previous one, not yet released by the loop
    inline = batch.evaluate_losses([(r, "exp", ref) for r in reqs], executor=batch.InlineExecutor())
    np.testing.assert_array_equal(losses, inline)
    assert losses[0] == 0.0 and np.all(losses[1:] > 0)


def test_dask_local_cluster_matches_local(tmp_path):
    distributed = pytest.importorskip("distributed")
    reqs = _requests()
    ref = batch.run_one(reqs[0]).silhouettes
    jobs = [(r, "exp", ref) for r in reqs]
    local = batch.evaluate_losses(jobs, store=Store(tmp_path / "a"), executor=batch.InlineExecutor())
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None) as cluster:
        with distributed.Client(cluster) as client:
            via_client = batch.evaluate_losses(jobs, store=Store(tmp_path / "b"), executor=client)
            via_executor = batch.evaluate_losses(jobs, store=Store(tmp_path / "c"), executor=client.get_executor())
    assert np.array_equal(local, via_client) and np.array_equal(local, via_executor)
    assert local[0] == 0.0 and np.all(local[1:] > 0)


def test_requests_name_the_engine_that_simulates_them(monkeypatch):
    """request_for records $VIRHEO_ARCH's engine in the request (its key): results of one engine never stand in for
    another's. f64 runs on taichi-cpu whichever CPU engine is chosen."""
    from mpm import runtime

    monkeypatch.setattr(runtime, "native_missing", lambda: None)  # as if built, wherever this runs
    keys = {}
    for arch, f32, f64 in (("taichi-cpu", "taichi-cpu", "taichi-cpu"), ("native", "native", "taichi-cpu"),
                           ("cpu", "native", "taichi-cpu")):
        monkeypatch.setenv("VIRHEO_ARCH", arch)
        req = _requests(n=1)[0]
        assert req.model.engine == f32 and req.to_dict()["engine"] == f32
        assert batch.request_for(Material(1.0, 0.5, 2.0), Setup(30, 40), density=1000.0, precision="f64",
                                 simulator=SIM).model.engine == f64
        keys[arch] = req.key
    assert keys["taichi-cpu"] != keys["native"] == keys["cpu"]
    monkeypatch.setenv("VIRHEO_ARCH", "gpu")
    with pytest.raises(ValueError, match="VIRHEO_ARCH") as e:
        _requests(n=1)
    assert "\n" not in str(e.value)


def test_a_worker_on_another_engine_refuses_the_request(monkeypatch):
    """A worker whose VIRHEO_ARCH chooses another engine than the requester's (a dask worker set up differently)
    says so in one line instead of storing one engine's result under another's key."""
    from dataclasses import replace

    monkeypatch.setenv("VIRHEO_ARCH", "taichi-cpu")
    req = _requests(batch.DEFAULT_SIMULATOR, n=1)[0]
    req = replace(req, model=replace(req.model, engine="native"))
    with pytest.raises(ValueError, match="requested for the native engine would run on taichi-cpu") as e:
        batch.run_one(req)
    assert "\n" not in str(e.value)


def test_code_version_covers_the_native_sources(tmp_path, monkeypatch):
    """Editing a native source (any file under mpm/native/ but build outputs) changes the MPM simulator's version."""
    listed = batch.native_sources()
    assert all(p.suffix not in (".o", ".so") for p in listed)
    assert {p.suffix for p in listed} >= ({".cpp", ".h"} if listed else set())
    src = tmp_path / "kernel.h"
    src.write_text("// one\n")
    monkeypatch.setattr(batch, "native_sources", lambda: listed + [src])
    versions = []
    for text in ("// one\n", "// two\n"):
        src.write_text(text)
        monkeypatch.setattr(batch, "_VERSIONS", {})
        versions.append(batch.code_version(batch.DEFAULT_SIMULATOR))
    assert versions[0] != versions[1]
    assert "native_engine.py" not in batch._NOT_SIMULATION  # its driver is hashed with the other mpm/*.py


def test_workers_stop_when_their_parent_is_killed(tmp_path):
    """A parent killed by a signal it cannot handle (here SIGKILL; SIGTERM to the parent alone is the same) never
    shuts its pool down: its workers notice within seconds and stop, instead of simulating on for nobody."""
    import os
    import signal
    import subprocess
    import sys
    import time

    script = (
        "import os, time\n"
        "from mpm import batch\n"
        "ex = batch.local_executor(1)\n"
        "print(ex.submit(os.getpid).result(), flush=True)\n"
        "ex.submit(time.sleep, 120)\n"
        "time.sleep(120)\n"
    )
    parent = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True,
                              env={**os.environ, "VIRHEO_ARCH": "taichi-cpu"})
    worker = int(parent.stdout.readline())
    os.kill(parent.pid, signal.SIGKILL)
    parent.wait()
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline:
        try:
            os.kill(worker, 0)
        except ProcessLookupError:
            break
        try:  # reap it where this test process adopted it (a subreaper)
            os.waitpid(worker, os.WNOHANG)
        except ChildProcessError:
            pass
        time.sleep(0.2)
    else:
        os.kill(worker, signal.SIGKILL)
        raise AssertionError(f"worker {worker} still runs 15 s after its parent was killed")


def test_a_batch_is_submitted_dearest_first(tmp_path):
    # a 70x70 mm box at 2.5 mm cells before 20x20 at the same cells, finer cells before coarser: the batch ends on
    # its cheapest simulations, whatever order the caller asked in; the results come back in the caller's order
    from concurrent.futures import Executor

    from mpm.model import ForwardModel

    m = Material(1.0, 0.6, 4.0)
    reqs = [batch.request_for(m, Setup(w, h), density=1000.0, image_size=(96, 54), simulator=SIM,
                              model=ForwardModel(cell_mm=cell, ppc=2))
            for w, h, cell in ((20, 20, 2.5), (70, 70, 2.5), (30, 40, 5.0), (30, 40, 2.5))]
    submitted = []

    class Recording(Executor):  # a pool's path through _serve: everything submitted, then collected
        def submit(self, fn, /, *args, **kwargs):
            submitted.append(args[0])
            return batch.InlineExecutor().submit(fn, *args, **kwargs)

    out = batch.evaluate(reqs, store=Store(tmp_path), executor=Recording())
    assert [(r.width_mm, r.height_mm, r.model.cell_mm) for r in submitted] == [
        (70, 70, 2.5), (30, 40, 2.5), (20, 20, 2.5), (30, 40, 5.0)]
    assert [batch.work(r) for r in submitted] == sorted(map(batch.work, reqs), reverse=True)
    assert all(np.array_equal(o.silhouettes, batch.run_one(r).silhouettes) for o, r in zip(out, reqs))
