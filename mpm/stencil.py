"""The grid window and the uGIMP stencil of the MPM step kernel (``mpm.kernels``), as Taichi functions for one dim.

The grid is a dense window over the particles' stencil bounding box, recomputed every step, described by the
small int32 control array ``win`` (layout below); grid nodes sit at integer multiples of the cell width (the
wall planes x = 0, y = 0, z = 0 are nodes).
"""
import itertools

import taichi as ti

# layout of the control array ``win``
OX, NX, COUNT, OVERFLOW, ERROR, DONE, NEED = 0, 3, 6, 7, 8, 9, 10


def build_stencil(D: int):
    """(stencil_base, ugimp, window, lead_weights, column, LEADS) for dim ``D``; the stencil loops run over the
    leading axes (``LEADS``: the 3^(D-1) node offsets of all axes but the last), then along the last axis."""

    @ti.func
    def stencil_base(x, inv_dx, l):
        """Node 0 of a particle's stencil (absolute cell indices): floor(x / dx - l).

        The window's bounding box and the transfers both take it from here, with the same operands, so that
        they round alike: a particle whose x / dx - l lies on an integer (the initial lattices put many there)
        must not land one node outside the window it was given."""
        return ti.floor(x * inv_dx - l, ti.i32)

    @ti.func
    def ugimp(x, inv_dx, origin, l):
        """uGIMP weights per axis for stencil nodes base + 0..2.

        x: position (m), inv_dx = 1 / dx, origin: the window origin (cells), l = l_p / dx <= 1/2 (1/4 with two
        particles per cell). Returns base (relative to the window origin), fx in [l, 1 + l) (the position in
        cells from stencil node 0; rounding may put it a hair outside, where the weights below extend
        continuously), the normalised 1D factors
        N = S / (2 l_p) (they sum to 1) and dN/dx_p in cell units. With r = fx - o = (x_p - x_i)/dx:
        N = 1 - (l^2 + r^2) / (2 l) for |r| < l, 1 - |r| for |r| < 1 - l, (1 + l - |r|)^2 / (4 l) for
        |r| < 1 + l, else 0; node 0 sees r in [l, 1 + l), node 1 [l - 1, l), node 2 [l - 2, l - 1).
        """
        node0 = stencil_base(x, inv_dx, l)
        base = node0 - origin
        fx = x * inv_dx - node0
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
    def window(win: ti.template()):
        """Origin (in cells: node (0,..) of the window sits at origin * dx) and flat-index strides."""
        origin = ti.Vector([win[OX + a] for a in ti.static(range(D))])
        stride = ti.Vector.one(ti.i32, D)
        for a in ti.static(range(D - 2, -1, -1)):
            stride[a] = stride[a + 1] * win[NX + a + 1]
        return origin, stride

    L = D - 1  # the last axis: unit stride in the grid, innermost in the stencil loops
    LEADS = [tuple(int(i) for i in idx) for idx in itertools.product(range(3), repeat=L)]

    @ti.func
    def lead_weights(w, dw, lead: ti.template()):
        """Weight and gradient factors of the stencil nodes (lead, k), k = 0..2 along the last axis:
        weight = wl w[L, k]; gradient = (gl[0] w[L, k], .., gl[L-1] w[L, k], wl dw[L, k]) (cell units)."""
        wl = 1.0
        gl = ti.Vector.one(float, D)
        for a in ti.static(range(L)):
            wl *= w[a, lead[a]]
            for b in ti.static(range(L)):
                gl[b] *= dw[a, lead[a]] if a == b else w[a, lead[a]]
        return wl, gl

    @ti.func
    def column(m, a: ti.template()):
        return ti.Vector([m[r, a] for r in ti.static(range(D))])

    return stencil_base, ugimp, window, lead_weights, column, LEADS
