"""The walls of the dam-break box in the MPM step kernel (``mpm.kernels``), as Taichi functions for one dim: box
tests, and the tangential velocity of wall nodes under the Navier slip law."""
import taichi as ti

from mpm.stencil import NX

# walls (boxes of ``mpm.scene.DamBreak.boxes``, in that order): (normal axis, normal sign, face of the box
# that is the wall plane); in 2D only the floor and the back wall exist
WALL_NORMALS = ((1, 1, 1), (0, 1, 1), (2, 1, 1), (2, -1, 0))
N_WALLS = {2: 2, 3: 4}


def build_walls(D: int, window):
    """(load_boxes, in_box, zcoord, navier_slip) for dim ``D``; ``window`` is the stencil's window function."""

    @ti.func
    def load_boxes(boxes: ti.template()):
        """The wall boxes as a local 8 x 3 matrix: row 2 b + s is corner s (0: low, 1: high) of box b."""
        return ti.Matrix([[boxes[r // 2, r % 2, a] for a in ti.static(range(3))] for r in ti.static(range(8))])

    @ti.func
    def in_box(bx, b: ti.template(), pos, z):
        """(inside x and y ranges, inside z range) of static box b of ``load_boxes``, inclusive bounds."""
        in_xy = (bx[2 * b, 0] <= pos[0] <= bx[2 * b + 1, 0]) and (bx[2 * b, 1] <= pos[1] <= bx[2 * b + 1, 1])
        in_z = bx[2 * b, 2] <= z <= bx[2 * b + 1, 2]
        return in_xy, in_z

    @ti.func
    def zcoord(pos, zmid):
        z = zmid
        if ti.static(D == 3):
            z = pos[2]
        return z

    @ti.func
    def navier_slip(i, grid: ti.template(), win: ti.template(), bx, dx, inv_dx, zmid, slip):
        """Tangential velocity of wall node i from the Navier slip law with slip length ``slip`` (m).

        The velocity profile u(s) = gamma (b + s) (s: signed distance from the wall plane, > 0 in the
        material, b the slip length; it vanishes at s = -b) is fitted through the first node outside
        every wall along the wall normal, at s_f: u(s) = u_f max(b + s, 0) / (b + s_f). The normal
        velocity is zero. Nodes in two walls (edges, corners) and nodes without a free neighbour stick.
        """
        origin, stride = window(win)
        local = ti.Vector.zero(ti.i32, D)
        rest = i
        for a in ti.static(range(D - 1, -1, -1)):
            local[a] = rest % win[NX + a]
            rest = rest // win[NX + a]
        pos = ti.Vector([(local[a] + origin[a]) * dx for a in ti.static(range(D))])
        z = zcoord(pos, zmid)
        inside = 0
        wall = -1
        for b in ti.static(range(4)):
            in_xy, in_z = in_box(bx, b, pos, z)
            if in_xy and in_z:
                inside += 1
                wall = b
        vel = ti.Vector.zero(float, D)
        if inside == 1:
            for b in ti.static(range(N_WALLS[D])):
                if wall == b:
                    axis, sign, face = ti.static(WALL_NORMALS[b])
                    s = sign * (pos[axis] - bx[2 * b + face, axis])  # <= 0: inside the wall
                    k = ti.floor(-s * inv_dx, ti.i32) + 1  # nodes to the first one outside
                    j = local[axis] + sign * k
                    if 0 <= j < win[NX + axis]:
                        fpos = pos
                        fpos[axis] += sign * k * dx
                        fz = zcoord(fpos, zmid)
                        free = True
                        for c in ti.static(range(4)):
                            in_xy, in_z = in_box(bx, c, fpos, fz)
                            if in_xy and in_z:
                                free = False
                        if free:
                            gf = grid[i + sign * k * stride[axis]]
                            factor = ti.max(slip + s, 0.0) / (slip + s + k * dx)  # Navier profile
                            for a in ti.static(range(D)):
                                if a != axis:
                                    vel[a] = gf[a] * factor
        return inside, vel

    return load_boxes, in_box, zcoord, navier_slip
