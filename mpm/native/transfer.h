// The transfers' instruction-set layer: how one particle's stencil-row operands are formed (P2G) and its row sums
// handed back (G2P). With AVX-512 a particle's operands and results pass through 4-float rows per lane, which
// 512-bit permutes turn into 16-lane fields and back once per block; on the narrower paths (AVX2, SSE2, NEON) they
// are read and written lane by lane. kernel.h's P2G and G2P call only what is below; nothing else there depends on
// the instruction set. Included by kernel.h inside its instruction set's namespace, after ugimp.

// per-lane quantities of P2G for a block of W particles (kernel.h's block_weights and scatter_prepare fill them)
template <int D>
struct ScatterBlock {
    alignas(64) float fx[D][W], w[D][3][W], dw[D][3][W], u[D][W], mC[D][D][W], S[D][D][W];
    alignas(64) int node0[W];  // each lane's stencil node 0 in the window (block_nodes)
#if VIRHEO_VEC_BYTES == 64
    // per lane, 4-float rows (a node's components): the weights w and dw along L (node k in place k), the
    // momentum u with the mass, and the columns of m C and S (column L, then 0 .. L-1), component r in place r
    alignas(64) float rows[4 + 2 * D][W][4];
#endif
};

// G2P's results for a block: velocity, velocity gradient C_p, grid mass at the particle
template <int D>
struct GatherBlock {
    alignas(64) float vp[D][W], B[D][D][W], mass[W];
#if VIRHEO_VEC_BYTES == 64
    alignas(64) float rows[4][W][4];  // gather_rows's row sums per lane: (v, m), grad along L, along 0, 1
#endif
};

// row_terms gives the operands of lane i's stencil rows in P2G: the weights along the last axis L on nodes 0..2
// (Wk), k times them (KWk) and their derivatives (DWk); the momentum with the mass (CU), the columns of m C (Qb) and
// S (Rb) along L on every node; per leading axis a, Wk times the columns a of m C (A[a]) and of S (G[a]). (Out
// parameters, not a returned struct: a struct of twelve 64-byte values stays in memory on the narrower paths.)

#if VIRHEO_VEC_BYTES == 64
// 16 rows of 4 floats (lane i's row at in[i]) -> 4 fields of 16 lanes (component c in comp[c])
VH_INLINE void rows_to_lanes(const float (*in)[4], V comp[4]) {
    V z[4];
    for (int k = 0; k < 4; k++) z[k] = vload(in[4 * k]);
    V lo01 = __builtin_shufflevector(z[0], z[1], 0, 4, 8, 12, 16, 20, 24, 28, 1, 5, 9, 13, 17, 21, 25, 29);
    V hi01 = __builtin_shufflevector(z[0], z[1], 2, 6, 10, 14, 18, 22, 26, 30, 3, 7, 11, 15, 19, 23, 27, 31);
    V lo23 = __builtin_shufflevector(z[2], z[3], 0, 4, 8, 12, 16, 20, 24, 28, 1, 5, 9, 13, 17, 21, 25, 29);
    V hi23 = __builtin_shufflevector(z[2], z[3], 2, 6, 10, 14, 18, 22, 26, 30, 3, 7, 11, 15, 19, 23, 27, 31);
    comp[0] = __builtin_shufflevector(lo01, lo23, 0, 1, 2, 3, 4, 5, 6, 7, 16, 17, 18, 19, 20, 21, 22, 23);
    comp[1] = __builtin_shufflevector(lo01, lo23, 8, 9, 10, 11, 12, 13, 14, 15, 24, 25, 26, 27, 28, 29, 30, 31);
    comp[2] = __builtin_shufflevector(hi01, hi23, 0, 1, 2, 3, 4, 5, 6, 7, 16, 17, 18, 19, 20, 21, 22, 23);
    comp[3] = __builtin_shufflevector(hi01, hi23, 8, 9, 10, 11, 12, 13, 14, 15, 24, 25, 26, 27, 28, 29, 30, 31);
}
// its inverse: 4 fields of 16 lanes -> 16 rows of 4 floats (lane i's row at out[i])
VH_INLINE void lanes_to_rows(V c0, V c1, V c2, V c3, float (*out)[4]) {
    V a01 = __builtin_shufflevector(c0, c1, 0, 16, 1, 17, 2, 18, 3, 19, 4, 20, 5, 21, 6, 22, 7, 23);
    V b01 = __builtin_shufflevector(c0, c1, 8, 24, 9, 25, 10, 26, 11, 27, 12, 28, 13, 29, 14, 30, 15, 31);
    V a23 = __builtin_shufflevector(c2, c3, 0, 16, 1, 17, 2, 18, 3, 19, 4, 20, 5, 21, 6, 22, 7, 23);
    V b23 = __builtin_shufflevector(c2, c3, 8, 24, 9, 25, 10, 26, 11, 27, 12, 28, 13, 29, 14, 30, 15, 31);
    vstore(out[0], __builtin_shufflevector(a01, a23, 0, 1, 16, 17, 2, 3, 18, 19, 4, 5, 20, 21, 6, 7, 22, 23));
    vstore(out[4], __builtin_shufflevector(a01, a23, 8, 9, 24, 25, 10, 11, 26, 27, 12, 13, 28, 29, 14, 15, 30, 31));
    vstore(out[8], __builtin_shufflevector(b01, b23, 0, 1, 16, 17, 2, 3, 18, 19, 4, 5, 20, 21, 6, 7, 22, 23));
    vstore(out[12], __builtin_shufflevector(b01, b23, 8, 9, 24, 25, 10, 11, 26, 27, 12, 13, 28, 29, 14, 15, 30, 31));
}
// a row of 4 floats as a stencil row: (r0 x4, r1 x4, r2 x4, r3 x4), and (r0, r1, r2, r3) on each of the 4 nodes
VH_INLINE V per_node(const float* r) {
    return (V)_mm512_permutexvar_ps(_mm512_set_epi32(3, 3, 3, 3, 2, 2, 2, 2, 1, 1, 1, 1, 0, 0, 0, 0),
                                    _mm512_castps128_ps512(_mm_loadu_ps(r)));
}
VH_INLINE V on_every_node(const float* r) { return (V)_mm512_broadcast_f32x4(_mm_loadu_ps(r)); }

// the weights along L (nodes 0..2) as rows 0 and 1 of every lane
template <int D>
VH_INLINE void weight_rows(ScatterBlock<D>& sb, const V w[3], const V dw[3]) {
    lanes_to_rows(w[0], w[1], w[2], V{}, sb.rows[0]);
    lanes_to_rows(dw[0], dw[1], dw[2], V{}, sb.rows[1]);
}

// the momentum with the mass and the columns of m C and S as rows of every lane (after scatter_prepare's fields)
template <int D>
VH_INLINE void scatter_rows(ScatterBlock<D>& sb, float mp) {
    constexpr int L = D - 1;
    const V zero{};
    auto put = [&](int q, auto f) {  // row q of every lane from its components f(0) .. f(3)
        lanes_to_rows(f(0), f(1), f(2), f(3), sb.rows[q]);
    };
    put(2, [&](int r) { return r < D ? vload(sb.u[r]) : r == D ? splat(mp) : zero; });
    for (int j = 0; j < D; j++) {  // column a = L, 0, .., L-1
        const int a = j == 0 ? L : j - 1;
        put(3 + 2 * j, [&](int r) { return r < D ? vload(sb.mC[r][a]) : zero; });
        put(4 + 2 * j, [&](int r) { return r < D ? vload(sb.S[r][a]) : zero; });
    }
}

template <int D>
VH_INLINE void row_terms(const ScatterBlock<D>& sb, int i, float, V& Wk, V& KWk, V& DWk, V& CU, V& Qb, V& Rb, V* A,
                         V* G) {
    constexpr int L = D - 1;
    const float(*rows)[W][4] = sb.rows;
    Wk = per_node(rows[0][i]), DWk = per_node(rows[1][i]), KWk = Wk * vload(NODE_INDEX_);
    CU = on_every_node(rows[2][i]), Qb = on_every_node(rows[3][i]), Rb = on_every_node(rows[4][i]);
    for (int a = 0; a < L; a++) {
        A[a] = Wk * on_every_node(rows[5 + 2 * a][i]);
        G[a] = Wk * on_every_node(rows[6 + 2 * a][i]);
    }
}

// G2P: lane i's weights along L on nodes 0..2 (Wk) and their derivatives (DWk)
template <int D>
VH_INLINE void node_weights(const ScatterBlock<D>& sb, int i, V& Wk, V& DWk) {
    Wk = per_node(sb.rows[0][i]), DWk = per_node(sb.rows[1][i]);
}

// G2P: lane i's row sums (velocity and mass VP, the gradient along L (BL) and along each leading axis (BA)), kept as
// its 4-float rows; gather_finish turns the block's rows into lanes
template <int D>
VH_INLINE void gather_rows(GatherBlock<D>& blk, int i, V VP, V BL, const V* BA, float) {
    constexpr int L = D - 1;
    V4 rows[4] = {node_sum(VP), node_sum(BL), {}, {}};
    for (int a = 0; a < L; a++) rows[2 + a] = node_sum(BA[a]);
    for (int q = 0; q < 4; q++) __builtin_memcpy(blk.rows[q][i], &rows[q], sizeof(V4));
}

// after gather_rows of lanes 0..cnt-1: the lanes past the last particle at rest, and the rows of 4 floats per lane
// turned into 16-lane fields (rows_to_lanes); C_p = grad v
template <int D>
VH_INLINE void gather_finish(GatherBlock<D>& blk, int cnt, float inv_dx) {
    constexpr int L = D - 1;
    for (int i = cnt; i < W; i++)
        for (int q = 0; q < 4; q++)
            for (int c = 0; c < 4; c++) blk.rows[q][i][c] = 0;
    for (int q = 0; q < 2 + L; q++) {
        V comp[4];
        rows_to_lanes(blk.rows[q], comp);
        if (q == 0) {  // velocity and mass
            for (int r = 0; r < D; r++) vstore(blk.vp[r], comp[r]);
            vstore(blk.mass, comp[D]);
        } else {  // C_p = grad v: column L from BL (q = 1), column a from BA[a] (q = 2 + a)
            const int col = q == 1 ? L : q - 2;
            for (int r = 0; r < D; r++) vstore(blk.B[r][col], comp[r] * inv_dx);
        }
    }
}

#else  // narrower registers: lane by lane
template <int D>
VH_INLINE void weight_rows(ScatterBlock<D>&, const V*, const V*) {}

template <int D>
VH_INLINE void scatter_rows(ScatterBlock<D>&, float) {}

template <int D>
VH_INLINE void row_terms(const ScatterBlock<D>& sb, int i, float mp, V& Wk, V& KWk, V& DWk, V& CU, V& Qb, V& Rb, V* A,
                         V* G) {
    constexpr int L = D - 1;
    const float w0 = sb.w[L][0][i], w1 = sb.w[L][1][i], w2 = sb.w[L][2][i];
    Wk = w0 * NODE0 + w1 * NODE1 + w2 * NODE2;
    KWk = w1 * NODE1 + (2.0f * w2) * NODE2;
    DWk = sb.dw[L][0][i] * NODE0 + sb.dw[L][1][i] * NODE1 + sb.dw[L][2][i] * NODE2;
    CU = mp * COMP(D), Qb = V{}, Rb = V{};
    for (int r = 0; r < D; r++) {
        CU += sb.u[r][i] * COMP(r);
        Qb += sb.mC[r][L][i] * COMP(r);
        Rb += sb.S[r][L][i] * COMP(r);
    }
    for (int a = 0; a < L; a++) {
        V ma{}, sa{};
        for (int r = 0; r < D; r++) ma += sb.mC[r][a][i] * COMP(r), sa += sb.S[r][a][i] * COMP(r);
        A[a] = Wk * ma;
        G[a] = Wk * sa;
    }
}

template <int D>
VH_INLINE void node_weights(const ScatterBlock<D>& sb, int i, V& Wk, V& DWk) {
    constexpr int L = D - 1;
    Wk = sb.w[L][0][i] * NODE0 + sb.w[L][1][i] * NODE1 + sb.w[L][2][i] * NODE2;
    DWk = sb.dw[L][0][i] * NODE0 + sb.dw[L][1][i] * NODE1 + sb.dw[L][2][i] * NODE2;
}

template <int D>
VH_INLINE void gather_rows(GatherBlock<D>& blk, int i, V VP, V BL, const V* BA, float inv_dx) {
    constexpr int L = D - 1;
    V4 vp = node_sum(VP), bl = node_sum(BL) * inv_dx, ba[D - 1];
    for (int a = 0; a < L; a++) ba[a] = node_sum(BA[a]) * inv_dx;
    for (int r = 0; r < D; r++) {
        blk.vp[r][i] = vp[r];
        for (int a = 0; a < L; a++) blk.B[r][a][i] = ba[a][r];
        blk.B[r][L][i] = bl[r];  // C_p = grad v
    }
    blk.mass[i] = vp[D];
}

template <int D>
VH_INLINE void gather_finish(GatherBlock<D>& blk, int cnt, float) {
    for (int i = cnt; i < W; i++) {  // lanes past the last particle: at rest
        for (int r = 0; r < D; r++) {
            blk.vp[r][i] = 0;
            for (int c = 0; c < D; c++) blk.B[r][c][i] = 0;
        }
        blk.mass[i] = 0;
    }
}
#endif
