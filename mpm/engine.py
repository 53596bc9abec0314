"""The compiled step kernel of ``mpm.kernels`` with its reusable device buffers, one per (dim, precision) and
Taichi program."""
import os

import numpy as np
import taichi as ti

from mpm import runtime
from mpm.kernels import build_kernels

_ENGINES: dict = {}


class Engine:
    """Compiled step kernel and reusable device buffers for one (dim, precision) in one Taichi program."""

    def __init__(self, dim: int, precision: str, prog):
        self.dim, self.precision, self.prog = dim, precision, prog
        self.dtype = ti.f32 if precision == "f32" else ti.f64
        self.np_dtype = np.float32 if precision == "f32" else np.float64
        # GPU: atomics and one grid copy; $VIRHEO_MPM_ATOMIC=1 forces that path on the CPU (for testing)
        self.atomic = not runtime.on_cpu() or os.environ.get("VIRHEO_MPM_ATOMIC") == "1"
        self.tasks = 1 if self.atomic else runtime.threads()
        self.serial = self.tasks == 1 and not self.atomic  # all steps of a call in one launch
        (self.step, self.init_bbox, self.grid_mass, self.params, self.particle_arrays,
         self.grid_arrays) = build_kernels(dim, self.tasks, self.atomic)
        self.cap_p = 0
        self.cap_g = 0
        self.warm = False  # True once every kernel has run (compiled or loaded from the cache)
        self.win = ti.ndarray(ti.i32, 16)
        self.acc = ti.ndarray(ti.i32, (self.tasks, 6))
        self.accf = ti.ndarray(self.dtype, self.tasks)
        self.boxes = ti.ndarray(self.dtype, (4, 2, 3))
        self.lim = ti.ndarray(ti.i32, 6)
        self.out = ti.ndarray(self.dtype, 1)

    def ensure_particles(self, n: int) -> None:
        if n <= self.cap_p:
            return
        cap = max(n, int(1.25 * self.cap_p))
        d = self.dim
        self.x = ti.Vector.ndarray(d, self.dtype, cap)
        self.v = ti.Vector.ndarray(d, self.dtype, cap)
        self.C = ti.Matrix.ndarray(d, d, self.dtype, cap)
        self.be = ti.Matrix.ndarray(3, 3, self.dtype, cap)
        self.iso = ti.ndarray(self.dtype, cap)  # det(b_e)^(-1/3), kept by the return mapping
        self.loge = ti.ndarray(self.dtype, cap)  # log of last step's excess stress: the Newton solve's start
        self.flags = ti.ndarray(ti.i32, cap)
        self.cap_p = cap

    def ensure_grid(self, nodes: int) -> None:
        if nodes <= self.cap_g:
            return
        cap = max(nodes, int(1.5 * self.cap_g), 4096)
        self.grid = ti.Vector.ndarray(self.dim + 1, self.dtype, self.tasks * cap)
        self.zero(self.grid)
        self.cap_g = cap

    def particles(self):
        """The particle arrays as the step kernel's argument pack."""
        return self.particle_arrays(x=self.x, v=self.v, C=self.C, be=self.be, iso=self.iso, loge=self.loge,
                                    flags=self.flags)

    def grid_state(self):
        """The grid arrays as the step kernel's argument pack."""
        return self.grid_arrays(grid=self.grid, win=self.win, acc=self.acc, accf=self.accf)

    def zero(self, arr) -> None:
        """Set a vector or matrix ndarray to zero. (Taichi's ``fill`` on those instantiates a template kernel
        per call and keeps it: about 8 KB per call, which added up to 30 KB per simulation.)"""
        arr.from_numpy(np.zeros(tuple(arr.shape) + tuple(arr.element_type.shape()), self.np_dtype))


def engine(dim: int, precision: str) -> Engine:
    """The engine for ``dim`` and ``precision``, built once per Taichi program and then reused."""
    prog = runtime.ensure_taichi(precision)
    key = (dim, precision)
    eng = _ENGINES.get(key)
    if eng is None or eng.prog is not prog:
        if eng is not None:  # Taichi was re-initialised: every engine of the old program is void
            _ENGINES.clear()
        eng = _ENGINES[key] = Engine(dim, precision, prog)
    return eng
