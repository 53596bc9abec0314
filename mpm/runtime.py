"""The Taichi runtime, set up in one place: architecture, CPU threads and default float precision.

``$VIRHEO_ARCH`` = auto (default: CUDA when available, else CPU) | cpu | cuda; ``$VIRHEO_THREADS``: CPU
threads (default 1: more threads made every measured model slower, docs/performance.md). Taichi holds one default
float per process, so switching precision re-initialises it (and recompiles): keep one per process.
Importing this module does not initialise Taichi.
"""
import contextlib
import io
import os

import taichi as ti
from taichi.lang import impl

PRECISIONS = ("f32", "f64")
# Taichi's own IR optimisation passes (CFG store forwarding, whole-kernel CSE) take minutes on the single-launch
# 3D step kernel and gain little over LLVM's: off, the first compile takes seconds (docs/performance.md)
ADVANCED_OPTIMIZATION = False


def arch():
    """The Taichi architecture chosen by ``$VIRHEO_ARCH``; ValueError for an unknown value or a missing GPU."""
    want = os.environ.get("VIRHEO_ARCH", "auto").lower()
    if want not in ("auto", "cpu", "cuda"):
        raise ValueError(f"VIRHEO_ARCH must be auto, cpu or cuda, got {want!r}")
    if want == "cpu":
        return ti.cpu
    has_cuda = bool(getattr(ti._lib.core, "with_cuda", lambda: False)()) and (
        os.path.exists("/dev/nvidia0") or os.path.exists("/dev/nvidiactl"))
    if want == "cuda" and not has_cuda:
        raise ValueError("VIRHEO_ARCH=cuda but no CUDA device is available")
    return ti.cuda if has_cuda else ti.cpu


def threads() -> int:
    """CPU threads for Taichi: ``$VIRHEO_THREADS``, default 1 (one thread runs each quarter frame in one launch);
    ValueError unless a whole number."""
    value = os.environ.get("VIRHEO_THREADS", "1")
    try:
        return max(1, int(value))
    except ValueError:
        raise ValueError(f"VIRHEO_THREADS must be a whole number of threads, got {value!r}") from None


def float_type(precision: str):
    """Taichi float type of ``precision`` ("f32" or "f64")."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be f32 or f64, got {precision!r}")
    return ti.f32 if precision == "f32" else ti.f64


def initialised() -> bool:
    """True once Taichi runs in this process."""
    return impl.get_runtime().prog is not None


def ensure_taichi(precision: str | None = None):
    """Initialise Taichi unless it already runs with ``precision`` (None: any precision, f32 when it
    must start); returns the running program."""
    rt = impl.get_runtime()
    if precision is None:
        if rt.prog is not None:
            return rt.prog
        precision = "f32"
    fp = float_type(precision)
    if rt.prog is not None and rt.default_fp == fp:
        return rt.prog
    if rt.prog is not None:
        ti.reset()
    with contextlib.redirect_stdout(io.StringIO()):  # Taichi prints its start-up lines to stdout
        ti.init(arch=arch(), default_fp=fp, offline_cache=True, cpu_max_num_threads=threads(), log_level=ti.WARN,
                advanced_optimization=ADVANCED_OPTIMIZATION)
    return impl.get_runtime().prog


def arch_name() -> str:
    """Name of the architecture Taichi runs on ("x64", "cuda", ...)."""
    return str(impl.current_cfg().arch).split(".")[-1]


def on_cpu() -> bool:
    return impl.current_cfg().arch == ti.cpu
