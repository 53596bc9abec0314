"""The MPM step kernel (Taichi) for one dim; ``mpm.engine`` compiles it and holds its device buffers.

One ``step`` launch advances the dam-break by one time step (paper section 4, appendix B):
1. P2G: grid momentum += w m (v + C (x_i - x_p)) - dt V_p tau grad w, grid mass += w m (uGIMP weights,
   APIC transfer, Kirchhoff stress of ``mpm.constitutive.kirchhoff_stress``, initial particle volume V_p).
2. Grid: p += dt m g; nodes inside a wall box get p = 0 (sticking); v_i = p / m. With a slip length
   b > 0 a second pass gives the wall nodes the tangential velocity of the Navier law u_s = b du/dn,
   fitted through the first node outside the wall (docs/method/forward-model.md, "Wall slip"; measured
   effect: docs/performance.md, "Wall slip").
3. G2P: v_p = sum w v_i, C_p = sum v_i (x) grad w, elastic predictor b* = F b F^T with F = I + dt C
   (eq. 52), with the density correction (below) the predictor's volume is capped at the one the particles'
   own spacing implies; plastic correction ``mpm.constitutive.return_mapping`` (eq. 57); particles inside a wall box
   are frozen (v = 0, C = 0; with a slip length their elastic state too); advection x += dt v.
With one thread all the steps up to the next time-step update run in one launch (a serial loop).
The grid window and the uGIMP stencil are in ``mpm.stencil``, the wall tests and the slip law in ``mpm.walls``.

Density correction (optional): the volume ratio J = sqrt(det b_e) that a particle carries and the volume its
neighbours leave it drift apart; where particles crowd (grid density interpolated to the particle,
rho_p = sum w m_i / dx^D, above the rest density rho_0 = m_p / V_p) the predictor's J is lowered to
rho_0 / rho_p (times this step's det F), so that the pressure of eq. 12 pushes them apart. Never raised, so
free surfaces (where rho_p underestimates) are left alone (docs/method/forward-model.md, "Density correction").
"""
import taichi as ti

from mpm.stencil import COUNT, DONE, ERROR, NEED, NX, OVERFLOW, OX, build_stencil
from mpm.walls import build_walls

from mpm.solver_constants import ERR_LEFT_REACH, ERR_NAN, ERRORS, FROZEN, HIDDEN, PLASTIC  # noqa: F401 (ERRORS re-exported)


def build_kernels(dim: int, tasks: int, atomic: bool):
    """The step kernel for ``dim``: on the CPU, ``tasks`` slices of the particles each scatter into their own
    grid copy without atomics; on the GPU (``atomic``) one grid copy with atomic adds."""
    from mpm.constitutive import iso_factor, kirchhoff_stress, return_mapping

    D = dim
    nd = ti.types.ndarray()
    serial = tasks == 1 and not atomic
    params = step_params(D)
    particle_arrays, grid_arrays = array_groups()
    stencil_base, ugimp, window, lead_weights, column, LEADS = build_stencil(D)
    L = D - 1  # the last axis: unit stride in the grid, innermost in the stencil loops
    load_boxes, in_box, zcoord, navier_slip = build_walls(D, window)

    @ti.func
    def block(m):
        """Upper-left D x D block of a 3x3 matrix."""
        r = ti.Matrix.zero(float, D, D)
        for i, j in ti.static(ti.ndrange(D, D)):
            r[i, j] = m[i, j]
        return r

    @ti.func
    def sandwich(F, b):
        """F b F^T for a symmetric b: the upper triangle, mirrored."""
        M = F @ b
        r = ti.Matrix.zero(float, 3, 3)
        for i, j in ti.static(ti.ndrange(3, 3)):
            if ti.static(j >= i):
                r[i, j] = M[i, 0] * F[j, 0] + M[i, 1] * F[j, 1] + M[i, 2] * F[j, 2]
                if ti.static(j > i):
                    r[j, i] = r[i, j]
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
                     iso: ti.template(), grid: ti.template(), origin, stride, inv_dx, prm):
        """Scatter particle p: node (lead, k) receives w (m v + m C (x_i - x_p)) - dt V_p tau grad w and w m.
        With u = m v - m C fx (fx: particle position from stencil node 0, cells) and the factors of
        ``lead_weights``, the momentum is w[L, k] (P + k Q) + dw[L, k] R with, per ``lead``,
        P = wl (u + sum_a lead[a] m C[:, a]) + sum_a gl[a] S[:, a], Q = wl m C[:, L], R = wl S[:, L]."""
        base, fx, w, dw = ugimp(x[p], inv_dx, origin, prm.lh)
        tau = kirchhoff_stress(be[p], iso[p], prm.kappa, prm.mu)
        S = (-prm.dt * prm.vol * inv_dx) * block(tau)  # force -V_p tau grad w (grad in cells)
        mC = (prm.mp * prm.dx) * C[p]
        u = prm.mp * v[p] - mC @ fx  # APIC momentum at stencil node 0
        node0 = base.dot(stride) + t * prm.capg  # the task's own grid copy (t = 0 with atomics)
        for lead in ti.static(LEADS):
            wl, gl = lead_weights(w, dw, lead)
            P = wl * u
            k0 = node0
            for a in ti.static(range(L)):
                if ti.static(lead[a] > 0):
                    P += (wl * lead[a]) * column(mC, a)
                    k0 += lead[a] * stride[a]
                P += gl[a] * column(S, a)
            Q = wl * column(mC, L)
            R = wl * column(S, L)
            ml = wl * prm.mp
            for k in ti.static(range(3)):
                mom = w[L, k] * (P + k * Q) + dw[L, k] * R
                contrib = ti.Vector.zero(float, D + 1)
                for a in ti.static(range(D)):
                    contrib[a] = mom[a]
                contrib[D] = w[L, k] * ml
                if ti.static(atomic):
                    grid[k0 + k] += contrib
                else:
                    grid[k0 + k] = grid[k0 + k] + contrib  # own grid copy per task: no atomics needed

    @ti.func
    def g2p_particle(p, x: ti.template(), v: ti.template(), C: ti.template(), be: ti.template(),
                     iso: ti.template(), loge: ti.template(), flags: ti.template(), grid: ti.template(), bx,
                     origin, stride, inv_dx, prm, yue: ti.template(), slipping: ti.template(), dens: ti.template()):
        dt = prm.dt
        xp = x[p]
        base, fx, w, dw = ugimp(xp, inv_dx, origin, prm.lh)
        vp = ti.Vector.zero(float, D)
        mass = 0.0
        B = ti.Matrix.zero(float, D, D)
        node0 = base.dot(stride)
        for lead in ti.static(LEADS):
            wl, gl = lead_weights(w, dw, lead)
            k0 = node0
            for a in ti.static(range(L)):
                if ti.static(lead[a] > 0):
                    k0 += lead[a] * stride[a]
            gm = 0.0  # sum_k w[L, k] m_k
            gw = ti.Vector.zero(float, D)  # sum_k w[L, k] v_k along the last axis
            gd = ti.Vector.zero(float, D)  # sum_k dw[L, k] v_k
            for k in ti.static(range(3)):
                g = grid[k0 + k]
                gv = ti.Vector([g[a] for a in ti.static(range(D))])
                gw += w[L, k] * gv
                gd += dw[L, k] * gv
                if ti.static(dens):
                    gm += w[L, k] * g[D]
            vp += wl * gw
            if ti.static(dens):
                mass += wl * gm
            for r in ti.static(range(D)):
                for a in ti.static(range(L)):
                    B[r, a] += gl[a] * gw[r]
                B[r, L] += wl * gd[r]
        B *= inv_dx  # C_p = grad v: the grid velocity gradient, not Jiang et al.'s B D^-1
        b_old = be[p]
        iso_old, loge_old = iso[p], loge[p]
        F = ti.Matrix.identity(float, 3) + dt * embed(B)
        b_trial = sandwich(F, b_old)  # elastic predictor, eq. 52 in its F b F^T form
        if ti.static(dens):
            crowd = mass * inv_dx ** D * prm.vol / prm.mp  # rho_p / rho_0
            if crowd > 1:
                j_spacing = F.determinant() / crowd
                det_trial = b_trial.determinant()
                if j_spacing * j_spacing < det_trial:  # lower J only: det b_e = J^2
                    b_trial *= iso_factor(det_trial / (j_spacing * j_spacing))  # (J_s^2 / det)^(1/3)
        # eq. 57, identity when elastic; the Newton solve starts from the particle's last log(e)
        b_new, iso_new, log_e, plastic = return_mapping(b_trial, b_old, iso[p], prm.mu, prm.eta, prm.n_power, prm.sy, dt,
                                                        loge[p], yue)
        f = flags[p]
        if plastic:
            f |= PLASTIC
        be[p] = b_new
        iso[p] = iso_new
        loge[p] = log_e
        # walls, tested at the pre-advection position, as the reference implementation does
        z = zcoord(xp, prm.zmid)
        frozen = False
        hidden = (f & HIDDEN) != 0
        for b in ti.static(range(4)):
            in_xy, in_z = in_box(bx, b, xp, z)
            if in_xy:
                hidden = in_z  # the last box containing (x, y) decides visibility
                if in_z:
                    frozen = True
        f &= ~(HIDDEN | FROZEN)
        if hidden:
            f |= HIDDEN
        if frozen:
            f |= FROZEN
            vp = ti.Vector.zero(float, D)
            B = ti.Matrix.zero(float, D, D)
            if ti.static(slipping):
                # the coating inside a slipping wall does not deform: its wall nodes move, and a strain
                # integrated there at rest would grow without bound and push the material beside it
                be[p] = b_old
                iso[p] = iso_old
                loge[p] = loge_old
        flags[p] = f
        xn = xp + dt * vp
        x[p] = xn
        v[p] = vp
        C[p] = B
        return xn, vp

    @ti.func
    def grid_node(I, grid: ti.template(), win: ti.template(), bx, prm):
        """Grid node I (window coordinates): momentum of all task copies plus dt m body, zero inside a wall
        (sticking), then velocity; stored as (v, m) in copy 0."""
        i = 0
        for a in ti.static(range(D)):
            i = i * win[NX + a] + I[a]
        g = grid[i]
        for t in ti.static(range(1, tasks)):
            g += grid[t * prm.capg + i]
        m = g[D]
        if m > 0:
            pos = ti.Vector([(I[a] + win[OX + a]) * prm.dx for a in ti.static(range(D))])
            mom = ti.Vector([g[a] for a in ti.static(range(D))])
            mom += (prm.dt * m) * prm.body  # gravity (and any other body force)
            z = zcoord(pos, prm.zmid)
            for b in ti.static(range(4)):
                in_xy, in_z = in_box(bx, b, pos, z)
                if in_xy and in_z:
                    mom = ti.Vector.zero(float, D)  # sticking wall
            vel = mom / m
            for a in ti.static(range(D)):
                g[a] = vel[a]
            grid[i] = g
        elif ti.static(tasks > 1):
            grid[i] = g

    @ti.func
    def step_body(x: ti.template(), v: ti.template(), C: ti.template(), be: ti.template(), iso: ti.template(),
                  loge: ti.template(), flags: ti.template(), grid: ti.template(), win: ti.template(),
                  acc: ti.template(), accf: ti.template(), bx, lim: ti.template(), prm, yue: ti.template(),
                  slipping: ti.template(), dens: ti.template()):
        inv_dx = 1.0 / prm.dx
        n, capg = prm.n, prm.capg
        # the particles in slices: one per task, each into its own grid copy (CPU), or one particle per slice
        # into the one grid copy by atomic adds (GPU)
        slices = n if ti.static(atomic) else tasks
        # 1. clear the previous window in every grid copy
        for i in range(win[COUNT]):
            for t in ti.static(range(tasks)):
                grid[t * capg + i] = ti.Vector.zero(float, D + 1)
        # 2. the new window: stencil bounding box of the particles (from the last G2P)
        for _ in range(1):
            if win[ERROR] == 0:
                lo = ti.Vector([acc[0, a] for a in ti.static(range(D))])
                hi = ti.Vector([acc[0, 3 + a] for a in ti.static(range(D))])
                for t in range(1, tasks):
                    for a in ti.static(range(D)):
                        lo[a] = ti.min(lo[a], acc[t, a])
                        hi[a] = ti.max(hi[a], acc[t, 3 + a])
                count = 1
                for a in ti.static(range(D)):
                    if lo[a] < lim[a] or hi[a] > lim[3 + a]:
                        win[ERROR] = ERR_LEFT_REACH
                    count *= hi[a] + 3 - lo[a]
                if win[ERROR] == 0:
                    if count > capg:
                        win[OVERFLOW] = 1
                        win[NEED] = count
                        win[COUNT] = 0
                    else:
                        for a in ti.static(range(D)):
                            win[OX + a] = lo[a]
                            win[NX + a] = hi[a] + 3 - lo[a]
                        win[COUNT] = count
                        if ti.static(atomic):  # G2P accumulates the next box atomically
                            for a in ti.static(range(D)):
                                acc[0, a] = 2147483647
                                acc[0, 3 + a] = -2147483647
                            accf[0] = 0.0
        # 3. P2G
        for t in range(slices):
            if win[OVERFLOW] == 0 and win[ERROR] == 0:
                origin, stride = window(win)
                p0, p1 = slice_of(t, n)
                for p in range(p0, p1):
                    p2g_particle(p, 0 if ti.static(atomic) else t, x, v, C, be, iso, grid, origin, stride, inv_dx,
                                 prm)
        # 4. grid update: gravity, sticking walls, velocity (copy 0 holds (v, m) afterwards); the nodes by their
        # window coordinates (nested loops on one thread: no index division), none after an overflow
        live = ti.cast(win[COUNT] > 0, ti.i32)
        if ti.static(D == 3):
            for I in ti.grouped(ti.ndrange(win[NX] * live, win[NX + 1], win[NX + 2])):
                grid_node(I, grid, win, bx, prm)
        else:
            for I in ti.grouped(ti.ndrange(win[NX] * live, win[NX + 1])):
                grid_node(I, grid, win, bx, prm)
        # 4b. walls with a slip length: tangential velocity of the wall nodes from the Navier law
        if ti.static(slipping):
            for i in range(win[COUNT]):
                if win[OVERFLOW] == 0 and win[ERROR] == 0:
                    g = grid[i]
                    if g[D] > 0:
                        inside, vel = navier_slip(i, grid, win, bx, prm.dx, inv_dx, prm.zmid, prm.slip)
                        if inside > 0:
                            for a in ti.static(range(D)):
                                g[a] = vel[a]
                            grid[i] = g
        # 5. G2P, constitutive update, walls, advection; bounding box and speed for the next step
        for t in range(slices):
            if win[OVERFLOW] == 0 and win[ERROR] == 0:
                lo = ti.Vector([2147483647] * D)
                hi = ti.Vector([-2147483647] * D)
                vmax2 = 0.0
                bad = 0
                origin, stride = window(win)
                p0, p1 = slice_of(t, n)
                for p in range(p0, p1):
                    xn, vp = g2p_particle(p, x, v, C, be, iso, loge, flags, grid, bx, origin, stride, inv_dx, prm,
                                          yue, slipping, dens)
                    if (xn != xn).any():
                        bad = 1
                    base = stencil_base(xn, inv_dx, prm.lh)
                    lo = ti.min(lo, base)
                    hi = ti.max(hi, base)
                    vmax2 = ti.max(vmax2, vp.norm_sqr())
                if ti.static(atomic):
                    for a in ti.static(range(D)):
                        ti.atomic_min(acc[0, a], lo[a])
                        ti.atomic_max(acc[0, 3 + a], hi[a])
                    ti.atomic_max(accf[0], ti.sqrt(vmax2))
                else:
                    for a in ti.static(range(D)):
                        acc[t, a] = lo[a]
                        acc[t, 3 + a] = hi[a]
                    accf[t] = ti.sqrt(vmax2)
                if bad:
                    win[ERROR] = ERR_NAN
        # 6. count the completed step
        for _ in range(1):
            if win[OVERFLOW] == 0 and win[ERROR] == 0:
                win[DONE] += 1

    @ti.func
    def share(t, n):
        """Particles [p0, p1) of task t's share of n."""
        return t * n // tasks, (t + 1) * n // tasks

    @ti.func
    def slice_of(t, n):
        """Particles [p0, p1) of slice t: one particle with atomics, else the task's share."""
        p0, p1 = t, t + 1
        if ti.static(not atomic):
            p0, p1 = share(t, n)
        return p0, p1

    @ti.func
    def step_of(pt: ti.template(), gs: ti.template(), bx, lim: ti.template(), prm, yue: ti.template(),
                slipping: ti.template(), dens: ti.template()):
        step_body(pt.x, pt.v, pt.C, pt.be, pt.iso, pt.loge, pt.flags, gs.grid, gs.win, gs.acc, gs.accf, bx, lim, prm,
                  yue, slipping, dens)

    @ti.kernel
    def step(pt: particle_arrays, gs: grid_arrays, boxes: nd, lim: nd, prm: params, steps: ti.i32,
             yue: ti.template(), slipping: ti.template(), dens: ti.template()):
        if ti.static(serial):  # one thread: all ``steps`` steps in one launch, loops run in order
            for _ in range(1):
                bx = load_boxes(boxes)
                for _s in range(steps):
                    step_of(pt, gs, bx, lim, prm, yue, slipping, dens)
        else:  # parallel loops: one step per launch
            bx = load_boxes(boxes)
            step_of(pt, gs, bx, lim, prm, yue, slipping, dens)

    @ti.kernel
    def init_bbox(x: nd, acc: nd, accf: nd, prm: params):
        """The stencil bounding box of each task's share of the initial positions: the first step's window."""
        inv_dx = 1.0 / prm.dx
        for t in range(tasks):
            lo = ti.Vector([2147483647] * D)
            hi = ti.Vector([-2147483647] * D)
            p0, p1 = share(t, prm.n)
            for p in range(p0, p1):
                base = stencil_base(x[p], inv_dx, prm.lh)
                lo = ti.min(lo, base)
                hi = ti.max(hi, base)
            for a in ti.static(range(D)):
                acc[t, a] = lo[a]
                acc[t, 3 + a] = hi[a]
            accf[t] = 0.0

    @ti.kernel
    def grid_mass(grid: nd, win: nd, out: nd):
        out[0] = 0.0
        for i in range(win[COUNT]):
            out[0] += grid[i][D]

    return step, init_bbox, grid_mass, params, particle_arrays, grid_arrays


def step_params(dim: int):
    """The step kernel's scalar parameters as one Taichi struct: particle count, grid capacity per copy, the
    step dt, the cell width dx, the particle's mass and volume, the moduli kappa and mu, the material (eta, n,
    sigma_y), the body force, the plane z of symmetry, half the box length in cells and the slip length."""
    return ti.types.struct(n=ti.i32, capg=ti.i32, dt=float, dx=float, mp=float, vol=float, kappa=float, mu=float,
                           eta=float, n_power=float, sy=float, body=ti.types.vector(dim, float), zmid=float, lh=float,
                           slip=float)


def array_groups():
    """The step kernel's arrays in two argument packs: the particles' state (positions x, velocities v, velocity
    gradients C, elastic left Cauchy-Green tensors be, their isochoric factors iso, the Newton solve's last log
    excess stress loge, the flag bits) and the grid's (node values of every task copy, the window record, each task's
    stencil bounding box and top speed)."""
    nd = ti.types.ndarray()
    return (ti.types.argpack(x=nd, v=nd, C=nd, be=nd, iso=nd, loge=nd, flags=nd),
            ti.types.argpack(grid=nd, win=nd, acc=nd, accf=nd))
