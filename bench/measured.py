"""How a benchmark was measured, for the header of its printed output: the measuring conditions belong to the
figures a bench prints, not to the prose of docs/ that quotes them.

    from measured import how_measured          # bench/ is a script's own folder on sys.path
    print(f"# measured: {how_measured()}")
"""
from __future__ import annotations

import datetime
import hashlib
import os
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def how_measured() -> str:
    """Date, commit, CPU model and cores, load average, the engine ``$VIRHEO_ARCH`` chooses, threads per
    simulation process and, where the native engine is built, its SIMD path and build: one line."""
    from mpm import runtime

    try:
        engine = runtime.engine_name()
    except ValueError as exc:
        engine = f"none ({exc})"
    return (f"{datetime.datetime.now().isoformat(timespec='minutes')}, commit {commit()}, {cpu_model()} "
            f"({os.cpu_count()} cores), load {load()}, engine {engine}, {runtime.threads()} thread(s) per "
            f"simulation process, {native_build()}")


def commit() -> str:
    """The checkout's commit, with -dirty when it has uncommitted changes."""
    try:
        return subprocess.run(["git", "-C", str(ROOT), "describe", "--always", "--dirty"], capture_output=True,
                              text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"


def cpu_model() -> str:
    if not os.path.exists("/proc/cpuinfo"):
        return "unknown CPU"
    with open("/proc/cpuinfo") as info:
        return next((line.split(":", 1)[1].strip() for line in info if line.startswith("model name")), "unknown CPU")


def native_build() -> str:
    """The native engine's SIMD path and the extension this process runs (its file's hash and time: a rebuild in
    place shows here), or why it does not run."""
    from mpm import native_engine, runtime

    missing = runtime.native_missing()
    if missing is not None:
        return f"native engine not available ({missing})"
    from mpm import _native

    path = Path(_native.__file__)
    stamp = datetime.datetime.fromtimestamp(path.stat().st_mtime).isoformat(timespec="seconds")
    return (f"native isa {native_engine.isa()}, extension {path.name} sha256 "
            f"{hashlib.sha256(path.read_bytes()).hexdigest()[:12]} built {stamp}")


def load() -> str:
    """The 1-, 5- and 15-minute load averages."""
    return "%.2f/%.2f/%.2f" % os.getloadavg()
