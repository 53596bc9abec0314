"""Simulation store: an SQLite index plus compressed arrays on disk, and optimiser checkpoints.

Every simulation *request* (material, setup, density, depth, camera, cell width, dimension, flow
rule, precision, image size, simulator, its code version and engine) has a stable key, the SHA-256 of its
canonical JSON.  A finished simulation is stored as

* ``sims/<key[:2]>/<key>.npz``: silhouettes packed with ``np.packbits``, front position per frame,
  frame times, the solver's stats and the request itself;
* one row in ``index.sqlite`` (table ``sims``, :mod:`mpm.store_index`) with the request, status (``ok`` /
  ``failed``), error text, wall time, and the request's material and setting (what :meth:`Store.materials`
  searches).  Failed simulations are remembered too: the simulator is deterministic for a given request, so a
  failure is a result (the optimiser sees NaN).

Video losses against an experiment are cached per (request key, experiment id) in ``losses``;
CMA-ES checkpoints (any picklable object) live in ``checkpoints/<run_id>.pkl`` with the previous
one kept as ``<run_id>.prev.pkl``.

Crash safety: every file is written by :func:`mpm.files.atomic_write` (temp file, rename) *before*
its index row is committed (one SQLite transaction, WAL journal), so a kill at any moment leaves
complete files only.  Damage from outside (a full disk, an interrupted copy) is healed on open:
a damaged index is moved aside and rebuilt from the array files, an unreadable array is
simulated again, an unreadable checkpoint falls back to the previous one or to the start.
"""
from __future__ import annotations

import json
import os
import pickle
import sqlite3
import time
import warnings
import zipfile
import zlib
from dataclasses import dataclass, field, fields
from functools import cached_property
from pathlib import Path

import numpy as np

from mpm.files import atomic_write, canonical_json, digest, json_default, pack, unpack  # noqa: F401 (re-exported)
from mpm.files import save_arrays
from mpm.model import MODEL_FIELDS, ForwardModel
from mpm.params import DEFAULT_DEPTH_MM, WORKING_SIZE
from mpm.store_index import INSERT_SIM, open_index


@dataclass(frozen=True)
class SimRequest:
    """Everything that determines one dam-break simulation (SI, setup in mm).

    ``camera`` is the camera's ``to_dict()`` as canonical JSON text (None: no silhouettes);
    ``model`` the forward model, whole, with the engine that runs it (``mpm.runtime.engine_for``), so that one
    engine's results never stand in for another's; ``simulator`` names the simulating function as
    ``"module:function"`` and ``code_version`` its source version, so that a changed solver never serves stale
    results.
    """

    eta: float
    n: float
    sigma_y: float
    width_mm: float
    height_mm: float
    density: float
    depth_mm: float = DEFAULT_DEPTH_MM
    camera: str | None = None
    model: ForwardModel = ForwardModel()  # keyed (ForwardModel.keyed): resolved, its engine named
    dim: int = 3
    precision: str = "f32"
    image_size: tuple = WORKING_SIZE
    simulator: str = "mpm.batch:run_mpm"
    code_version: str = ""

    def to_dict(self) -> dict:
        """The request as flat JSON values: the model's fields beside the others, as requests always were; an
        engine left open (requests stored before engines) and the paper's moduli are left out (the keys they had)."""
        d = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "model"}
        d.update(self.model.to_dict())
        if not d["engine"]:
            del d["engine"]
        d["image_size"] = list(self.image_size)
        d["camera"] = json.loads(self.camera) if self.camera else None
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "SimRequest":
        d = dict(d)
        d["image_size"] = tuple(d.get("image_size", WORKING_SIZE))
        cam = d.get("camera")
        d["camera"] = canonical_json(cam) if cam is not None else None
        model = {k: d.pop(k) for k in MODEL_FIELDS if k in d}
        model["engine"] = model.get("engine") or None
        return cls(**d, model=ForwardModel(**model))

    @cached_property
    def key(self) -> str:
        """The request's stable key: the SHA-256 of its canonical JSON (computed once: a study asks it many times)."""
        return digest(self.to_dict())

    @property
    def setting_key(self) -> str:
        """Digest of everything but the material: requests that differ only in the material share it."""
        return digest({k: v for k, v in self.to_dict().items() if k not in ("eta", "n", "sigma_y")})

    @property
    def material(self) -> tuple:
        return (self.eta, self.n, self.sigma_y)


@dataclass
class SimResult:
    """Outcome of one simulation: silhouettes (F, H, W) bool or None, front (F,) in m, stats.

    ``error`` is None for a success, else a one-line description of the failure.
    """

    silhouettes: np.ndarray | None
    front_m: np.ndarray | None = None
    times: np.ndarray | None = None
    stats: dict = field(default_factory=dict)
    error: str | None = None
    wall_seconds: float = float("nan")

    @property
    def ok(self) -> bool:
        return self.error is None

    @property
    def particle_steps(self) -> float | None:
        """Particles x time steps: the simulation's work, the same on every machine and under any load (None when
        its record does not say, e.g. a failed simulation)."""
        stats = self.stats or {}
        if stats.get("n_particles") is None or stats.get("steps") is None:
            return None
        return float(stats["n_particles"]) * float(stats["steps"])


def _setting_of(request_json: str) -> tuple:
    """(setting key, eta, n, sigma_y) of a request in the index (all None for one that does not parse)."""
    try:
        r = SimRequest.from_dict(json.loads(request_json))
    except (ValueError, TypeError):
        return (None, None, None, None)
    return (r.setting_key, *r.material)


class StoreWarning(UserWarning):
    """A damaged part of the store was set aside; the run goes on without it."""


_UNREADABLE = (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, zlib.error)


class Store:
    """Persistent cache of simulations, their losses and optimiser checkpoints under ``root``.

    Opening a store heals it: a damaged index is moved aside and rebuilt from the intact arrays on
    disk; an unreadable array or checkpoint is treated as missing.  Each repair is one
    :class:`StoreWarning`.
    """

    def __init__(self, root):
        self.root = Path(root)
        if self.root.exists() and not self.root.is_dir():
            raise NotADirectoryError(f"store {self.root} is a file, not a folder: name a folder for --store")
        self.root.mkdir(parents=True, exist_ok=True)
        self._warned: set[str] = set()
        try:
            self._db = self._open_index()
        except sqlite3.DatabaseError as exc:
            self._db = self._rebuild_index(exc)
        else:
            if self._db.execute("SELECT COUNT(*) FROM sims").fetchone()[0] == 0 and any(self._array_files()):
                self._db.close()
                self._db = self._rebuild_index(None)
        self._sweep_temp_files()

    @property
    def index_path(self) -> Path:
        return self.root / "index.sqlite"

    def _open_index(self) -> sqlite3.Connection:
        return open_index(self.index_path, _setting_of)

    def _array_files(self):
        base = self.root / "sims"
        return base.glob("*/*.npz") if base.is_dir() else iter(())

    def _warn(self, key: str, message: str) -> None:
        if key not in self._warned:
            self._warned.add(key)
            warnings.warn(message, StoreWarning, stacklevel=3)

    def _rebuild_index(self, error) -> sqlite3.Connection:
        """Move a damaged index aside and index every readable array file again."""
        aside = None
        if error is not None:
            aside = self.index_path.with_name(f"index.sqlite.damaged-{time.strftime('%Y%m%d-%H%M%S')}")
            for suffix in ("", "-wal", "-shm"):
                src = Path(str(self.index_path) + suffix)
                if src.exists():
                    os.replace(src, Path(str(aside) + suffix))
        db = self._open_index()
        rows, skipped = [], 0
        for path in self._array_files():
            try:
                with np.load(path) as z:
                    request = json.loads(str(z["request"]))
                    wall = float(z["wall_seconds"]) if "wall_seconds" in z.files else float("nan")
                    unpack(z["silhouettes"], z["shape"]) if z["shape"].size else None
                req = SimRequest.from_dict(request)
                key = req.key
            except (*_UNREADABLE, TypeError):
                skipped += 1
                continue
            if key != path.stem:
                skipped += 1
                continue
            rows.append((key, canonical_json(request), "ok", None, wall, path.stat().st_mtime,
                         req.setting_key, *req.material))
        with db:
            db.execute("BEGIN IMMEDIATE")
            db.executemany(INSERT_SIM, rows)
        what = (f"store index {self.index_path} was damaged ({str(error).splitlines()[0]}); moved to {aside.name}"
                if error is not None else f"store index {self.index_path} had no entries")
        self._warn("index", f"{what}; rebuilt from {len(rows)} intact simulations on disk"
                   + (f" ({skipped} unreadable files will be simulated again)" if skipped else ""))
        return db

    # -- simulations -------------------------------------------------------------------------
    def _array_path(self, key: str) -> Path:
        return self.root / "sims" / key[:2] / f"{key}.npz"

    def has(self, request: SimRequest) -> bool:
        row = self._db.execute("SELECT 1 FROM sims WHERE key=?", (request.key,)).fetchone()
        return row is not None

    def get(self, request: SimRequest) -> SimResult | None:
        """The stored result of ``request``, or None when it was never simulated (or its file is unreadable)."""
        key = request.key
        row = self._db.execute("SELECT status, error, wall_seconds FROM sims WHERE key=?", (key,)).fetchone()
        if row is None:
            return None
        status, error, wall = row
        if status != "ok":
            return SimResult(None, error=error or "failed", wall_seconds=wall if wall is not None else float("nan"))
        path = self._array_path(key)
        try:
            with np.load(path) as z:
                sil = unpack(z["silhouettes"], z["shape"]) if z["shape"].size else None
                front = z["front_m"]
                times = z["times"]
                stats = json.loads(str(z["stats"]))
        except _UNREADABLE as exc:
            self._warn(key, f"simulation file {path} is unreadable ({type(exc).__name__}); it will be simulated again")
            with self._db:
                self._db.execute("BEGIN IMMEDIATE")
                self._db.execute("DELETE FROM sims WHERE key=?", (key,))
            try:
                path.unlink()
            except OSError:
                pass
            return None
        return SimResult(sil, front, times, stats, None, wall if wall is not None else float("nan"))

    def put(self, request: SimRequest, result: SimResult) -> None:
        """Persist ``result``: arrays first (atomic rename), then the index row (one transaction).

        The array file carries its request too, so that a lost index can be rebuilt from the files."""
        key = request.key
        if result.ok:
            if result.silhouettes is not None:
                packed, shape = pack(result.silhouettes)
            else:
                packed, shape = np.zeros((0, 0), np.uint8), ()
            arrays = dict(
                silhouettes=packed,
                shape=np.asarray(shape, dtype=np.int64),
                front_m=np.asarray(result.front_m if result.front_m is not None else [], dtype=float),
                times=np.asarray(result.times if result.times is not None else [], dtype=float),
                stats=np.asarray(canonical_json(result.stats or {})),
                request=np.asarray(canonical_json(request.to_dict())),
                wall_seconds=np.asarray(float(result.wall_seconds)),
            )
            atomic_write(self._array_path(key), lambda fh: save_arrays(fh, **arrays))
        status = "ok" if result.ok else "failed"
        with self._db:  # sqlite3 context: BEGIN ... COMMIT
            self._db.execute("BEGIN IMMEDIATE")
            self._db.execute(
                INSERT_SIM, (key, canonical_json(request.to_dict()), status, result.error, float(result.wall_seconds),
                             time.time(), request.setting_key, *request.material),
            )

    def count(self, status: str | None = None) -> int:
        """Number of stored simulations (optionally only those with ``status`` 'ok' or 'failed')."""
        if status is None:
            return self._db.execute("SELECT COUNT(*) FROM sims").fetchone()[0]
        return self._db.execute("SELECT COUNT(*) FROM sims WHERE status=?", (status,)).fetchone()[0]

    def requests(self) -> list[SimRequest]:
        rows = self._db.execute("SELECT request FROM sims ORDER BY created").fetchall()
        return [SimRequest.from_dict(json.loads(r[0])) for r in rows]

    def timings(self) -> list[tuple[SimRequest, float]]:
        """(request, wall seconds of its simulation) of every simulation that succeeded, in the order they were
        stored: what a simulation costs by model and setup on the machine that ran it."""
        rows = self._db.execute("SELECT request, wall_seconds FROM sims WHERE status='ok' ORDER BY created").fetchall()
        return [(SimRequest.from_dict(json.loads(r)), float("nan") if w is None else float(w)) for r, w in rows]

    def materials(self, settings) -> list[tuple[float, float, float]]:
        """Materials (eta, n, sigma_y) stored (ok or failed) in every one of ``settings`` (``SimRequest.setting_key``
        values), in the order they were first simulated."""
        settings = sorted(set(settings))
        if not settings:
            return []
        rows = self._db.execute(
            f"SELECT eta, n, sigma_y FROM sims WHERE setting IN ({','.join('?' * len(settings))}) "
            "GROUP BY eta, n, sigma_y HAVING COUNT(DISTINCT setting) = ? ORDER BY MIN(created), MIN(rowid)",
            (*settings, len(settings))).fetchall()
        return [tuple(r) for r in rows]

    # -- losses --------------------------------------------------------------------------------
    def get_loss(self, request: SimRequest, experiment_id: str) -> float | None:
        """Cached video loss of ``request`` against experiment ``experiment_id`` (NaN: failed), or None."""
        row = self._db.execute(
            "SELECT loss FROM losses WHERE key=? AND experiment=?", (request.key, experiment_id)
        ).fetchone()
        if row is None:
            return None
        return float("nan") if row[0] is None else float(row[0])

    def put_loss(self, request: SimRequest, experiment_id: str, loss: float) -> None:
        value = None if not np.isfinite(loss) else float(loss)
        with self._db:
            self._db.execute("BEGIN IMMEDIATE")
            self._db.execute(
                "INSERT OR REPLACE INTO losses (key, experiment, loss) VALUES (?,?,?)",
                (request.key, experiment_id, value),
            )

    # -- checkpoints ---------------------------------------------------------------------------
    def _checkpoint_path(self, run_id: str) -> Path:
        return self.root / "checkpoints" / f"{run_id}.pkl"

    def save_checkpoint(self, run_id: str, state) -> None:
        """Pickle ``state`` (e.g. a dict holding the CMAEvolutionStrategy) atomically; the previous
        checkpoint is kept as ``<run_id>.prev.pkl`` to fall back on."""
        data = pickle.dumps(state, protocol=pickle.HIGHEST_PROTOCOL)
        path = self._checkpoint_path(run_id)
        if path.exists():
            os.replace(path, path.with_suffix(".prev.pkl"))
        atomic_write(path, lambda fh: fh.write(data))

    def load_checkpoint(self, run_id: str):
        """The latest readable checkpoint of ``run_id`` (else the one before it), or None."""
        path = self._checkpoint_path(run_id)
        for candidate in (path, path.with_suffix(".prev.pkl")):
            if not candidate.exists():
                continue
            try:
                with open(candidate, "rb") as fh:
                    return pickle.load(fh)
            except Exception as exc:  # noqa: BLE001  (any failure to unpickle means the file is unusable)
                self._warn(f"checkpoint {candidate}", f"checkpoint {candidate} is unreadable "
                           f"({type(exc).__name__}); resuming from the one before it or from the start")
        return None

    # -- housekeeping --------------------------------------------------------------------------
    def _sweep_temp_files(self, older_than_s: float = 3600.0) -> None:
        """Remove temp files left by killed writers (only old ones: others may be writing now)."""
        now = time.time()
        for sub in ("sims", "checkpoints"):
            base = self.root / sub
            if not base.exists():
                continue
            for tmp in base.rglob("*.tmp"):
                try:
                    if now - tmp.stat().st_mtime > older_than_s:
                        tmp.unlink()
                except FileNotFoundError:
                    pass

    def close(self) -> None:
        self._db.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __getstate__(self):  # a Store travels to workers as its path only
        return {"root": str(self.root)}

    def __setstate__(self, state):
        self.__init__(state["root"])
