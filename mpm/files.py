"""Files of the simulation store and the reports: canonical JSON and its digest, packed silhouettes,
atomic writes, strict JSON files and reading them back.

Every file the store (and the reports) write goes through :func:`atomic_write` (temp file, rename), so a
kill at any moment leaves the old file or the new one, never half of one.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import tempfile
import zipfile
from pathlib import Path

import numpy as np


def canonical_json(value) -> str:
    """Canonical JSON text of ``value``: sorted keys, no spaces, numpy values as Python ones."""
    return json.dumps(value, sort_keys=True, separators=(",", ":"), default=json_default)


def json_default(o):
    """``json.dumps(default=...)`` for numpy values, paths and objects with ``to_dict()``."""
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    if hasattr(o, "to_dict"):
        return o.to_dict()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def digest(value) -> str:
    """SHA-256 hex digest of the canonical JSON of ``value`` (sorted keys, floats as repr)."""
    return hashlib.sha256(canonical_json(value).encode()).hexdigest()


def pack(silhouettes: np.ndarray) -> tuple[np.ndarray, tuple]:
    """Bool (F, H, W) -> (uint8 packed bits, shape)."""
    s = np.asarray(silhouettes, dtype=bool)
    return np.packbits(s.reshape(s.shape[0], -1), axis=1), tuple(s.shape)


def save_arrays(fh, **arrays) -> None:
    """``np.savez_compressed`` at deflate level 1: the same ``.npz`` that ``np.load`` reads, about 7 times faster to
    write for a simulation's packed silhouettes and about a third larger."""
    with zipfile.ZipFile(fh, "w", zipfile.ZIP_DEFLATED, compresslevel=1) as archive:
        for name, value in arrays.items():
            with archive.open(name + ".npy", "w", force_zip64=True) as member:
                np.lib.format.write_array(member, np.asanyarray(value), allow_pickle=False)


def unpack(packed: np.ndarray, shape) -> np.ndarray:
    shape = tuple(int(v) for v in shape)
    flat = np.unpackbits(packed, axis=1, count=int(np.prod(shape[1:])))
    return flat.reshape(shape).astype(bool)


def _read_umask() -> int:
    mask = os.umask(0o022)  # the only way to read it; set back at once (at import, before any threads)
    os.umask(mask)
    return mask


_UMASK = _read_umask()


def atomic_write(path, write, *, mode: str = "b") -> Path:
    """Write ``path`` all or nothing: ``write(fileobj)`` fills a temp file beside it, which is renamed over ``path``.
    A killed process or a full disk leaves the old file (or none), never a half-written one.  Nothing is forced to
    the disk (no fsync): that would guard only against the machine itself stopping, and cost the store 3-4 ms a
    simulation; a file that a crash of the machine leaves empty is unreadable, and the store simulates it again.
    The file gets the user's normal mode (0666 less the umask).  ``mode``: "b" or "t"."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=path.name + ".", suffix=".tmp", dir=path.parent)
    try:
        os.fchmod(fd, 0o666 & ~_UMASK)
        with os.fdopen(fd, "w" + mode) as fh:
            write(fh)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise
    return path


def _finite_or_none(o):
    """Replace non-finite floats by None (strict JSON)."""
    if isinstance(o, float) and not math.isfinite(o):
        return None
    if isinstance(o, dict):
        return {k: _finite_or_none(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_finite_or_none(v) for v in o]
    return o


def write_json(path, data) -> Path:
    """Write ``data`` as indented strict JSON (non-finite numbers as null), all or nothing."""
    text = json.dumps(_finite_or_none(json.loads(json.dumps(data, default=json_default))), indent=2, allow_nan=False)
    return atomic_write(path, lambda fh: fh.write(text + "\n"), mode="t")


def read_json(path):
    """The JSON value held by file ``path``; a one-line ValueError when the file is not valid JSON."""
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ValueError(f"{path} is not valid JSON: {exc}") from None


def _to_json(value):
    """``value`` with every object that has ``to_dict()`` replaced by its dictionary (inside dicts and lists too)."""
    if hasattr(value, "to_dict"):
        return value.to_dict()
    if isinstance(value, dict):
        return {k: _to_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_to_json(v) for v in value]
    return value


class JsonRecord:
    """Mixin for a dataclass stored as a JSON object: its fields in order, by name.

    ``OMIT_IF_NONE``: fields left out of the JSON while None (optional keys). ``READERS``: field name -> function
    that turns the field's JSON value back into its type (e.g. ``Material``); other fields are taken as they are.
    :meth:`from_dict` ignores keys that are not fields, so a file with more keys than the class still loads.
    """

    OMIT_IF_NONE: tuple = ()
    READERS: dict = {}

    def to_dict(self) -> dict:
        from dataclasses import fields

        return {f.name: _to_json(getattr(self, f.name)) for f in fields(self)
                if not (f.name in self.OMIT_IF_NONE and getattr(self, f.name) is None)}

    @classmethod
    def from_dict(cls, data: dict):
        from dataclasses import fields

        kw = {f.name: data[f.name] for f in fields(cls) if f.name in data}
        for name, read in cls.READERS.items():
            if kw.get(name) is not None:
                kw[name] = read(kw[name])
        return cls(**kw)
