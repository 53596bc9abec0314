"""Forward model: constitutive law, MPM dam-break, camera, silhouettes, video loss, experiments.

``simulate``, ``Simulation`` and ``SimulationError`` are loaded lazily, so that ``import mpm`` or
``import mpm.camera`` does not initialise Taichi.
"""
_LAZY = {"simulate": "mpm.solver", "Simulation": "mpm.solver", "SimulationError": "mpm.solver"}


def __getattr__(name):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'mpm' has no attribute {name!r}")


def __dir__():
    return sorted(list(globals()) + list(_LAZY))
