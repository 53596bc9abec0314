"""One place chooses the engine (mpm.runtime): $VIRHEO_ARCH's values, the fallback to Taichi's CPU path, the
one-line errors, and CI's demand for the native engine (VIRHEO_REQUIRE_NATIVE=1)."""
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace as NS

import pytest

from mpm import runtime
from studies.cli import main

REPO = Path(__file__).resolve().parent.parent


def test_the_native_engine_is_built_where_ci_requires_it():
    """CI (.ci/run) sets VIRHEO_REQUIRE_NATIVE=1: there a missing native engine fails the suite (elsewhere it is
    skipped, with the reason). Where built, it is what ``cpu`` and ``native`` choose, on a SIMD path it names."""
    why = runtime.native_missing()
    if why is not None:
        if os.environ.get("VIRHEO_REQUIRE_NATIVE") == "1":
            pytest.fail(f"VIRHEO_REQUIRE_NATIVE=1 but the native engine is not available: {why}")
        pytest.skip(f"native engine unavailable (VIRHEO_REQUIRE_NATIVE=1 makes this a failure): {why}")
    from mpm import native_engine

    assert native_engine.available() and native_engine.why_unavailable() == ""
    assert native_engine.isa() in ("avx512", "avx2", "generic")


@pytest.fixture
def hidden_native(monkeypatch):
    """The native engine as if not built, and no notice said yet in this process."""
    from mpm import native_engine

    monkeypatch.setattr(native_engine, "available", lambda: False)
    monkeypatch.setattr(native_engine, "why_unavailable", lambda: "mpm._native is not built (test)")
    monkeypatch.setattr(runtime, "_SAID", set())


@pytest.fixture
def built_native(monkeypatch):
    monkeypatch.setattr(runtime, "native_missing", lambda: None)
    monkeypatch.setattr(runtime, "_SAID", set())


@pytest.mark.parametrize("value, gpu, engine", [
    ("taichi-cpu", False, "taichi-cpu"), ("taichi-cpu", True, "taichi-cpu"), ("native", False, "native"),
    ("native", True, "native"), ("cpu", False, "native"), ("cpu", True, "native"), ("auto", False, "native"),
    (None, False, "native"), ("auto", True, "cuda"), ("cuda", True, "cuda"), (" CPU ", False, "native"),
])
def test_each_value_chooses_its_engine(value, gpu, engine, built_native, monkeypatch):
    monkeypatch.setattr(runtime, "_has_cuda", lambda: gpu)
    if value is None:
        monkeypatch.delenv("VIRHEO_ARCH", raising=False)
    else:
        monkeypatch.setenv("VIRHEO_ARCH", value)
    assert runtime.engine_name() == engine
    assert runtime.engine_for("f64") == ("taichi-cpu" if engine == "native" else engine)


@pytest.mark.parametrize("value, engine", [("cpu", "taichi-cpu"), ("auto", "taichi-cpu"),
                                           ("taichi-cpu", "taichi-cpu")])
def test_without_the_extension_cpu_and_auto_fall_back_to_taichi(value, engine, hidden_native, monkeypatch, capsys):
    monkeypatch.setattr(runtime, "_has_cuda", lambda: False)
    monkeypatch.setenv("VIRHEO_ARCH", value)
    assert runtime.engine_name() == engine
    assert capsys.readouterr().err == ""  # choosing says nothing; the first simulation does


@pytest.mark.parametrize("value, gpu, needle", [
    ("gpu", True, "VIRHEO_ARCH must be one of auto, cpu, native, taichi-cpu, cuda; got 'gpu'"),
    ("x64", False, "got 'x64'"),
    ("cuda", False, "VIRHEO_ARCH=cuda but no CUDA device is available"),
    ("native", False, "VIRHEO_ARCH=native but the native engine is not available: mpm._native is not built (test)"),
])
def test_unknown_or_unavailable_engines_are_one_line_value_errors(value, gpu, needle, hidden_native, monkeypatch):
    monkeypatch.setattr(runtime, "_has_cuda", lambda: gpu)
    monkeypatch.setenv("VIRHEO_ARCH", value)
    for ask in (runtime.engine_name, runtime.engine_for):
        with pytest.raises(ValueError) as e:
            ask()
        assert needle in str(e.value) and "\n" not in str(e.value)


def test_the_fallback_is_said_once_at_the_first_simulation(hidden_native, monkeypatch, capsys):
    """``cpu`` without the extension runs on taichi-cpu and says why in one line on stderr, once per process."""
    from mpm import solver

    monkeypatch.setattr(runtime, "_has_cuda", lambda: False)
    monkeypatch.setenv("VIRHEO_ARCH", "cpu")
    sims = [solver.simulate(NS(eta=1.0, n=1.0, sigma_y=0.0), NS(width_mm=20, height_mm=20), density=1000.0,
                            cell_mm=5.0, dim=2) for _ in range(2)]
    assert [s.stats["arch"] for s in sims] == ["taichi-cpu", "taichi-cpu"]
    err = capsys.readouterr().err
    assert err == ("virheometry: the native engine is not built (mpm._native is not built (test)); "
                   "running on Taichi's CPU path\n")


def test_f64_asked_of_the_native_engine_runs_on_taichi_and_says_so_once(built_native, monkeypatch, capsys):
    monkeypatch.setenv("VIRHEO_ARCH", "native")
    assert [runtime.engine_for("f64", say=True) for _ in range(3)] == ["taichi-cpu"] * 3
    assert runtime.engine_for("f32", say=True) == "native"
    assert capsys.readouterr().err == "virheometry: the native engine runs f32; f64 runs on taichi-cpu\n"
    with pytest.raises(ValueError, match="precision must be f32 or f64"):
        runtime.engine_for("f16")


def test_taichi_architecture_follows_the_engine(monkeypatch):
    import taichi as ti

    monkeypatch.setattr(runtime, "_has_cuda", lambda: False)
    for value in ("taichi-cpu", "cpu", "native", "auto"):
        monkeypatch.setenv("VIRHEO_ARCH", value)
        assert runtime.arch() == ti.cpu
    monkeypatch.setattr(runtime, "_has_cuda", lambda: True)
    for value in ("cuda", "auto"):
        monkeypatch.setenv("VIRHEO_ARCH", value)
        assert runtime.arch() == ti.cuda


def test_choosing_an_engine_neither_imports_nor_starts_taichi():
    code = ("import sys, os\n"
            "os.environ['VIRHEO_ARCH'] = 'cpu'\n"
            "from mpm import runtime, batch\n"
            "runtime.engine_name()\n"
            "import mpm.native_engine\n"
            "assert 'taichi' not in sys.modules, 'taichi imported'\n")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120, cwd=REPO)


@pytest.mark.parametrize("value, needle", [("bogus", "VIRHEO_ARCH must be one of"),
                                           ("native", "the native engine is not available")])
def test_the_cli_refuses_a_bad_engine_in_one_line_before_writing(value, needle, hidden_native, monkeypatch, capsys,
                                                                 tmp_path):
    monkeypatch.setenv("VIRHEO_ARCH", value)
    out = tmp_path / "o"
    for argv in (["simulate", "--material", "1,0.5,2", "--setup", "30x20", "--out", str(out)],
                 ["demo", "--out", str(out), "--workers", "0"]):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and needle in err and "Traceback" not in err
        assert not out.exists()


def test_the_cli_refuses_a_bad_engine_in_a_fresh_process(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "studies.cli", "simulate", "--material", "1,0.5,2", "--setup",
                           "30x20", "--out", str(tmp_path / "o")], capture_output=True, text=True, timeout=120,
                          cwd=REPO, env={**os.environ, "VIRHEO_ARCH": "taichi"})
    assert proc.returncode == 2 and proc.stderr.startswith("virheo simulate: error: VIRHEO_ARCH must be one of")
    assert len(proc.stderr.strip().splitlines()) == 1
