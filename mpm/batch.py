"""Evaluate many simulation requests in parallel through a ``concurrent.futures`` executor.

* Local processes by default (``ProcessPoolExecutor`` with the 'spawn' context: each worker is a
  long-lived process, so the Taichi runtime and its compiled kernels survive between tasks).
* Any ``concurrent.futures.Executor`` may be passed instead, e.g. a dask.distributed
  ``Client.get_executor()``; a ``Client`` itself is turned into its executor.  The code path is
  the same: ``submit`` + ``as_completed``, no scheduler of our own; a batch is only submitted dearest first
  (:func:`work`), so that it ends on its cheapest simulations.
* ``workers=0`` evaluates in the calling process (:class:`InlineExecutor`), for tests and debugging.

The store is consulted before anything is submitted and every result is written to it the moment
it arrives, so a killed run loses only the simulations that were in flight.  A simulation that
fails (``SimulationError`` or another ``RuntimeError``/``ArithmeticError``) is stored as failed and
its loss is NaN; any other exception is a bug and propagates.
"""
from __future__ import annotations

import hashlib
import importlib
import json
import multiprocessing
import os
import sys
import threading
import time
from concurrent.futures import Executor, Future, ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Callable, Iterable, Sequence

import numpy as np

from mpm import runtime
from mpm.loss import video_loss
from mpm.model import ForwardModel
from mpm.params import DEFAULT_DEPTH_MM, WORKING_SIZE
from mpm.store import SimRequest, SimResult, Store, digest

DEFAULT_SIMULATOR = "mpm.batch:run_mpm"

# Source files of this package that do not change what a simulation computes.
_NOT_SIMULATION = {"store.py", "store_index.py", "files.py", "batch.py", "forward.py", "datasets.py", "experiment.py",
                   "loss.py", "shear.py", "ranges.py", "laws.py", "model.py", "__init__.py"}


# -- requests --------------------------------------------------------------------------------------
def camera_json(camera) -> str | None:
    """Canonical JSON of a camera (an object with ``to_dict()``, a dict, or None)."""
    if camera is None:
        return None
    d = camera.to_dict() if hasattr(camera, "to_dict") else dict(camera)
    return json.dumps(d, sort_keys=True, separators=(",", ":"), default=float)


def request_for(material, setup, *, density: float, model: ForwardModel = ForwardModel(),
                depth_mm: float = DEFAULT_DEPTH_MM, camera=None, dim: int = 3, precision: str = "f32",
                image_size=WORKING_SIZE, simulator: str = DEFAULT_SIMULATOR) -> SimRequest:
    """Build a :class:`SimRequest` from any material (``.eta .n .sigma_y``) and setup (``.width_mm .height_mm``)
    with ``model`` keyed (:meth:`ForwardModel.keyed`: its defaults filled in and its engine resolved; ValueError,
    one line, for an unavailable engine)."""
    return SimRequest(
        eta=float(material.eta), n=float(material.n), sigma_y=float(material.sigma_y),
        width_mm=float(setup.width_mm), height_mm=float(setup.height_mm), density=float(density),
        depth_mm=float(depth_mm), camera=camera_json(camera), model=model.keyed(str(precision)), dim=int(dim),
        precision=str(precision), image_size=tuple(int(v) for v in image_size), simulator=simulator,
        code_version=code_version(simulator),
    )


_VERSIONS: dict[str, str] = {}
_BUILT = {".o", ".obj", ".so", ".pyd", ".dll", ".dylib", ".a", ".lib", ".pyc", ".d"}  # build outputs, not sources


def native_sources() -> list[Path]:
    """The native engine's source files: everything under ``mpm/native/`` but build outputs, sorted."""
    base = Path(__file__).parent / "native"
    if not base.is_dir():
        return []
    return sorted(p for p in base.rglob("*") if p.is_file() and p.suffix not in _BUILT
                  and not {"__pycache__", "build"} & set(p.relative_to(base).parts[:-1]))


def code_version(simulator: str) -> str:
    """Version of the forward model's source: ``CODE_VERSION`` of its module if set, else a source hash.

    For the MPM simulator the hash covers every ``mpm/*.py`` that takes part in simulating
    (not the store, batch, data or loss modules) and the native engine's sources under ``mpm/native/``, so
    editing either engine invalidates the cache.
    """
    if simulator in _VERSIONS:
        return _VERSIONS[simulator]
    module_name = simulator.split(":")[0]
    module = importlib.import_module(module_name)
    version = getattr(module, "CODE_VERSION", None)
    if version is None:
        h = hashlib.sha256()
        here = Path(__file__).parent
        if simulator == DEFAULT_SIMULATOR:
            files = sorted(p for p in here.glob("*.py") if p.name not in _NOT_SIMULATION) + native_sources()
        else:
            files = [Path(module.__file__)]
        for p in files:
            h.update(p.relative_to(here).as_posix().encode() if p.is_relative_to(here) else p.name.encode())
            h.update(p.read_bytes())
        version = h.hexdigest()[:16]
    _VERSIONS[simulator] = version
    return version


# -- the forward model (runs in the workers) -------------------------------------------------------
def run_mpm(request: SimRequest) -> SimResult:
    """The default forward model: :func:`mpm.simulate` of the request's material, setup and experiment with its
    model, whole."""
    import mpm.solver as solver
    from mpm.camera import Camera
    from mpm.params import Material, Setup

    camera = Camera.from_dict(json.loads(request.camera)) if request.camera else None
    sim = solver.simulate(Material(*request.material), Setup(request.width_mm, request.height_mm),
                          model=request.model, density=request.density, dim=request.dim, camera=camera,
                          depth_mm=request.depth_mm, image_size=tuple(request.image_size), precision=request.precision)
    sil = None if getattr(sim, "silhouettes", None) is None else np.asarray(sim.silhouettes, dtype=bool)
    return SimResult(sil, np.asarray(sim.front_m, float), np.asarray(sim.times, float), dict(sim.stats or {}))


def _resolve(simulator: str) -> Callable[[SimRequest], SimResult]:
    module_name, _, func = simulator.partition(":")
    return getattr(importlib.import_module(module_name), func or "simulate")


def run_one(request: SimRequest) -> SimResult:
    """Run one request with its simulator; a failed simulation becomes a SimResult with ``error``."""
    t0 = time.perf_counter()
    try:
        result = _resolve(request.simulator)(request)
    except (RuntimeError, ArithmeticError) as exc:  # SimulationError is a RuntimeError
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        result = SimResult(None, error=f"{type(exc).__name__}: {msg}")
    result.wall_seconds = time.perf_counter() - t0
    if result.ok and result.silhouettes is not None and not np.all(np.isfinite(result.front_m)):
        result = SimResult(None, error="non-finite front position", wall_seconds=result.wall_seconds)
    return result


# -- executors --------------------------------------------------------------------------------------
class InlineExecutor(Executor):
    """Runs each task in the calling process at submit time (``workers=0``)."""

    def submit(self, fn, /, *args, **kwargs):
        fut = Future()
        try:
            fut.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001  (delivered through the future)
            fut.set_exception(exc)
        return fut


def _exit_with_parent(parent: int, every_s: float = 1.0) -> None:
    """Stop this worker within ``every_s`` once its parent has died: a parent killed by a signal it cannot handle
    (SIGTERM to it alone, SIGKILL) never shuts its pool down, and its workers would simulate on for nobody."""
    while True:
        time.sleep(every_s)
        if os.getppid() != parent:
            os._exit(1)


def _init_worker() -> None:
    threading.Thread(target=_exit_with_parent, args=(os.getppid(),), daemon=True, name="exit-with-parent").start()
    os.environ.setdefault("OMP_NUM_THREADS", "1")  # one simulation per core
    runtime.leave_notices_to_parent()  # local_executor said which engine runs, once for all workers
    # results travel back through the executor: what a worker prints (Taichi's start-up lines) is noise
    sys.stdout = open(os.devnull, "w")


def local_executor(workers: int | None = None) -> Executor:
    """Local worker processes ('spawn'), which inherit ``$VIRHEO_ARCH`` and so the engine; ``workers=0`` ->
    in-process. Default: one per CPU core. ValueError (one line) for an unknown or unavailable engine."""
    if workers is not None and workers < 0:
        raise ValueError(f"workers={workers} must be >= 0 (0: in this process)")
    if workers == 0:
        return InlineExecutor()
    runtime.engine_for(say=True)  # an unknown or unavailable engine fails here, before any worker starts
    return ProcessPoolExecutor(
        max_workers=int(workers or os.cpu_count() or 1), mp_context=multiprocessing.get_context("spawn"),
        initializer=_init_worker,
    )


def as_executor(executor) -> Executor:
    """Accept a concurrent.futures Executor or a dask.distributed Client (-> its executor)."""
    if hasattr(executor, "get_executor") and not isinstance(executor, Executor):
        return executor.get_executor()
    return executor


def shutdown(executor) -> None:
    """Shut an executor down, cancelling what has not started (dask's executor lacks ``cancel_futures``)."""
    if executor is None or not hasattr(executor, "shutdown"):
        return
    try:
        executor.shutdown(wait=True, cancel_futures=True)
    except TypeError:
        executor.shutdown(wait=True)


def connect(scheduler: str):
    """A dask.distributed executor for ``--scheduler ADDRESS`` (tcp://host:port)."""
    from distributed import Client

    return Client(scheduler).get_executor()


# -- evaluation -------------------------------------------------------------------------------------
def work(request: SimRequest) -> float:
    """A simulation's relative cost: its particles (the box's volume over the particle spacing cubed) times its
    steps (inversely proportional to the cell width)."""
    spacing_mm = request.model.cell_mm / request.model.ppc
    return request.width_mm * request.height_mm * request.depth_mm / spacing_mm ** 3 / request.model.cell_mm


def _serve(requests: Iterable[SimRequest], store: Store | None, executor,
           done: Callable[[SimRequest, SimResult, bool], None]) -> None:
    """``done(request, result, cached)`` once per distinct request: from the store where present, else simulated via
    ``executor`` and stored as each completes.  Nothing is kept after ``done``, so a study of many simulations holds
    only the results its caller keeps."""
    seen, todo = set(), {}
    for req in requests:
        if req.key in seen:
            continue
        seen.add(req.key)
        hit = store.get(req) if store is not None else None
        if hit is not None:
            done(req, hit, True)
        else:
            todo[req.key] = req
    # dearest first: a batch then ends on its cheapest simulations, so no worker waits long for the last one
    todo = dict(sorted(todo.items(), key=lambda kv: -work(kv[1])))

    def finish(key: str, res: SimResult) -> None:
        if store is not None:
            store.put(todo[key], res)
        done(todo[key], res, False)

    ex = local_executor(0) if executor is None else as_executor(executor)
    if isinstance(ex, InlineExecutor):  # one at a time, each stored before the next starts
        for key, req in todo.items():
            finish(key, run_one(req))
        return
    futures = {ex.submit(run_one, req): key for key, req in todo.items()}
    try:
        for fut in as_completed(futures):
            finish(futures.pop(fut), fut.result())
    finally:
        for fut in futures:
            fut.cancel()


def evaluate(requests: Sequence[SimRequest], *, store: Store | None = None, executor=None,
             on_result: Callable[[SimRequest, SimResult, bool], None] | None = None) -> list[SimResult]:
    """Results of ``requests`` in order: from the store where present, else simulated via ``executor``.

    Identical requests are simulated once.  Each new result is stored as soon as it completes.
    ``on_result(request, result, cached)`` is called once per distinct request (for progress bars).
    """
    results: dict[str, SimResult] = {}

    def keep(req: SimRequest, res: SimResult, cached: bool) -> None:
        results[req.key] = res
        if on_result:
            on_result(req, res, cached)

    _serve(requests, store, executor, keep)
    return [results[req.key] for req in requests]


def evaluate_losses(jobs: Iterable[tuple[SimRequest, str, np.ndarray]], *, store: Store | None = None,
                    executor=None, on_result=None) -> np.ndarray:
    """Video losses (eq. 3) of ``(request, experiment_id, reference_frames)`` jobs; NaN for failures.

    Cached losses are served from the store without loading arrays; a stored simulation without that loss is
    loaded and scored; the rest are simulated, stored and scored as they complete, their silhouettes then
    dropped, so memory does not grow with the number of jobs.
    """
    jobs = list(jobs)
    out = np.full(len(jobs), np.nan)
    by_key: dict[str, list[int]] = {}
    for i, (req, exp_id, _) in enumerate(jobs):
        cached = store.get_loss(req, exp_id) if store is not None else None
        if cached is None:
            by_key.setdefault(req.key, []).append(i)
        else:
            out[i] = cached
            if on_result:
                on_result(req, None, True)

    def score(req: SimRequest, res: SimResult, cached: bool) -> None:
        for i in by_key[req.key]:
            _, exp_id, ref = jobs[i]
            out[i] = float(video_loss(res.silhouettes, ref)) if res.ok and res.silhouettes is not None else float("nan")
            if store is not None:
                store.put_loss(req, exp_id, out[i])
        if on_result:
            on_result(req, res, cached)

    _serve((jobs[idx[0]][0] for idx in by_key.values()), store, executor, score)
    return out


def experiment_id(frames: np.ndarray, name: str = "") -> str:
    """Content id of reference footage: hash of its packed silhouettes (and name)."""
    f = np.asarray(frames, dtype=bool)
    h = hashlib.sha256(np.packbits(f).tobytes())
    h.update(repr(f.shape).encode())
    return digest({"frames": h.hexdigest(), "name": name})[:32]
