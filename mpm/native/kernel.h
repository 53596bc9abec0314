// The MPM dam-break step of mpm/kernels.py, in C++: one SIMD width, compiled once per instruction set.
//
// engine.cpp includes this file once per target (AVX-512, AVX2, generic) inside its own namespace and target
// pragma, after the headers it needs and types.h (Params, Outputs, Result, the time-step schedule). The
// instruction sets differ only in the two layers this file includes: simd.h (the 16-lane values and their
// operations) and transfer.h (how a particle's stencil rows are formed in P2G and summed in G2P); the physics
// below reads the same on every one. Sections and names follow the Taichi step: P2G, grid, G2P, return mapping
// (paper section 4, appendix B); the constants arrive from their one Python home (mpm/scene.py,
// mpm/solver_constants.py) through Params.
//
// Layout: particles in blocked structure-of-arrays (16 lanes of one field contiguous, all fields of a block
// together, so that a step streams through one region of memory), float32, padded to whole blocks; the grid is
// the dense window of mpm/stencil.py with 4 floats per node (momentum or velocity, then mass; 2D: one pad),
// its last axis contiguous, so that one stencil row (3 nodes) is one 16-float vector (the 4th node gets + 0).
// Per block of 16 particles the constitutive update runs across the lanes; the transfers run per particle along
// stencil rows. A step is one fused pass per particle: G2P from grid A, constitutive update, advection, and P2G
// of the next step into grid B (the same time step), except at a time-step update.

namespace VIRHEO_ISA {
using virheo::Params;
using virheo::Outputs;
using virheo::Result;
using virheo::ProgressFn;
using virheo::Substeps;
using virheo::substeps;

#include "simd.h"

VH_INLINE V iso_factor(V det) { return vrcbrt(det); }  // det(b_e)^(-1/3)

// symmetric 3x3 as (xx, yy, zz, xy, xz, yz)
struct Sym { V a[6]; };
VH_INLINE V sym_det(const Sym& s) {
    const V *a = s.a;
    return a[0] * (a[1] * a[2] - a[5] * a[5]) - a[3] * (a[3] * a[2] - a[5] * a[4]) + a[4] * (a[3] * a[5] - a[1] * a[4]);
}
VH_INLINE V sym_trace(const Sym& s) { return s.a[0] + s.a[1] + s.a[2]; }
VH_INLINE Sym sym_scale(const Sym& s, V f) {
    Sym r;
    for (int i = 0; i < 6; i++) r.a[i] = s.a[i] * f;
    return r;
}
VH_INLINE Sym sym_select(VI m, const Sym& a, const Sym& b) {
    Sym r;
    for (int i = 0; i < 6; i++) r.a[i] = sel(m, a.a[i], b.a[i]);
    return r;
}
VH_INLINE Sym sym_dev(const Sym& s) {  // deviatoric part A - tr(A)/3 I
    Sym r = s;
    V t = sym_trace(s) * (1.0f / 3.0f);
    for (int i = 0; i < 3; i++) r.a[i] = s.a[i] - t;
    return r;
}
VH_INLINE V sym_norm(const Sym& s) {  // Frobenius norm
    const V *a = s.a;
    return vsqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2] + 2.0f * (a[3] * a[3] + a[4] * a[4] + a[5] * a[5]));
}
VH_INLINE Sym sandwich(const V F[3][3], const Sym& b) {  // F b F^T (elastic predictor, eq. 52)
    const int si[3][3] = {{0, 3, 4}, {3, 1, 5}, {4, 5, 2}};
    V M[3][3];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) M[i][j] = F[i][0] * b.a[si[0][j]] + F[i][1] * b.a[si[1][j]] + F[i][2] * b.a[si[2][j]];
    Sym r;
    const int pi[6] = {0, 1, 2, 0, 0, 1}, pj[6] = {0, 1, 2, 1, 2, 2};
    for (int c = 0; c < 6; c++) {
        int i = pi[c], j = pj[c];
        r.a[c] = M[i][0] * F[j][0] + M[i][1] * F[j][1] + M[i][2] * F[j][2];
    }
    return r;
}

// Kirchhoff stress tau = (kappa/2)(J^2 - 1) I + mu dev(bbar) (eqs. 10, 12), iso = det(b_e)^(-1/3)
VH_INLINE Sym kirchhoff_stress(const Sym& be, V iso, float kappa, float mu) {
    V p = 0.5f * kappa * (sym_det(be) - 1.0f);
    Sym t = sym_scale(sym_dev(sym_scale(be, iso)), splat(mu));
    for (int i = 0; i < 3; i++) t.a[i] += p;
    return t;
}

struct Rule { float alpha, beta, c; };

// Plastic correction of the trial b_e (appendix B, eq. 57 with the old isochoric trace): mpm.constitutive's
// return_mapping across 16 lanes. The Newton solve on s = log(e) (e: excess stress) starts from
// min(log_e0, log(e_trial)) and stops per lane once a step is below newton_tol (at most `iterations`).
struct Mapped { Sym be; V iso, log_e; VI plastic; };
VH_INLINE Mapped return_mapping(const Sym& b_trial, const Sym& b_old, V iso_old, float mu, float eta, float n,
                                float sy, float dt, V log_e0, Rule rule, VI live, int iterations, float newton_tol,
                                float no_warm_start) {
    Mapped out;
    V det = sym_det(b_trial);
    V J = vsqrt(det);
    out.iso = iso_factor(det);
    Sym d = sym_dev(b_trial);  // dev(bbar) = iso dev(b): the cube root and the norm run side by side
    V x_trial = mu / J * out.iso * sym_norm(d);  // eq. 13
    V e_trial = rule.alpha * x_trial - rule.beta * sy;  // eq. 15
    out.plastic = (e_trial > 0.0f) & live;
    out.be = b_trial;
    out.log_e = splat(no_warm_start);
    if (!any(out.plastic)) return out;
    V T = sym_trace(b_old) * iso_old;  // tr(bbar_old)
    V k = dt * mu / J * T * (1.0f / 3.0f);  // eq. 57
    V a = sel(out.plastic, rule.alpha * rule.c * k, splat(1.0f));
    V log_t = vlog(sel(out.plastic, e_trial, splat(1.0f)));
    V log_a = vlog(a) - __builtin_logf(eta) / n;
    float p = 1.0f / n;
    V s = vmin(log_e0, log_t);
    V scale = out.iso / (rule.alpha * x_trial), inv_det = 1.0f / det;  // computed while the solve runs
    VI active = out.plastic;
    for (int it = 0; it < iterations; it++) {
        // G(s) = log(e^s + e^v) - log_t, v = log_a + p s; d = v - s, r = e^-|d|
        V dd = log_a + (p - 1.0f) * s;
        V r = vexp(-vabs(dd));
        V g = vmax(s, s + dd) + vlog(1.0f + r) - log_t;
        V slope = sel(dd > 0.0f, (r + p) / (1.0f + r), (1.0f + p * r) / (1.0f + r));
        V step = g / slope;
        s = sel(active, s - step, s);
        active = active & (vabs(step) >= newton_tol);
        if (!any(active)) break;
    }
    V ratio = (vexp(s) + rule.beta * sy) * scale;  // iso x / x_trial, x = (e + beta sigma_y) / alpha (iso d = dev bbar)
    Sym bn;
    V t3 = T * (1.0f / 3.0f);
    for (int i = 0; i < 6; i++) bn.a[i] = ratio * d.a[i];
    for (int i = 0; i < 3; i++) bn.a[i] += t3;  // eq. 56
    Sym res = sym_scale(bn, vrcbrt(sym_det(bn) * inv_det));  // isochoric: det kept
    out.be = sym_select(out.plastic, res, b_trial);
    out.log_e = sel(out.plastic, s, out.log_e);
    return out;
}

// uGIMP weights per axis of stencil nodes base + 0..2 (mpm/stencil.py's ugimp): fx is the position in cells
// from stencil node 0, l = l_p / dx, q = 1 / (4 l).
struct Weights { V w[3], dw[3]; };
VH_INLINE Weights ugimp(V fx, float l) {
    Weights r;
    float q = 0.25f / l;
    V e0 = (1.0f + l) - fx;
    VI lin0 = fx < (1.0f - l);
    r.w[0] = sel(lin0, 1.0f - fx, q * e0 * e0);
    r.dw[0] = sel(lin0, splat(-1.0f), -2.0f * q * e0);
    V r1 = fx - 1.0f;
    VI in1 = r1 > -l;
    r.w[1] = sel(in1, 1.0f - 2.0f * q * (l * l + r1 * r1), 1.0f + r1);
    r.dw[1] = sel(in1, -4.0f * q * r1, splat(1.0f));
    V e2 = (l - 1.0f) + fx;
    VI in2 = e2 > 0.0f;
    r.w[2] = sel(in2, q * e2 * e2, V{});
    r.dw[2] = sel(in2, 2.0f * q * e2, V{});
    return r;
}

#include "transfer.h"

using virheo::ERR_INTERRUPTED, virheo::ERR_LEFT_REACH, virheo::ERR_NAN, virheo::ERR_SPEED;
using virheo::FROZEN, virheo::HIDDEN, virheo::PLASTIC;
constexpr int INT_BIG = 2147483647;

struct Window {
    int org[3] = {0, 0, 0}, n[3] = {1, 1, 1}, stride[3] = {0, 0, 1};
    long count = 0;
    long row[9] = {};  // offsets (floats) of the stencil rows from a stencil's node 0, leading axes in order
};

template <int D>
struct Engine {
    static constexpr int L = D - 1;  // the last axis: unit stride in the grid
    static constexpr int LEADS = D == 3 ? 9 : 3;
    Params P;
    Rule rule;
    int N = 0, NP = 0, T = 1;
    float inv_dx = 0;
    // particles: NP = N rounded up to whole blocks; field f of particle p at word (p / W) * NF * W + f * W + p % W
    static unsigned long slot(unsigned long p) { return p / W * (NF * W) + p % W; }  // word of field 0
    template <class T>
    struct Field {
        T* p0 = nullptr;
        T& operator[](long p) const { return p0[slot((unsigned long)p)]; }
    };
    // in the order a step reads them
    static constexpr int F_X = 0, F_BASE = D, F_BE = 2 * D, F_ISO = F_BE + 6, F_LOGE = F_ISO + 1, F_FLAGS = F_LOGE + 1,
                         F_V = F_FLAGS + 1, F_C = F_V + D, F_ID = F_C + D * D, NF = F_ID + 1;
    struct Words {  // raw 64-byte aligned memory: each word is written and read as one type only
        void* ptr = nullptr;
        void reset(size_t words) {
            std::free(ptr);
            ptr = std::aligned_alloc(64, (words * 4 + 63) / 64 * 64);
        }
        ~Words() { std::free(ptr); }
    } store, spare;
    Field<float> x[D], v[D], C[D * D], be[6], iso, loge;
    Field<int> flags, id, base[D];
    template <class T>
    Field<T> field(const Words& s, int f) const { return Field<T>{reinterpret_cast<T*>(s.ptr) + f * W}; }
    void bind() {
        for (int a = 0; a < D; a++) x[a] = field<float>(store, F_X + a), v[a] = field<float>(store, F_V + a),
                                    base[a] = field<int>(store, F_BASE + a);
        for (int c = 0; c < D * D; c++) C[c] = field<float>(store, F_C + c);
        for (int c = 0; c < 6; c++) be[c] = field<float>(store, F_BE + c);
        iso = field<float>(store, F_ISO), loge = field<float>(store, F_LOGE);
        flags = field<int>(store, F_FLAGS), id = field<int>(store, F_ID);
    }
    // grids A (read by G2P) and B (written by P2G), T copies each
    std::vector<float> grid[2];
    long cap[2] = {0, 0};
    Window win[2];
    int cur = 0;  // grid[cur] is A
    // the stencil bounding box of the current positions
    int lo[3], hi[3];
    float vmax = 0;
    // per-axis box masks of the grid nodes (bit b: inside box b along that axis)
    std::vector<unsigned char> axis_mask[3];
    unsigned char zmask2d = 0;

    using Block = GatherBlock<D>;

    // ---------------------------------------------------------------------------------------------------
    // set-up
    void init(const Params& p, const double* pos, const int* flags0, int n) {
        P = p;
        N = n;
        NP = (n + W - 1) / W * W;
        T = p.threads < 1 ? 1 : p.threads;
        inv_dx = 1.0f / P.dx;
        if (T > 1) pool.start(T);
        rule = Rule{P.alpha, P.beta, P.flow_c};
        store.reset((size_t)NP * NF);
        spare.reset((size_t)NP * NF);
        bind();
        for (int i = 0; i < NP; i++) {
            int q = i < n ? i : n - 1;  // lanes past the last particle copy it
            for (int a = 0; a < D; a++) x[a][i] = (float)pos[(long)q * D + a], v[a][i] = 0.0f, base[a][i] = 0;
            for (int c = 0; c < D * D; c++) C[c][i] = 0.0f;
            for (int c = 0; c < 6; c++) be[c][i] = c < 3 ? 1.0f : 0.0f;
            iso[i] = 1.0f;
            loge[i] = P.no_warm_start;
            flags[i] = flags0[q];
            id[i] = q;
        }
        bases_and_box(0, NP);
        zmask2d = 0;
        if (D == 2)
            for (int b = 0; b < 4; b++)
                if (P.boxes[b][0][2] <= P.zmid && P.zmid <= P.boxes[b][1][2]) zmask2d |= 1 << b;
    }

    // stencil node 0 of every particle (floor(x / dx - l), mpm/stencil.py's stencil_base) and their box
    void bases_and_box(int p0, int p1) {
        VI lov[3], hiv[3];
        for (int a = 0; a < D; a++) lov[a] = splati(INT_BIG), hiv[a] = splati(-INT_BIG);
        for (int p = p0; p < p1; p += W) {
            VI live = (vloadi(IOTA_) + p) < N;
            for (int a = 0; a < D; a++) {
                VI b = vfloor_i(vload(&x[a][p]) * inv_dx - P.lh);
                vstorei(&base[a][p], b);
                lov[a] = seli(live & (b < lov[a]), b, lov[a]);
                hiv[a] = seli(live & (b > hiv[a]), b, hiv[a]);
            }
        }
        for (int a = 0; a < D; a++) {
            lo[a] = INT_BIG, hi[a] = -INT_BIG;
            for (int i = 0; i < W; i++) lo[a] = lov[a][i] < lo[a] ? lov[a][i] : lo[a], hi[a] = hiv[a][i] > hi[a] ? hiv[a][i] : hi[a];
        }
    }

    bool outside_reach() const {
        for (int a = 0; a < D; a++)
            if (lo[a] < P.lim[a] || hi[a] > P.lim[3 + a]) return true;
        return false;
    }

    // grid g's window around the current stencil box, `margin` nodes wider on each side; zeroed
    void open_window(int g, int margin) {
        Window& w = win[g];
        long count = 1;
        for (int a = 0; a < D; a++) {
            w.org[a] = lo[a] - margin;
            w.n[a] = hi[a] + margin + 3 - w.org[a];
            count *= w.n[a];
        }
        w.stride[D - 1] = 1;
        for (int a = D - 2; a >= 0; a--) w.stride[a] = w.stride[a + 1] * w.n[a + 1];
        w.count = count;
        for (int j = 0; j < LEADS; j++) w.row[j] = D == 3 ? ((long)(j / 3) * w.stride[0] + (long)(j % 3) * w.stride[1]) * 4
                                                          : (long)j * w.stride[0] * 4;
        long need = count + 1;  // + the 4th node of the last row
        if (need > cap[g]) {
            cap[g] = need + need / 2;
            grid[g].assign((size_t)cap[g] * 4 * T, 0.0f);
        } else {
            for (int t = 0; t < T; t++) std::fill_n(&grid[g][(size_t)t * cap[g] * 4], need * 4, 0.0f);
        }
    }

    // ---------------------------------------------------------------------------------------------------
    // threads: particles in T contiguous slices of whole blocks, run by a pool that lives as long as the engine
    struct Pool {
        int tasks = 1;
        std::vector<std::thread> workers;
        std::mutex m;
        std::condition_variable wake, done;
        std::function<void(int)> job;
        long generation = 0;
        int pending = 0;
        bool stop = false;
        void start(int t) {
            tasks = t;
            for (int i = 1; i < tasks; i++) workers.emplace_back([this, i] { serve(i); });
        }
        void serve(int t) {
            virheo::FlushDenormals flush;  // as the calling thread (engine.cpp)
            long seen = 0;
            for (;;) {
                std::unique_lock<std::mutex> lk(m);
                wake.wait(lk, [&] { return stop || generation != seen; });
                if (stop) return;
                seen = generation;
                lk.unlock();
                job(t);
                lk.lock();
                if (--pending == 0) done.notify_one();
            }
        }
        void run(const std::function<void(int)>& f) {
            {
                std::lock_guard<std::mutex> lk(m);
                job = f;
                pending = tasks - 1;
                generation++;
            }
            wake.notify_all();
            f(0);
            std::unique_lock<std::mutex> lk(m);
            done.wait(lk, [&] { return pending == 0; });
        }
        ~Pool() {
            {
                std::lock_guard<std::mutex> lk(m);
                stop = true;
            }
            wake.notify_all();
            for (auto& w : workers) w.join();
        }
    } pool;

    template <class F>
    void parallel(int tasks, F&& f) {
        if (tasks <= 1) {
            f(0);
            return;
        }
        pool.run(std::function<void(int)>(f));
    }
    int slice(int t) const { return (int)((long)NP / W * t / T) * W; }

    // ---------------------------------------------------------------------------------------------------
    // 1. P2G: node (lead, k) receives w (m v + m C (x_i - x_p)) - dt V_p tau grad w and w m
    using Scatter = ScatterBlock<D>;


    // per-lane quantities of P2G for the block at p (positions x, bases, b_e, iso, v, C already stored)
    void scatter_prepare(int p, float dt, Scatter& sb) {
        const float mp = P.mp, dx = P.dx;
        block_weights(p, sb);
        V fx[D];
        for (int a = 0; a < D; a++) fx[a] = vload(sb.fx[a]);
        Sym b;
        for (int c = 0; c < 6; c++) b.a[c] = vload(&be[c][p]);
        Sym tau = kirchhoff_stress(b, vload(&iso[p]), P.kappa, P.mu);
        const int si[3][3] = {{0, 3, 4}, {3, 1, 5}, {4, 5, 2}};
        float sf = -dt * P.vol * inv_dx;  // force -V_p tau grad w (grad in cells)
        for (int r = 0; r < D; r++) {
            V u = mp * vload(&v[r][p]);
            for (int c = 0; c < D; c++) {
                vstore(sb.S[r][c], sf * tau.a[si[r][c]]);
                V mc = (mp * dx) * vload(&C[r * D + c][p]);
                vstore(sb.mC[r][c], mc);
                u -= mc * fx[c];  // APIC momentum at stencil node 0
            }
            vstore(sb.u[r], u);
        }
        scatter_rows(sb, mp);  // (AVX-512: as rows of every lane)
    }

    // scatter lane i of the block into copy t of grid g
    // (block_nodes has found the block's stencils inside the window)
    void scatter_lane(int i, const Scatter& sb, int g, int t) {
        const Window& w = win[g];
        float* gr = &grid[g][((size_t)t * cap[g] + sb.node0[i]) * 4];
        V Wk, KWk, DWk, CU, Qb, Rb, A[D - 1], G[D - 1];
        row_terms(sb, i, P.mp, Wk, KWk, DWk, CU, Qb, Rb, A, G);
        V U = Wk * CU + KWk * Qb + DWk * Rb;
        if constexpr (D == 3) {
            // the weights are a tensor product: row (a0, a1) = w1[a1] X[a0] + w0[a0] Z[a1]
            V X[3], Z[3];
            for (int a = 0; a < 3; a++) {
                X[a] = sb.w[0][a][i] * (U + (float)a * A[0]) + sb.dw[0][a][i] * G[0];
                Z[a] = ((float)a * sb.w[1][a][i]) * A[1] + sb.dw[1][a][i] * G[1];
            }
            for (int a0 = 0; a0 < 3; a0++)
                for (int a1 = 0; a1 < 3; a1++) {
                    V row = sb.w[1][a1][i] * X[a0] + sb.w[0][a0][i] * Z[a1];
                    float* q = gr + w.row[3 * a0 + a1];
                    row_add(q, row);
                }
        } else {
            for (int a0 = 0; a0 < 3; a0++) {
                V row = sb.w[0][a0][i] * (U + (float)a0 * A[0]) + sb.dw[0][a0][i] * G[0];
                float* q = gr + w.row[a0];
                row_add(q, row);
            }
        }
    }

    void p2g_pass(int g, float dt) {
        parallel(T, [&](int t) {
            Scatter sb;
            for (int p = slice(t); p < slice(t + 1); p += W) {
                scatter_prepare(p, dt, sb);
                int cnt = N - p < W ? N - p : W;
                block_nodes(p, cnt, g, sb);  // the window is the particles' exact box
                for (int i = 0; i < cnt; i++) scatter_lane(i, sb, g, t);
            }
        });
    }

    // ---------------------------------------------------------------------------------------------------
    // 2. grid: momentum of all copies + dt m body, zero inside a wall (sticking), velocity; (v, m) in copy 0
    void build_axis_masks(int g) {
        const Window& w = win[g];
        for (int a = 0; a < D; a++) {
            axis_mask[a].assign(w.n[a], 0);
            for (int i = 0; i < w.n[a]; i++) {
                float pos = (float)(i + w.org[a]) * P.dx;
                unsigned char m = 0;
                for (int b = 0; b < 4; b++)
                    if (P.boxes[b][0][a] <= pos && pos <= P.boxes[b][1][a]) m |= 1 << b;
                axis_mask[a][i] = m;
            }
        }
    }

    void grid_update(int g, float dt) {
        const Window& w = win[g];
        build_axis_masks(g);
        const float b0 = P.body[0] * dt, b1 = P.body[1] * dt, b2 = P.body[2] * dt;
        float* G0 = grid[g].data();
        const long cp = cap[g] * 4;
        const int rows = D == 3 ? w.n[0] * w.n[1] : w.n[0];
        const int nl = w.n[L];
        parallel(T, [&](int t) {
            for (int r = rows * t / T; r < rows * (t + 1) / T; r++) {
                unsigned char mr = D == 3 ? (axis_mask[0][r / w.n[1]] & axis_mask[1][r % w.n[1]]) : (axis_mask[0][r] & zmask2d);
                const unsigned char* ml = axis_mask[L].data();
                float* q = G0 + (long)r * nl * 4;
                for (int k = 0; k < nl; k++, q += 4) {
                    float m0 = q[0], m1 = q[1], m2 = q[2], m3 = q[3];
                    for (int c = 1; c < T; c++) {
                        const float* o = q + c * cp;
                        m0 += o[0], m1 += o[1], m2 += o[2], m3 += o[3];
                    }
                    float m = D == 3 ? m3 : m2;
                    if (m > 0) {
                        if (mr & ml[k]) {
                            m0 = m1 = 0.0f;
                            if (D == 3) m2 = 0.0f;
                        } else {
                            m0 += m * b0, m1 += m * b1;  // gravity (and any other body force)
                            if (D == 3) m2 += m * b2;
                        }
                        m0 /= m, m1 /= m;  // a division, not times 1/m: a denormal mass would make that inf
                        if (D == 3) m2 /= m;
                    }
                    q[0] = m0, q[1] = m1, q[2] = m2, q[3] = m3;
                }
            }
        });
        if (P.slipping) navier_slip(g);
    }

    // 2b. walls with a slip length: tangential velocity of wall nodes from the Navier law (mpm/walls.py)
    int boxes_holding(const float* pos) const {
        float z = D == 3 ? pos[2] : P.zmid;
        int m = 0;
        for (int b = 0; b < 4; b++) {
            bool in_xy = P.boxes[b][0][0] <= pos[0] && pos[0] <= P.boxes[b][1][0] && P.boxes[b][0][1] <= pos[1] &&
                         pos[1] <= P.boxes[b][1][1];
            bool in_z = P.boxes[b][0][2] <= z && z <= P.boxes[b][1][2];
            if (in_xy && in_z) m |= 1 << b;
        }
        return m;
    }

    void navier_slip(int g) {
        static const int NORMALS[4][3] = {{1, 1, 1}, {0, 1, 1}, {2, 1, 1}, {2, -1, 0}};  // axis, sign, face
        const int n_walls = D == 3 ? 4 : 2;
        const Window& w = win[g];
        float* G0 = grid[g].data();
        const int n1 = D == 3 ? w.n[1] : 1, nl = w.n[L];
        int idx[3] = {0, 0, 0};
        for (int r = 0; r < w.n[0] * n1; r++) {
            idx[0] = r / n1;
            if (D == 3) idx[1] = r % n1;
            unsigned char mr = D == 3 ? (axis_mask[0][idx[0]] & axis_mask[1][idx[1]]) : (axis_mask[0][idx[0]] & zmask2d);
            if (!mr) continue;  // no wall along this row
            for (int k = 0; k < nl; k++) {
                int m = mr & axis_mask[L][k];  // the boxes holding the node (the grid update's test)
                float* q = G0 + ((long)r * nl + k) * 4;
                if (!m || !(q[D] > 0)) continue;
                idx[L] = k;
                float pos[3] = {0, 0, 0};
                for (int a = 0; a < D; a++) pos[a] = (float)(idx[a] + w.org[a]) * P.dx;
                float vel[3] = {0, 0, 0};
                if ((m & (m - 1)) == 0) {  // exactly one wall
                    int b = __builtin_ctz(m);
                    if (b < n_walls) {
                        int axis = NORMALS[b][0], sign = NORMALS[b][1], face = NORMALS[b][2];
                        float s = sign * (pos[axis] - P.boxes[b][face][axis]);  // <= 0: inside the wall
                        int kk = (int)std::floor(-s * inv_dx) + 1;  // nodes to the first one outside
                        int j = idx[axis] + sign * kk;
                        if (0 <= j && j < w.n[axis]) {
                            float fpos[3] = {pos[0], pos[1], pos[2]};
                            fpos[axis] += sign * kk * P.dx;
                            if (!boxes_holding(fpos)) {
                                const float* gf = q + (long)sign * kk * w.stride[axis] * 4;
                                float f = std::max(P.slip + s, 0.0f) / (P.slip + s + kk * P.dx);  // Navier profile
                                for (int a = 0; a < D; a++)
                                    if (a != axis) vel[a] = gf[a] * f;
                            }
                        }
                    }
                }
                for (int a = 0; a < D; a++) q[a] = vel[a];
            }
        }
    }

    // ---------------------------------------------------------------------------------------------------
    // 3. G2P: v_p = sum w v_i, C_p = sum v_i (x) grad w (and the grid density with the correction)
    // the uGIMP weights of the block at p at its stored positions and stencil nodes
    void block_weights(int p, Scatter& sb) {
        for (int a = 0; a < D; a++) {
            V fx = vload(&x[a][p]) * inv_dx - tofloat(vloadi(&base[a][p]));
            Weights wt = ugimp(fx, P.lh);
            vstore(sb.fx[a], fx);
            for (int k = 0; k < 3; k++) vstore(sb.w[a][k], wt.w[k]), vstore(sb.dw[a][k], wt.dw[k]);
            if (a == L) weight_rows(sb, wt.w, wt.dw);  // (AVX-512: as rows 0 and 1 of every lane)
        }
    }

    // each lane's stencil node 0 in window g, for the block at p; true if a live lane's stencil leaves the window
    bool block_nodes(int p, int cnt, int g, Scatter& sb) {
        const Window& w = win[g];
        VI k{}, out{};
        for (int a = 0; a < D; a++) {
            VI b = vloadi(&base[a][p]) - w.org[a];
            out |= (b < 0) | (b > w.n[a] - 3);
            k += b * w.stride[a];
        }
        vstorei(sb.node0, k);
        return any(out & (vloadi(IOTA_) < cnt));
    }

    void gather_lane(int i, int g, const Scatter& sb, Block& blk) {
        const Window& w = win[g];
        const float* gr = &grid[g][(long)sb.node0[i] * 4];
        float wt[D][3], dw[D][3];
        for (int a = 0; a < D; a++)
            for (int k = 0; k < 3; k++) wt[a][k] = sb.w[a][k][i], dw[a][k] = sb.dw[a][k][i];
        V Wk, DWk;
        node_weights(sb, i, Wk, DWk);
        // the weights are a tensor product: sum over the last leading axis first
        V VP, BL, BA[D - 1];
        if constexpr (D == 3) {
            V T1{}, T2{}, T3{};
            for (int a0 = 0; a0 < 3; a0++) {
                V g0 = row_load(gr + w.row[3 * a0]), g1 = row_load(gr + w.row[3 * a0 + 1]), g2 = row_load(gr + w.row[3 * a0 + 2]);
                V S1 = wt[1][0] * g0 + wt[1][1] * g1 + wt[1][2] * g2;  // sum_a1 w1 v
                V S2 = dw[1][0] * g0 + dw[1][1] * g1 + dw[1][2] * g2;  // sum_a1 dw1 v
                T1 += wt[0][a0] * S1;
                T2 += dw[0][a0] * S1;
                T3 += wt[0][a0] * S2;
            }
            VP = Wk * T1, BA[0] = Wk * T2, BA[1] = Wk * T3, BL = DWk * T1;
        } else {
            V T1{}, T2{};
            for (int a0 = 0; a0 < 3; a0++) {
                V g = row_load(gr + w.row[a0]);
                T1 += wt[0][a0] * g;
                T2 += dw[0][a0] * g;
            }
            VP = Wk * T1, BA[0] = Wk * T2, BL = DWk * T1;
        }
        gather_rows(blk, i, VP, BL, BA, inv_dx);
    }

    // ---------------------------------------------------------------------------------------------------
    // The fused pass of one step over a slice: G2P from grid A, constitutive update, walls, advection,
    // then (scatter) P2G into copy t of grid B for the next step of the same dt.
    struct SliceOut {
        int lo[3], hi[3];
        float vmax2 = 0;
        bool nan = false, miss = false;
    };

    void step_slice(int t, float dt, bool scatter, SliceOut& so) {
        const int A = cur, Bg = 1 - cur;
        Block blk;
        Scatter sb;
        VI lov[3], hiv[3];
        for (int a = 0; a < D; a++) lov[a] = splati(INT_BIG), hiv[a] = splati(-INT_BIG);
        V vmax2{};
        VI nan{};
        bool miss = false;
        const float dx3 = D == 3 ? inv_dx * inv_dx * inv_dx : inv_dx * inv_dx;
        for (int p = slice(t); p < slice(t + 1); p += W) {
            int cnt = N - p < W ? N - p : W;
            if (cnt <= 0) break;
            block_weights(p, sb);
            block_nodes(p, cnt, A, sb);
            for (int i = 0; i < cnt; i++) gather_lane(i, A, sb, blk);
            gather_finish(blk, cnt, inv_dx);
            VI live = vloadi(IOTA_) < cnt;
            // elastic predictor b* = F b F^T, F = I + dt C (eq. 52)
            V F[3][3];
            for (int r = 0; r < 3; r++)
                for (int c = 0; c < 3; c++) F[r][c] = splat(r == c ? 1.0f : 0.0f);
            V Bm[D][D];
            for (int r = 0; r < D; r++)
                for (int c = 0; c < D; c++) Bm[r][c] = vload(blk.B[r][c]), F[r][c] += dt * Bm[r][c];
            Sym b_old;
            for (int c = 0; c < 6; c++) b_old.a[c] = vload(&be[c][p]);
            V iso_old = vload(&iso[p]), loge_old = vload(&loge[p]);
            Sym b_trial = sandwich(F, b_old);
            if (P.dens) {  // density correction: lower J to the one the spacing implies where particles crowd
                V crowd = vload(blk.mass) * (dx3 * P.vol / P.mp);  // rho_p / rho_0
                V detF = D == 3 ? F[0][0] * (F[1][1] * F[2][2] - F[1][2] * F[2][1]) -
                                      F[0][1] * (F[1][0] * F[2][2] - F[1][2] * F[2][0]) +
                                      F[0][2] * (F[1][0] * F[2][1] - F[1][1] * F[2][0])
                                : F[0][0] * F[1][1] - F[0][1] * F[1][0];
                V js = detF / crowd;
                V det_trial = sym_det(b_trial);
                VI lower = (crowd > 1.0f) & (js * js < det_trial);
                if (any(lower)) b_trial = sym_scale(b_trial, sel(lower, vrcbrt(det_trial / (js * js)), splat(1.0f)));
            }
            // eq. 57, identity when elastic; the Newton solve starts from the particle's last log(e)
            Mapped mp = return_mapping(b_trial, b_old, iso_old, P.mu, P.eta, P.n, P.sy, dt, loge_old, rule, live,
                                       P.newton_iterations, P.newton_tol, P.no_warm_start);
            // walls, tested at the pre-advection position
            V xp[D];
            for (int a = 0; a < D; a++) xp[a] = vload(&x[a][p]);
            V z = D == 3 ? xp[D - 1] : splat(P.zmid);
            VI f = vloadi(&flags[p]);
            VI hidden = (f & HIDDEN) != 0, frozen{};
            for (int b = 0; b < 4; b++) {  // each box tested on all 16 lanes
                const float(*bx)[3] = P.boxes[b];
                VI in_xy = (bx[0][0] <= xp[0]) & (xp[0] <= bx[1][0]) & (bx[0][1] <= xp[1]) & (xp[1] <= bx[1][1]);
                VI in_z = (bx[0][2] <= z) & (z <= bx[1][2]);
                hidden = seli(in_xy, in_z, hidden);  // the last box containing (x, y) decides visibility
                frozen |= in_xy & in_z;
            }
            f = (f | (mp.plastic & PLASTIC)) & ~(HIDDEN | FROZEN);
            f |= (hidden & HIDDEN) | (frozen & FROZEN);
            vstorei(&flags[p], f);
            Sym be_new = mp.be;
            V iso_new = mp.iso, loge_new = mp.log_e;
            if (P.slipping && any(frozen)) {
                // the coating inside a slipping wall does not deform
                be_new = sym_select(frozen, b_old, be_new);
                iso_new = sel(frozen, iso_old, iso_new);
                loge_new = sel(frozen, loge_old, loge_new);
            }
            for (int c = 0; c < 6; c++) vstore(&be[c][p], be_new.a[c]);
            vstore(&iso[p], iso_new);
            vstore(&loge[p], loge_new);
            V speed2{};
            for (int a = 0; a < D; a++) {
                V va = sel(frozen, V{}, vload(blk.vp[a]));
                V xn = xp[a] + dt * va;
                vstore(&x[a][p], xn);
                vstore(&v[a][p], va);
                speed2 += va * va;
                nan |= live & (xn != xn);
                VI b = vfloor_i(xn * inv_dx - P.lh);
                vstorei(&base[a][p], b);
                lov[a] = seli(live & (b < lov[a]), b, lov[a]);
                hiv[a] = seli(live & (b > hiv[a]), b, hiv[a]);
            }
            vmax2 = sel(live & (speed2 > vmax2), speed2, vmax2);
            for (int r = 0; r < D; r++)
                for (int c = 0; c < D; c++) vstore(&C[r * D + c][p], sel(frozen, V{}, Bm[r][c]));
            if (scatter && !miss) {
                scatter_prepare(p, dt, sb);
                miss = block_nodes(p, cnt, Bg, sb);  // then P2G runs again on the exact window
                if (!miss)
                    for (int i = 0; i < cnt; i++) scatter_lane(i, sb, Bg, t);
            }
        }
        for (int a = 0; a < D; a++) {
            so.lo[a] = INT_BIG, so.hi[a] = -INT_BIG;
            for (int i = 0; i < W; i++) {
                so.lo[a] = lov[a][i] < so.lo[a] ? lov[a][i] : so.lo[a];
                so.hi[a] = hiv[a][i] > so.hi[a] ? hiv[a][i] : so.hi[a];
            }
        }
        so.vmax2 = 0;
        for (int i = 0; i < W; i++) so.vmax2 = vmax2[i] > so.vmax2 ? vmax2[i] : so.vmax2;
        so.nan = any(nan);
        so.miss = miss;
    }

    // one step after grid A's update: returns 0, or the error code (ERR_NAN, ERR_LEFT_REACH)
    int step(float dt, bool scatter) {
        std::vector<SliceOut> outs(T);
        if (scatter) open_window(1 - cur, 1);
        parallel(T, [&](int t) { step_slice(t, dt, scatter, outs[t]); });
        bool miss = false, nan = false;
        float vm2 = 0;
        for (int a = 0; a < D; a++) lo[a] = INT_BIG, hi[a] = -INT_BIG;
        for (auto& so : outs) {
            miss |= so.miss, nan |= so.nan;
            vm2 = so.vmax2 > vm2 ? so.vmax2 : vm2;
            for (int a = 0; a < D; a++) lo[a] = std::min(lo[a], so.lo[a]), hi[a] = std::max(hi[a], so.hi[a]);
        }
        vmax = std::sqrt(vm2);
        if (nan) return ERR_NAN;
        if (scatter) {
            if (outside_reach()) return ERR_LEFT_REACH;
            cur = 1 - cur;
            if (miss) {  // a stencil left the margin: P2G again on a window from the exact box
                refills++;
                open_window(cur, 0);
                p2g_pass(cur, dt);
            }
        }
        return 0;
    }
    long refills = 0;

    // particles sorted by their stencil node (x slowest, the last axis fastest): neighbours in memory scatter
    // into neighbouring nodes
    void sort_particles() {
        const Window& w = win[cur];
        std::vector<int> key(N), start(w.count + 1, 0), order(N);
        for (int p = 0; p < N; p++) {
            long k = 0;
            for (int a = 0; a < D; a++) k += (long)(base[a][p] - w.org[a]) * w.stride[a];
            key[p] = (int)k;
            start[k + 1]++;
        }
        for (long k = 0; k < w.count; k++) start[k + 1] += start[k];
        for (int p = 0; p < N; p++) order[start[key[p]]++] = p;
        // all fields of particle order[p] into slot p of the spare region (lanes past N stay), then swap
        const char* from = static_cast<const char*>(store.ptr);
        char* to = static_cast<char*>(spare.ptr);
        for (int p = 0; p < NP; p++) {
            const char* src = from + slot(p < N ? order[p] : p) * 4;
            char* dst = to + slot(p) * 4;
            for (int f = 0; f < NF; f++) std::memcpy(dst + f * W * 4, src + f * W * 4, 4);
        }
        std::swap(store.ptr, spare.ptr);
        bind();
    }

    // ---------------------------------------------------------------------------------------------------
    // the whole simulation: frames at P.frame_times, the time step from the CFL condition (substeps, types.h)
    // re-evaluated P.substeps times per frame interval
    Result run(Outputs out, ProgressFn progress, void* ctx) {
        Result res;
        double t = 0.0;
        for (int k = 0; k < P.n_frames; k++) {
            double t_prev = k / P.fps, t_frame = P.frame_times[k];
            for (int sub = 0; sub < P.substeps; sub++) {
                double t_target = t_prev + (sub + 1) * (t_frame - t_prev) / P.substeps;
                double vm = (double)vmax;
                if (!std::isfinite(vm) || vm > P.speed_limit) {
                    res.error = ERR_SPEED, res.error_value = vm;
                    return finish(res);
                }
                res.vmax_seen = std::max(res.vmax_seen, vm);
                const Substeps sched = substeps(t, t_target, vm, P.dx, P.wave_speed, P.gravity, P.cfl);
                const long m = sched.m;
                const double dt = sched.dt;
                float dtf = (float)dt;
                if (outside_reach()) {
                    res.error = ERR_LEFT_REACH;
                    return finish(res);
                }
                open_window(cur, 0);
                sort_particles();
                res.sorts++;
                p2g_pass(cur, dtf);
                for (long s = 1; s <= m; s++) {
                    grid_update(cur, dtf);
                    int err = step(dtf, s < m);
                    if (err) {
                        res.error = err;
                        return finish(res);
                    }
                    res.steps++;
                }
                res.dt_min = std::min(res.dt_min, dt), res.dt_max = std::max(res.dt_max, dt);
                t = t_target;
            }
            write_frame(k, out);
            if (progress && progress(ctx, k + 1)) {
                res.error = ERR_INTERRUPTED;
                return finish(res);
            }
        }
        return finish(res);
    }
    Result finish(Result r) {
        r.refills = refills;
        return r;
    }

    void write_frame(int k, const Outputs& out) {
        float* fx = out.frames_x + (size_t)k * N * D;
        unsigned char* ff = out.frames_flags + (size_t)k * N;
        double js = 0;
        long moving = 0;
        for (int p = 0; p < N; p++) {
            int q = id[p];
            for (int a = 0; a < D; a++) fx[(size_t)q * D + a] = x[a][p];
            ff[q] = (unsigned char)flags[p];
            if (!(flags[p] & FROZEN)) {
                double a0 = be[0][p], a1 = be[1][p], a2 = be[2][p], a3 = be[3][p], a4 = be[4][p], a5 = be[5][p];
                double det = a0 * (a1 * a2 - a5 * a5) - a3 * (a3 * a2 - a5 * a4) + a4 * (a3 * a5 - a1 * a4);
                js += std::sqrt(std::fabs(det));
                moving++;
            }
        }
        out.mean_j[k] = moving ? js / moving : 1.0;
        double mass = 0;
        const Window& w = win[cur];
        const float* g = grid[cur].data();
        for (long i = 0; i < w.count; i++) mass += g[i * 4 + D];
        out.grid_mass[k] = mass;
    }
};

// ---------------------------------------------------------------------------------------------------------
// entry points of this instruction set

static Result simulate(const Params& p, const double* pos, const int* flags0, int n, Outputs out,
                       ProgressFn progress, void* ctx) {
    if (p.dim == 3) {
        Engine<3> e;
        e.init(p, pos, flags0, n);
        return e.run(out, progress, ctx);
    }
    Engine<2> e;
    e.init(p, pos, flags0, n);
    return e.run(out, progress, ctx);
}

// mpm.constitutive.return_mapping over a batch: be_trial, be_old (N, 3, 3); par (N, 6) = mu, eta, n, sigma_y,
// dt, log_e0; rule: the flow rule's (alpha, beta, c). Writes the new b_e (N, 3, 3), plastic flags and log(e).
static void return_mapping_batch(const float* bt, const float* bo, const float* par, int n, Rule rule, int iterations,
                                 float newton_tol, float no_warm_start, float* out, int* plastic, float* log_e) {
    const int pi[6] = {0, 1, 2, 0, 0, 1}, pj[6] = {0, 1, 2, 1, 2, 2};
    for (int i = 0; i < n; i++) {  // one lane per call: the parameters may differ per entry
        Sym t, o;
        for (int c = 0; c < 6; c++) t.a[c] = splat(bt[i * 9 + pi[c] * 3 + pj[c]]), o.a[c] = splat(bo[i * 9 + pi[c] * 3 + pj[c]]);
        const float* q = par + i * 6;
        V iso_old = iso_factor(sym_det(o));
        Mapped m = return_mapping(t, o, iso_old, q[0], q[1], q[2], q[3], q[4], splat(q[5]), rule, splati(-1), iterations,
                                  newton_tol, no_warm_start);
        for (int c = 0; c < 6; c++) {
            out[i * 9 + pi[c] * 3 + pj[c]] = m.be.a[c][0];
            out[i * 9 + pj[c] * 3 + pi[c]] = m.be.a[c][0];
        }
        plastic[i] = m.plastic[0] != 0;
        log_e[i] = m.log_e[0];
    }
}

#undef VH_INLINE
#undef NODE0
#undef NODE1
#undef NODE2
#undef COMP
}  // namespace VIRHEO_ISA
