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


# AMD's x86 families by (family, first model, last model): the core generation decides how 512-bit vector
# operations execute (Zen 4 splits each into two 256-bit halves; Zen 5 has full-width units), which moves the
# native engine's speed against Taichi's
AMD_CORES = ((25, 0x00, 0x0F, "Zen 3"), (25, 0x10, 0x1F, "Zen 4"), (25, 0x20, 0x2F, "Zen 3"),
             (25, 0x40, 0x4F, "Zen 3+"), (25, 0x50, 0x5F, "Zen 3"), (25, 0x60, 0x7F, "Zen 4"),
             (25, 0xA0, 0xAF, "Zen 4"), (26, 0x00, 0xFF, "Zen 5"))


def cpu_model() -> str:
    """The CPU's model name with its family, model and stepping (a virtual machine may show only a vendor
    name, e.g. "AMD EPYC"), and the core generation where it is an AMD one listed in AMD_CORES."""
    if not os.path.exists("/proc/cpuinfo"):
        return "unknown CPU"
    fields: dict[str, str] = {}
    with open("/proc/cpuinfo") as info:
        for line in info:
            if not line.strip():
                break  # the first processor's block
            key, _, value = line.partition(":")
            fields.setdefault(key.strip(), value.strip())
    name = fields.get("model name", "unknown CPU")
    try:
        family, model = int(fields["cpu family"]), int(fields["model"])
    except (KeyError, ValueError):
        return name
    core = next((c for f, lo, hi, c in AMD_CORES if fields.get("vendor_id") == "AuthenticAMD" and f == family
                 and lo <= model <= hi), None)
    ident = f"family {family} model {model} stepping {fields.get('stepping', '?')}"
    return f"{name} [{ident}: {core}]" if core else f"{name} [{ident}]"


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


def real_materials(slugs: dict, only=None):
    """(name, slug, manifest rows, footage folders) of each shared material in ``slugs`` (name -> slug), in setup
    order, those of ``only`` (slugs) alone when given."""
    from mpm.datasets import material_rows, real_world_dir

    for name, slug in slugs.items():
        if only and slug not in only:
            continue
        rows = material_rows(name)
        yield name, slug, rows, [str(real_world_dir() / r["folder"]) for r in rows]

