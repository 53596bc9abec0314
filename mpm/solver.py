"""Explicit MPM for the dam-break (Taichi): uGIMP weights, APIC-like transfers, HB return mapping.

One time step follows REFERENCE_SPEC 2.5 (the authors' order):

1. P2G: grid momentum += w m (v + C (x_i - x_p)) - dt V_p tau grad w, grid mass += w m, with the
   Kirchhoff stress tau of ``mpm.constitutive.kirchhoff_stress`` and the initial particle volume V_p.
2. Grid: p += dt m g; nodes inside any wall box get p = 0 (sticking); v_i = p / m.
3. G2P: v_p = sum w v_i (PIC), C_p = grad v = sum v_i (x) grad w (the affine matrix is the grid velocity
   gradient from the uGIMP weight gradients, as the reference does -- not Jiang et al.'s B D^-1), elastic
   predictor b* = F b F^T with F = I + dt C (eq. 52), plastic correction ``return_mapping`` (eq. 57);
   particles inside a wall box get v = 0, C = 0 (frozen, they still carry stress); advection x += dt v.

Discretisation: particles on a cell-centred lattice (no jitter), ``PARTICLES_PER_CELL`` per cell per axis
(default 1; the reference uses 2) with uGIMP half-length l_p = spacing / 2; default cell width
``DEFAULT_CELL_MM`` = 1.5 mm. Both chosen by a convergence study (docs/performance.md, "Forward model"):
for equal cost a finer grid with one particle per cell is closer to the finest one-particle run than the
reference's two per axis on a coarser grid. Thin films of runny material on the sticking floor converge with
neither: their runout keeps falling as the grid resolves the no-slip boundary layer, and one particle per cell flows 15-30 % less than two and depends
on the time step; only the paper's discretisation (``simulate(..., cell_mm=1.26, ppc=2)``) reproduces the
paper's fits of such materials (docs/results.md, "Cause: the discretisation of a thin film").
Grid nodes lie on the wall planes (x = 0, y = 0, z = 0 are nodes) unless ``GRID_SHIFT`` moves them.

Speed on a small CPU:

* The grid is a flat, dense window over the particles' stencil bounding box, recomputed every step (its
  origin and extents live on the device; nothing syncs with Python inside a step). A 30 x 20 mm flow
  touches a few ten thousand nodes; the reference's fixed 3.4M-node grid is never built. The buffer grows
  geometrically when the flow spreads and is reused across calls.
* On the CPU, P2G runs one task per thread over a contiguous slice of the particles, each scattering into
  its own copy of the grid with plain (non-atomic) adds; the grid update sums the copies. G2P likewise
  keeps bounding box and maximum speed per task. No atomics in any particle loop. On CUDA the same kernel
  uses atomics and one grid copy.
* A whole step is one kernel launch; all fields are Taichi ndarrays sized to a capacity that only grows,
  so repeated ``simulate`` calls neither recompile (one compilation per process per dim, precision and
  flow rule; Taichi's offline cache serves later processes) nor allocate per call.
* Time step from the CFL condition dt = CFL dx / (c + |v|max), c = sqrt((kappa + 4/3 mu) / rho) the
  elastic wave speed, re-evaluated 4 times per frame interval and adjusted so that frames land exactly at
  t = k/24 s.

2D (``dim=2``): plane strain in the x-y section at mid-depth: 2D grid and particles (per unit depth),
3x3 b_e with a zero out-of-plane velocity gradient; floor and back wall only. Its frames are extruded
over the 3D particle layers in z so that silhouettes compare with 3D ones.

Precision: ``"f32"`` (default) or ``"f64"`` sets Taichi's default float; Taichi holds one default per
process, so switching precision re-initialises Taichi (and recompiles) -- keep one per process.
Arch: ``$VIRHEO_ARCH`` = auto (default: CUDA when available, else CPU) | cpu | cuda; CPU threads
``$VIRHEO_THREADS`` (default: all cores; use 1 per process when running several processes).
Not thread-safe: one simulation at a time per process (batch evaluation uses processes).
"""
import math
import os
import time
from dataclasses import dataclass, field

import numpy as np
import taichi as ti
from taichi.lang import impl

from mpm import scene as sc

DEFAULT_CELL_MM = 1.5  # with one particle per cell per axis; chosen by measurement: docs/performance.md
CFL = 0.5  # dt = CFL * dx / (c + |v|max); 0.6-0.65 still stable, 0.8 blows up (docs/performance.md)
PARTICLES_PER_CELL = 1  # per axis (the reference uses 2; see docs/performance.md)
GRID_SHIFT = (0.0, 0.0, 0.0)  # per axis: grid nodes sit at (I + GRID_SHIFT) * dx
SUBSTEPS_PER_FRAME = 4  # the time step is re-evaluated this often per frame interval
FLOW_RULES = ("paper", "yue2015")
PRECISIONS = ("f32", "f64")

# layout of the small int32 control array ``win``
_OX, _NX, _COUNT, _OVERFLOW, _ERROR, _DONE, _NEED = 0, 3, 6, 7, 8, 9, 10
_HIDDEN, _PLASTIC, _FROZEN = 1, 2, 4  # particle flag bits
_ERRORS = {1: "a particle position became NaN", 2: "particles left the region the flow can reach"}


class SimulationError(RuntimeError):
    """The simulation blew up (NaN, runaway speed, particles leaving the reachable region)."""


@dataclass
class Simulation:
    """Result of :func:`simulate`. Positions in metres in the reference frame (see ``mpm.scene``)."""

    times: np.ndarray  # (8,) s, t_k = k/24
    frames: list  # 8 arrays (N_k, 3) of the visible particles' positions
    silhouettes: np.ndarray | None  # (8, H, W) bool, True = material, when a camera was given
    front_m: np.ndarray  # (8,) runout: max x of the moving (non-frozen) material
    stats: dict = field(default_factory=dict)


# ---------------------------------------------------------------------------------------------------
# Taichi runtime and kernels (compiled once per process per dim, precision and flow rule)

_ENGINES: dict = {}


def _arch():
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


def _threads() -> int:
    return max(1, int(os.environ.get("VIRHEO_THREADS", os.cpu_count() or 1)))


def _ensure_taichi(precision: str):
    """Initialise Taichi for ``precision`` unless it already runs with it; returns the Program."""
    fp = ti.f32 if precision == "f32" else ti.f64
    rt = impl.get_runtime()
    if rt.prog is not None and rt.default_fp == fp:
        return rt.prog
    if rt.prog is not None:
        ti.reset()
    ti.init(arch=_arch(), default_fp=fp, offline_cache=True, cpu_max_num_threads=_threads(),
            log_level=ti.WARN)
    return impl.get_runtime().prog


class _Engine:
    """Compiled step kernel and reusable device buffers for one (dim, precision) in one Taichi program."""

    def __init__(self, dim: int, precision: str, prog):
        self.dim, self.precision, self.prog = dim, precision, prog
        self.dtype = ti.f32 if precision == "f32" else ti.f64
        self.np_dtype = np.float32 if precision == "f32" else np.float64
        # GPU: atomics and one grid copy; $VIRHEO_MPM_ATOMIC=1 forces that path on the CPU (for testing)
        self.atomic = impl.current_cfg().arch != ti.cpu or os.environ.get("VIRHEO_MPM_ATOMIC") == "1"
        self.tasks = 1 if self.atomic else _threads()
        self.step, self.init_bbox, self.grid_mass = _build_kernels(dim, self.tasks, self.atomic)
        self.cap_p = 0
        self.cap_g = 0
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
        self.flags = ti.ndarray(ti.i32, cap)
        self.cap_p = cap

    def ensure_grid(self, nodes: int) -> None:
        if nodes <= self.cap_g:
            return
        cap = max(nodes, int(1.5 * self.cap_g), 4096)
        self.grid = ti.Vector.ndarray(self.dim + 1, self.dtype, self.tasks * cap)
        self.grid.fill(0)
        self.cap_g = cap


def _engine(dim: int, precision: str) -> _Engine:
    prog = _ensure_taichi(precision)
    key = (dim, precision)
    eng = _ENGINES.get(key)
    if eng is None or eng.prog is not prog:
        if eng is not None:  # Taichi was re-initialised: every engine of the old program is void
            _ENGINES.clear()
        eng = _ENGINES[key] = _Engine(dim, precision, prog)
    return eng


def _build_kernels(dim: int, tasks: int, atomic: bool):
    """The step kernel for ``dim`` with ``tasks`` grid copies (CPU) or atomics (GPU)."""
    from mpm.constitutive import kirchhoff_stress, return_mapping

    D = dim
    nd = ti.types.ndarray()

    @ti.func
    def ugimp(X, l):
        """uGIMP weights per axis (REFERENCE_SPEC 2.4) for stencil nodes base + 0..2.

        X: position in cell units relative to the window origin, l = l_p / dx <= 1/2 (1/4 with two
        particles per cell). Returns base, fx = X - base in [l, 1 + l), the normalised 1D factors
        N = S / (2 l_p) (they sum to 1) and dN/dx_p in cell units. With r = fx - o = (x_p - x_i)/dx:
        N = 1 - (l^2 + r^2) / (2 l) for |r| < l, 1 - |r| for |r| < 1 - l, (1 + l - |r|)^2 / (4 l) for
        |r| < 1 + l, else 0; node 0 sees r in [l, 1 + l), node 1 [l - 1, l), node 2 [l - 2, l - 1).
        """
        base = ti.floor(X - l, ti.i32)
        fx = X - base
        q = 0.25 / l
        w = ti.Matrix.zero(float, D, 3)
        dw = ti.Matrix.zero(float, D, 3)
        for a in ti.static(range(D)):
            r0 = fx[a]  # node 0
            if r0 < 1.0 - l:
                w[a, 0] = 1.0 - r0
                dw[a, 0] = -1.0
            else:
                e0 = 1.0 + l - r0
                w[a, 0] = q * e0 * e0
                dw[a, 0] = -2.0 * q * e0
            r1 = fx[a] - 1.0  # node 1
            if r1 > -l:
                w[a, 1] = 1.0 - 2.0 * q * (l * l + r1 * r1)
                dw[a, 1] = -4.0 * q * r1
            else:
                w[a, 1] = 1.0 + r1
                dw[a, 1] = 1.0
            e2 = l - 1.0 + fx[a]  # node 2: 1 + l - |r2|
            if e2 > 0.0:
                w[a, 2] = q * e2 * e2
                dw[a, 2] = 2.0 * q * e2
        return base, fx, w, dw

    @ti.func
    def window(win: ti.template(), shift):
        """Origin (in cells: node (0,..) of the window sits at origin * dx) and flat-index strides."""
        origin = ti.Vector([win[_OX + a] + shift[a] for a in ti.static(range(D))])
        stride = ti.Vector.one(ti.i32, D)
        for a in ti.static(range(D - 2, -1, -1)):
            stride[a] = stride[a + 1] * win[_NX + a + 1]
        return origin, stride

    @ti.func
    def stencil(w, dw, off: ti.template()):
        """Weight and gradient (cell units) of stencil node ``off``: tensor products of the 1D factors."""
        wt = 1.0
        grad = ti.Vector.one(float, D)
        for a in ti.static(range(D)):
            wt *= w[a, off[a]]
            for b in ti.static(range(D)):
                grad[b] *= dw[a, off[a]] if a == b else w[a, off[a]]
        return wt, grad

    @ti.func
    def in_box(boxes: ti.template(), b: ti.template(), pos, z):
        """(inside x and y ranges, inside z range) of static box b, inclusive bounds."""
        in_xy = (boxes[b, 0, 0] <= pos[0] <= boxes[b, 1, 0]) and (boxes[b, 0, 1] <= pos[1] <= boxes[b, 1, 1])
        in_z = boxes[b, 0, 2] <= z <= boxes[b, 1, 2]
        return in_xy, in_z

    @ti.func
    def zcoord(pos, zmid):
        z = zmid
        if ti.static(D == 3):
            z = pos[2]
        return z

    @ti.func
    def block(m):
        """Upper-left D x D block of a 3x3 matrix."""
        r = ti.Matrix.zero(float, D, D)
        for i, j in ti.static(ti.ndrange(D, D)):
            r[i, j] = m[i, j]
        return r

    @ti.func
    def embed(m):
        """D x D velocity gradient as 3x3 (plane strain: zero out-of-plane rows and columns)."""
        r = ti.Matrix.zero(float, 3, 3)
        for i, j in ti.static(ti.ndrange(D, D)):
            r[i, j] = m[i, j]
        return r

    @ti.func
    def p2g_particle(p, t, x: ti.template(), v: ti.template(), C: ti.template(), be: ti.template(),
                     grid: ti.template(), origin, stride, capg, dt, inv_dx, dx, mp, vol, kappa, mu, lh):
        X = x[p] * inv_dx - origin
        base, fx, w, dw = ugimp(X, lh)
        tau = kirchhoff_stress(be[p], kappa, mu)
        S = (-dt * vol * inv_dx) * block(tau)  # force -V_p tau grad w (REFERENCE_SPEC 2.5; grad in cells)
        mv = mp * v[p]
        mC = (mp * dx) * C[p]
        node0 = base.dot(stride)
        if ti.static(not atomic):
            node0 += t * capg
        for off in ti.static(ti.grouped(ti.ndrange(*([3] * D)))):
            wt, grad = stencil(w, dw, off)
            mom = wt * (mv + mC @ (off - fx)) + S @ grad  # APIC: m (v + C (x_i - x_p))
            contrib = ti.Vector.zero(float, D + 1)
            for a in ti.static(range(D)):
                contrib[a] = mom[a]
            contrib[D] = wt * mp
            k = node0 + off.dot(stride)
            if ti.static(atomic):
                grid[k] += contrib
            else:
                grid[k] = grid[k] + contrib  # own grid copy per task: no atomics needed

    @ti.func
    def g2p_particle(p, x: ti.template(), v: ti.template(), C: ti.template(), be: ti.template(),
                     flags: ti.template(), grid: ti.template(), boxes: ti.template(), origin, stride, dt,
                     inv_dx, mu, eta, n, sy, zmid, lh, yue: ti.template()):
        xp = x[p]
        X = xp * inv_dx - origin
        base, fx, w, dw = ugimp(X, lh)
        vp = ti.Vector.zero(float, D)
        B = ti.Matrix.zero(float, D, D)
        node0 = base.dot(stride)
        for off in ti.static(ti.grouped(ti.ndrange(*([3] * D)))):
            wt, grad = stencil(w, dw, off)
            g = grid[node0 + off.dot(stride)]
            gv = ti.Vector([g[a] for a in ti.static(range(D))])
            vp += wt * gv
            B += gv.outer_product(grad)
        B *= inv_dx  # C_p = grad v (REFERENCE_SPEC 2.5 step 4)
        b_old = be[p]
        F = ti.Matrix.identity(float, 3) + dt * embed(B)
        b_trial = F @ b_old @ F.transpose()  # elastic predictor, eq. 52 in its F b F^T form
        b_new = return_mapping(b_trial, b_old, mu, eta, n, sy, dt, yue)  # eq. 57; identity when elastic
        f = flags[p]
        if (b_new != b_trial).any():
            f |= _PLASTIC
        be[p] = b_new
        # walls, tested at the pre-advection position (REFERENCE_SPEC 2.5, 2.7)
        z = zcoord(xp, zmid)
        frozen = False
        hidden = (f & _HIDDEN) != 0
        for b in ti.static(range(4)):
            in_xy, in_z = in_box(boxes, b, xp, z)
            if in_xy:
                hidden = in_z  # the last box containing (x, y) decides visibility
                if in_z:
                    frozen = True
        f &= ~(_HIDDEN | _FROZEN)
        if hidden:
            f |= _HIDDEN
        if frozen:
            f |= _FROZEN
            vp = ti.Vector.zero(float, D)
            B = ti.Matrix.zero(float, D, D)
        flags[p] = f
        xn = xp + dt * vp
        x[p] = xn
        v[p] = vp
        C[p] = B
        return xn, vp

    @ti.kernel
    def step(x: nd, v: nd, C: nd, be: nd, flags: nd, grid: nd, win: nd, acc: nd, accf: nd, boxes: nd,
             lim: nd, n: ti.i32, capg: ti.i32, dt: float, dx: float, mp: float, vol: float, kappa: float,
             mu: float, eta: float, nn: float, sy: float, gravity: float, zmid: float,
             shift: ti.types.vector(D, float),
             lh: float, yue: ti.template()):
        inv_dx = 1.0 / dx
        # 1. clear the previous window in every grid copy
        for i in range(win[_COUNT]):
            for t in ti.static(range(tasks)):
                grid[t * capg + i] = ti.Vector.zero(float, D + 1)
        # 2. the new window: stencil bounding box of the particles (from the last G2P)
        for _ in range(1):
            if win[_ERROR] == 0:
                lo = ti.Vector([acc[0, a] for a in ti.static(range(D))])
                hi = ti.Vector([acc[0, 3 + a] for a in ti.static(range(D))])
                for t in range(1, tasks):
                    for a in ti.static(range(D)):
                        lo[a] = ti.min(lo[a], acc[t, a])
                        hi[a] = ti.max(hi[a], acc[t, 3 + a])
                count = 1
                for a in ti.static(range(D)):
                    if lo[a] < lim[a] or hi[a] > lim[3 + a]:
                        win[_ERROR] = 2
                    count *= hi[a] + 3 - lo[a]
                if win[_ERROR] == 0:
                    if count > capg:
                        win[_OVERFLOW] = 1
                        win[_NEED] = count
                        win[_COUNT] = 0
                    else:
                        for a in ti.static(range(D)):
                            win[_OX + a] = lo[a]
                            win[_NX + a] = hi[a] + 3 - lo[a]
                        win[_COUNT] = count
                        if ti.static(atomic):  # G2P accumulates the next box atomically
                            for a in ti.static(range(D)):
                                acc[0, a] = 2147483647
                                acc[0, 3 + a] = -2147483647
                            accf[0] = 0.0
        # 3. P2G
        if ti.static(atomic):
            for p in range(n):
                if win[_OVERFLOW] == 0 and win[_ERROR] == 0:
                    origin, stride = window(win, shift)
                    p2g_particle(p, 0, x, v, C, be, grid, origin, stride, capg, dt, inv_dx, dx, mp, vol, kappa, mu,
                                 lh)
        else:
            for t in range(tasks):
                if win[_OVERFLOW] == 0 and win[_ERROR] == 0:
                    origin, stride = window(win, shift)
                    for p in range(t * n // tasks, (t + 1) * n // tasks):
                        p2g_particle(p, t, x, v, C, be, grid, origin, stride, capg, dt, inv_dx, dx, mp, vol, kappa, mu,
                                 lh)
        # 4. grid update: gravity, sticking walls, velocity (copy 0 holds (v, m) afterwards)
        for i in range(win[_COUNT]):
            g = grid[i]
            for t in ti.static(range(1, tasks)):
                g += grid[t * capg + i]
            m = g[D]
            if m > 0:
                local = ti.Vector.zero(ti.i32, D)
                rest = i
                for a in ti.static(range(D - 1, -1, -1)):
                    local[a] = rest % win[_NX + a]
                    rest = rest // win[_NX + a]
                pos = ti.Vector([(local[a] + win[_OX + a] + shift[a]) * dx for a in ti.static(range(D))])
                mom = ti.Vector([g[a] for a in ti.static(range(D))])
                mom[1] -= dt * m * gravity
                z = zcoord(pos, zmid)
                for b in ti.static(range(4)):
                    in_xy, in_z = in_box(boxes, b, pos, z)
                    if in_xy and in_z:
                        mom = ti.Vector.zero(float, D)  # sticking wall
                vel = mom / m
                for a in ti.static(range(D)):
                    g[a] = vel[a]
            grid[i] = g
        # 5. G2P, constitutive update, walls, advection; bounding box and speed for the next step
        if ti.static(atomic):
            for p in range(n):
                if win[_OVERFLOW] == 0 and win[_ERROR] == 0:
                    origin, stride = window(win, shift)
                    xn, vp = g2p_particle(p, x, v, C, be, flags, grid, boxes, origin, stride, dt, inv_dx, mu, eta, nn,
                                          sy, zmid, lh, yue)
                    if (xn != xn).any():
                        win[_ERROR] = 1
                    base = ti.floor(xn * inv_dx - shift - lh, ti.i32)
                    for a in ti.static(range(D)):
                        ti.atomic_min(acc[0, a], base[a])
                        ti.atomic_max(acc[0, 3 + a], base[a])
                    ti.atomic_max(accf[0], vp.norm())
        else:
            for t in range(tasks):
                if win[_OVERFLOW] == 0 and win[_ERROR] == 0:
                    lo = ti.Vector([2147483647] * D)
                    hi = ti.Vector([-2147483647] * D)
                    vmax2 = 0.0
                    bad = 0
                    origin, stride = window(win, shift)
                    for p in range(t * n // tasks, (t + 1) * n // tasks):
                        xn, vp = g2p_particle(p, x, v, C, be, flags, grid, boxes, origin, stride, dt, inv_dx, mu, eta,
                                              nn, sy, zmid, lh, yue)
                        if (xn != xn).any():
                            bad = 1
                        base = ti.floor(xn * inv_dx - shift - lh, ti.i32)
                        lo = ti.min(lo, base)
                        hi = ti.max(hi, base)
                        vmax2 = ti.max(vmax2, vp.norm_sqr())
                    for a in ti.static(range(D)):
                        acc[t, a] = lo[a]
                        acc[t, 3 + a] = hi[a]
                    accf[t] = ti.sqrt(vmax2)
                    if bad:
                        win[_ERROR] = 1
        # 6. count the completed step
        for _ in range(1):
            if win[_OVERFLOW] == 0 and win[_ERROR] == 0:
                win[_DONE] += 1

    @ti.kernel
    def init_bbox(x: nd, win: nd, acc: nd, accf: nd, n: ti.i32, dx: float, shift: ti.types.vector(D, float),
                  lh: float):
        for t in range(tasks):
            lo = ti.Vector([2147483647] * D)
            hi = ti.Vector([-2147483647] * D)
            for p in range(t * n // tasks, (t + 1) * n // tasks):
                base = ti.floor(x[p] / dx - shift - lh, ti.i32)
                lo = ti.min(lo, base)
                hi = ti.max(hi, base)
            for a in ti.static(range(D)):
                acc[t, a] = lo[a]
                acc[t, 3 + a] = hi[a]
            accf[t] = 0.0

    @ti.kernel
    def grid_mass(grid: nd, win: nd, out: nd):
        out[0] = 0.0
        for i in range(win[_COUNT]):
            out[0] += grid[i][D]

    return step, init_bbox, grid_mass


# ---------------------------------------------------------------------------------------------------
# public entry point


def _check_options(dim, flow_rule, precision, image_size):
    if dim not in (2, 3):
        raise ValueError(f"dim must be 2 or 3, got {dim!r}")
    if flow_rule not in FLOW_RULES:
        raise ValueError(f"flow_rule must be one of {', '.join(FLOW_RULES)}, got {flow_rule!r}")
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be f32 or f64, got {precision!r}")
    from mpm.camera import image_size_of

    return image_size_of(image_size)


def simulate(material, setup, *, density, cell_mm=None, dim=3, flow_rule="paper", camera=None,
             depth_mm=40.0, image_size=(960, 540), precision="f32", ppc=None, progress=None) -> Simulation:
    """Run the dam-break for 1/3 s and return 8 frames (t = k/24 s) of visible particle positions.

    material: any object with .eta (Pa s^n), .n, .sigma_y (Pa); setup: any object with .width_mm,
    .height_mm (20-70 mm); density in kg/m^3; cell_mm: grid cell width (default ``DEFAULT_CELL_MM``);
    ppc: particles per cell per axis (default ``PARTICLES_PER_CELL``; the paper's discretisation is
    cell_mm=1.26, ppc=2); depth_mm: distance between the side walls;
    camera: a ``mpm.camera.Camera`` to also render silhouettes at image_size = (width, height);
    precision: "f32" or "f64"; flow_rule: "paper" or "yue2015"; progress: optional callable
    ``progress(frames_done, 8)`` called after each simulated frame.
    Raises ValueError for bad input, SimulationError when the run blows up.
    """
    eta, n, sigma_y = sc.check_material(material)
    size = _check_options(dim, flow_rule, precision, image_size)
    scene = sc.DamBreak.build(setup, density=density, cell_mm=DEFAULT_CELL_MM if cell_mm is None else cell_mm,
                              depth_mm=depth_mm, dim=dim, ppc=PARTICLES_PER_CELL if ppc is None else ppc)
    t_start, cpu_start = time.perf_counter(), time.process_time()
    eng = _engine(dim, precision)
    t_ready = time.perf_counter()
    run = _Run(eng, scene, eta, n, sigma_y, flow_rule == "yue2015")
    frames3, front, stats = run.execute(progress)
    t_sim = time.perf_counter()
    silhouettes = None
    if camera is not None:
        from mpm.silhouette import render

        silhouettes = np.stack([render(f, camera, image_size=size, spacing_m=scene.spacing_m) for f in frames3])
    t_end = time.perf_counter()
    stats.update(
        setup_s=t_ready - t_start, sim_s=t_sim - t_ready, render_s=t_end - t_sim, wall_s=t_end - t_start,
        cpu_s=time.process_time() - cpu_start,
        cell_mm=scene.cell_m * 1e3, ppc=scene.ppc, dim=dim, precision=precision, flow_rule=flow_rule,
        arch=str(impl.current_cfg().arch).split(".")[-1], tasks=eng.tasks,
    )
    stats["particle_steps_per_s"] = stats["n_particles"] * stats["steps"] / max(stats["sim_s"], 1e-9)
    return Simulation(sc.frame_times(), frames3, silhouettes, front, stats)


class _Run:
    """One simulation on an engine's buffers."""

    def __init__(self, eng: _Engine, scene: sc.DamBreak, eta, n, sigma_y, yue: bool):
        self.eng, self.scene = eng, scene
        self.eta, self.n, self.sigma_y, self.yue = eta, n, sigma_y, yue
        self.shift = ti.Vector([float(v) for v in GRID_SHIFT[:scene.dim]])  # kernel argument, built once
        pos = scene.particles()
        self.count = len(pos)
        eng.ensure_particles(self.count)
        cap, d, dt = eng.cap_p, scene.dim, eng.np_dtype
        _, hidden = scene.frozen_and_hidden(pos)
        x = np.zeros((cap, d), dt)
        x[: self.count] = pos
        be = np.zeros((cap, 3, 3), dt)
        be[:] = np.eye(3)
        flags = np.zeros(cap, np.int32)
        flags[: self.count] = np.where(hidden, _HIDDEN, 0)
        eng.x.from_numpy(x)
        eng.v.fill(0)
        eng.C.fill(0)
        eng.be.from_numpy(be)
        eng.flags.from_numpy(flags)
        eng.boxes.from_numpy(scene.boxes().astype(dt))
        lo, hi = scene.reach()
        lim = np.zeros(6, np.int32)
        lim[:d] = np.floor(lo / scene.cell_m) - 1
        lim[3:3 + d] = np.ceil(hi / scene.cell_m) + 1
        eng.lim.from_numpy(lim)
        win = np.zeros(16, np.int32)
        eng.win.from_numpy(win)
        eng.init_bbox(eng.x, eng.win, eng.acc, eng.accf, self.count, scene.cell_m, self.shift,
                      scene.half_length_m / scene.cell_m)
        first = eng.acc.to_numpy()
        span = first[:, 3:3 + d].max(0) + 3 - first[:, :d].min(0)
        eng.ensure_grid(int(np.prod(span)) * 2)
        eng.grid.fill(0)  # the previous run leaves its last window behind

    def _launch(self, steps: int, dt: float) -> None:
        eng, s = self.eng, self.scene
        for _ in range(steps):
            eng.step(eng.x, eng.v, eng.C, eng.be, eng.flags, eng.grid, eng.win, eng.acc, eng.accf, eng.boxes,
                     eng.lim, self.count, eng.cap_g, dt, s.cell_m, s.particle_mass, s.particle_volume, s.kappa,
                     s.mu, self.eta, self.n, self.sigma_y, s.gravity, s.plane_z_m, self.shift,
                     s.half_length_m / s.cell_m, self.yue)

    def _advance(self, steps: int, dt: float) -> None:
        """Run ``steps`` steps of size dt, growing the grid whenever the window overflows it."""
        eng = self.eng
        done0 = int(eng.win.to_numpy()[_DONE])
        target = done0 + steps
        todo = steps
        while todo > 0:
            self._launch(todo, dt)
            win = eng.win.to_numpy()
            if win[_ERROR]:
                raise SimulationError(f"simulation blew up: {_ERRORS.get(int(win[_ERROR]), 'unknown error')}")
            if win[_OVERFLOW]:
                eng.ensure_grid(int(win[_NEED]) * 3 // 2)
                win[_OVERFLOW] = 0
                win[_COUNT] = 0  # the new buffer is zero: nothing to clear
                eng.win.from_numpy(win)
            todo = target - int(win[_DONE])

    def execute(self, progress=None):
        eng, scene = self.eng, self.scene
        c = scene.wave_speed
        t = 0.0
        steps = 0
        dts = []
        vmax_seen = 0.0
        frames3, front, mean_j, mass_err, visible = [], [], [], [], []
        m_total = self.count * scene.particle_mass
        for k, t_frame in enumerate(sc.frame_times()):
            t_prev = k / sc.FPS
            for sub in range(SUBSTEPS_PER_FRAME):
                t_target = t_prev + (sub + 1) * (t_frame - t_prev) / SUBSTEPS_PER_FRAME
                vmax = float(eng.accf.to_numpy().max())
                if not math.isfinite(vmax) or vmax > scene.speed_limit:
                    raise SimulationError(f"simulation blew up: speed {vmax:.3g} m/s exceeds "
                                          f"{scene.speed_limit:.3g} m/s")
                vmax_seen = max(vmax_seen, vmax)
                # CFL: elastic wave speed plus particle speed, with room for a chunk of free-fall
                dt_cfl = CFL * scene.cell_m / (c + vmax + scene.gravity * (t_target - t))
                m = max(1, math.ceil((t_target - t) / dt_cfl - 1e-9))
                dt = (t_target - t) / m
                self._advance(m, dt)
                t = t_target
                steps += m
                dts.append(dt)
            x, hidden, frozen, jm = self._snapshot()
            frames3.append(self._visible_positions(x, hidden))
            visible.append(int((~hidden).sum()))
            moving = ~frozen
            front.append(float(x[moving, 0].max()) if moving.any() else 0.0)
            mean_j.append(jm)
            eng.grid_mass(eng.grid, eng.win, eng.out)
            mass_err.append(abs(float(eng.out.to_numpy()[0]) - m_total) / m_total)
            if progress is not None:
                progress(k + 1, sc.N_FRAMES)
        flags = eng.flags.to_numpy()[: self.count]
        stats = dict(
            n_particles=self.count, steps=steps, dt_min=float(min(dts)), dt_max=float(max(dts)), max_speed=float(vmax_seen),
            plastic_count=int(((flags & _PLASTIC) != 0).sum()), mean_J=mean_j, mass_kg=m_total,
            grid_mass_rel_err=max(mass_err), n_visible=visible, wave_speed=c,
            spacing_m=scene.spacing_m, grid_capacity=eng.cap_g, frozen_count=int(((flags & _FROZEN) != 0).sum()),
        )
        return frames3, np.array(front), stats

    def _snapshot(self):
        eng, n = self.eng, self.count
        x = eng.x.to_numpy()[:n].astype(np.float64)
        flags = eng.flags.to_numpy()[:n]
        be = eng.be.to_numpy()[:n].astype(np.float64)
        frozen = (flags & _FROZEN) != 0
        moving = ~frozen
        j = np.sqrt(np.abs(np.linalg.det(be[moving]))) if moving.any() else np.ones(1)
        if not np.all(np.isfinite(x)):
            raise SimulationError("simulation blew up: a particle position became NaN")
        return x, (flags & _HIDDEN) != 0, frozen, float(j.mean())

    def _visible_positions(self, x, hidden) -> np.ndarray:
        p = x[~hidden]
        if self.scene.dim == 3:
            return p
        # plane strain: extrude the section over the 3D particle layers in z (near-wall layer excluded)
        s = self.scene.spacing_m
        o = self.scene.overlap_m
        nz = int(math.ceil((self.scene.depth_m + 2 * o) / s - 1e-9))
        zs = -o + s * (np.arange(nz) + 0.5)
        zs = zs[zs <= self.scene.depth_m]
        out = np.empty((len(p) * len(zs), 3))
        out[:, :2] = np.repeat(p, len(zs), axis=0)
        out[:, 2] = np.tile(zs, len(p))
        return out
