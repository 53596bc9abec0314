"""Batch evaluation: store lookups first, local processes, dask LocalCluster, failures -> NaN."""
import numpy as np
import pytest

from mpm import batch
from mpm.store import Store
from similarity.space import Material, Setup

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
