"""The one place that chooses the simulation engine and sets up Taichi: engine, CPU threads, float precision.

``$VIRHEO_ARCH`` names the engine (read at each call, so a process may switch by setting ``os.environ``):

* ``native``: the native C++ engine (``mpm.native_engine``; f32 only);
* ``taichi-cpu``: Taichi's CPU path, the reference;
* ``cuda``: Taichi on a GPU;
* ``cpu``: the best CPU engine, native where built, else taichi-cpu;
* ``auto`` (default): cuda where a GPU is present, else as ``cpu``.

``$VIRHEO_THREADS``: CPU threads (default 1: more threads made every measured model slower,
docs/performance.md). Taichi holds one default float per process, so switching precision re-initialises it (and
recompiles): keep one per process. Importing this module neither imports nor initialises Taichi.
"""
import contextlib
import importlib
import io
import os
import sys

PRECISIONS = ("f32", "f64")
ENGINES = ("native", "taichi-cpu", "cuda")  # what engine_name() returns, and stats["arch"] of a simulation
ARCH_VALUES = ("auto", "cpu", "native", "taichi-cpu", "cuda")  # what $VIRHEO_ARCH may say
# Taichi's own IR optimisation passes (CFG store forwarding, whole-kernel CSE) take minutes on the single-launch
# 3D step kernel and gain little over LLVM's: off, the first compile takes seconds (docs/decisions.md#engine)
ADVANCED_OPTIMIZATION = False
_SAID: set = set()  # the notices this process has printed (or left to the process that started it)
_STARTED = {"arch": None}  # the architecture Taichi was initialised for


def _wanted() -> str:
    want = os.environ.get("VIRHEO_ARCH", "auto").strip().lower() or "auto"
    if want not in ARCH_VALUES:
        raise ValueError(f"VIRHEO_ARCH must be one of {', '.join(ARCH_VALUES)}; got {want!r}")
    return want


def _has_cuda() -> bool:
    if not (os.path.exists("/dev/nvidia0") or os.path.exists("/dev/nvidiactl")):
        return False  # no driver: no need to load Taichi to know
    import taichi as ti

    return bool(getattr(ti._lib.core, "with_cuda", lambda: False)())


def native_missing() -> str | None:
    """None when the native engine can run here, else one line saying why not."""
    try:
        native_engine = importlib.import_module("mpm.native_engine")
    except ModuleNotFoundError as exc:
        if exc.name == "mpm.native_engine":
            return "mpm/native_engine.py is missing"
        return f"mpm.native_engine does not import: {exc}".splitlines()[0]
    except ImportError as exc:
        return f"mpm.native_engine does not import: {exc}".splitlines()[0]
    if native_engine.available():
        return None
    return (str(native_engine.why_unavailable()).strip().splitlines() or ["unknown reason"])[0]


def _choose() -> tuple[str, str | None]:
    """(engine, why native was passed over for a ``cpu``/``auto`` choice, or None)."""
    want = _wanted()
    if want == "taichi-cpu":
        return want, None
    if want == "cuda" or (want == "auto" and _has_cuda()):
        if want == "cuda" and not _has_cuda():
            raise ValueError("VIRHEO_ARCH=cuda but no CUDA device is available")
        return "cuda", None
    missing = native_missing()
    if want == "native":
        if missing is not None:
            raise ValueError(f"VIRHEO_ARCH=native but the native engine is not available: {missing}")
        return "native", None
    return ("native", None) if missing is None else ("taichi-cpu", missing)


def engine_name() -> str:
    """The engine ``$VIRHEO_ARCH`` chooses: "native", "taichi-cpu" or "cuda". One-line ValueError for an unknown
    value, for ``cuda`` without a GPU and for ``native`` when the extension is not built."""
    return _choose()[0]


def engine_for(precision: str = "f32", *, say: bool = False) -> str:
    """The engine that runs a simulation in ``precision``: :func:`engine_name`, except that f64 runs on taichi-cpu
    where the native engine (f32 only) is chosen. ``say``: print, once per process, one line on stderr when the
    choice falls back to Taichi's CPU path (the native engine not built; f64 asked of the native engine)."""
    float_type_name(precision)
    name, missing = _choose()
    if missing is not None and say:
        _say_once("missing", f"virheometry: the native engine is not built ({missing}); running on Taichi's CPU path")
    if name == "native" and precision != "f32":
        if say:
            _say_once("f64", "virheometry: the native engine runs f32; f64 runs on taichi-cpu")
        return "taichi-cpu"
    return name


def _say_once(key: str, line: str) -> None:
    if key not in _SAID:
        _SAID.add(key)
        print(line, file=sys.stderr, flush=True)


def leave_notices_to_parent() -> None:
    """In a worker process: the process that started it has said why the native engine is not used."""
    _SAID.add("missing")


def arch():
    """The Taichi architecture for ``$VIRHEO_ARCH``: CUDA for ``cuda`` (and ``auto`` with a GPU), else the CPU
    (also under ``native``, where Taichi only runs what the native engine does not: f64); ValueError for an unknown
    value or a missing GPU."""
    import taichi as ti

    want = _wanted()
    if want == "cuda" and not _has_cuda():
        raise ValueError("VIRHEO_ARCH=cuda but no CUDA device is available")
    return ti.cuda if want == "cuda" or (want == "auto" and _has_cuda()) else ti.cpu


def threads() -> int:
    """CPU threads for a simulation: ``$VIRHEO_THREADS``, default 1 (one thread runs each quarter frame in one
    launch); ValueError unless a whole number."""
    value = os.environ.get("VIRHEO_THREADS", "1")
    try:
        return max(1, int(value))
    except ValueError:
        raise ValueError(f"VIRHEO_THREADS must be a whole number of threads, got {value!r}") from None


def float_type_name(precision: str) -> str:
    """``precision`` itself when it is "f32" or "f64"; ValueError otherwise."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be f32 or f64, got {precision!r}")
    return precision


def float_type(precision: str):
    """Taichi float type of ``precision`` ("f32" or "f64")."""
    import taichi as ti

    return ti.f32 if float_type_name(precision) == "f32" else ti.f64


def initialised() -> bool:
    """True once Taichi runs in this process."""
    if "taichi" not in sys.modules:
        return False
    from taichi.lang import impl

    return impl.get_runtime().prog is not None


def ensure_taichi(precision: str | None = None):
    """Initialise Taichi unless it already runs with ``precision`` (None: any precision, f32 when it
    must start) on the architecture ``$VIRHEO_ARCH`` asks for; returns the running program."""
    import taichi as ti
    from taichi.lang import impl

    rt = impl.get_runtime()
    if precision is None:
        if rt.prog is not None:
            return rt.prog
        precision = "f32"
    fp, want = float_type(precision), arch()
    if rt.prog is not None and rt.default_fp == fp and _STARTED["arch"] in (None, want):
        return rt.prog
    if rt.prog is not None:
        ti.reset()
    with contextlib.redirect_stdout(io.StringIO()):  # Taichi prints its start-up lines to stdout
        ti.init(arch=want, default_fp=fp, offline_cache=True, cpu_max_num_threads=threads(), log_level=ti.WARN,
                advanced_optimization=ADVANCED_OPTIMIZATION)
    _STARTED["arch"] = want
    return impl.get_runtime().prog


def arch_name() -> str:
    """Name of the architecture Taichi runs on ("x64", "cuda", ...)."""
    from taichi.lang import impl

    return str(impl.current_cfg().arch).split(".")[-1]


def on_cpu() -> bool:
    import taichi as ti
    from taichi.lang import impl

    return impl.current_cfg().arch == ti.cpu
