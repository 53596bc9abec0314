// The 16-lane vector layer of the native engine: the value types V (float) and VI (int32), their loads, stores,
// selects and rounding, exp, log and x^(-1/3) in float32, and the lane patterns of a stencil row. Everything that
// differs between instruction sets below the transfers lives here (engine.cpp sets VIRHEO_VEC_BYTES, the register
// width: 64 for AVX-512, 32 for AVX2, 16 for SSE2 and NEON); kernel.h includes it inside its instruction set's
// namespace.

constexpr int W = 16;  // lanes of a block
typedef float V4 __attribute__((vector_size(16)));

#define VH_INLINE static inline __attribute__((always_inline))

// The 16-lane values V (float) and VI (int32). With AVX-512 one register each (GCC's vector extension); on
// narrower instruction sets a pack of native registers with the same operators: GCC lowers a 64-byte vector
// type that the target lacks through the stack, which made those paths several times slower than scalar code.
// engine.cpp sets VIRHEO_VEC_BYTES, the register width of the instruction set.
#if VIRHEO_VEC_BYTES == 64
typedef float V __attribute__((vector_size(64)));
typedef int VI __attribute__((vector_size(64)));
VH_INLINE VI asi(V a) { return (VI)a; }
VH_INLINE V asf(VI a) { return (V)a; }
VH_INLINE VI to_int(V a) { return __builtin_convertvector(a, VI); }  // truncation
VH_INLINE V tofloat(VI a) { return __builtin_convertvector(a, V); }
VH_INLINE V vsqrt(V a) {
    V r;
    for (int i = 0; i < W; i++) r[i] = __builtin_sqrtf(a[i]);
    return r;
}
#else
typedef float NF __attribute__((vector_size(VIRHEO_VEC_BYTES)));
typedef int NI __attribute__((vector_size(VIRHEO_VEC_BYTES)));
constexpr int NL = VIRHEO_VEC_BYTES / 4, K = W / NL;  // lanes per register, registers per value
struct VI {
    NI r[K];
    int operator[](int i) const { return r[i / NL][i % NL]; }
};
struct V {
    NF r[K];
    float operator[](int i) const { return r[i / NL][i % NL]; }
    float& operator[](int i) { return reinterpret_cast<float*>(r)[i]; }
};
#define VH_BIN(T, R, op)                                                       \
    VH_INLINE R operator op(const T& a, const T& b) {                          \
        R o;                                                                   \
        for (int k = 0; k < K; k++) o.r[k] = a.r[k] op b.r[k];                 \
        return o;                                                              \
    }
#define VH_SCALAR(T, S, R, op)                                                 \
    VH_INLINE R operator op(const T& a, S b) {                                 \
        R o;                                                                   \
        for (int k = 0; k < K; k++) o.r[k] = a.r[k] op b;                      \
        return o;                                                              \
    }                                                                          \
    VH_INLINE R operator op(S a, const T& b) {                                 \
        R o;                                                                   \
        for (int k = 0; k < K; k++) o.r[k] = a op b.r[k];                      \
        return o;                                                              \
    }
#define VH_ARITH(T, S, op) VH_BIN(T, T, op) VH_SCALAR(T, S, T, op)              \
    VH_INLINE T& operator op##=(T& a, const T& b) { return a = a op b; }         \
    VH_INLINE T& operator op##=(T& a, S b) { return a = a op b; }
#define VH_CMP(T, S, op) VH_BIN(T, VI, op) VH_SCALAR(T, S, VI, op)
VH_ARITH(V, float, +) VH_ARITH(V, float, -) VH_ARITH(V, float, *) VH_ARITH(V, float, /)
VH_CMP(V, float, <) VH_CMP(V, float, >) VH_CMP(V, float, <=) VH_CMP(V, float, >=) VH_CMP(V, float, ==)
VH_CMP(V, float, !=)
VH_ARITH(VI, int, +) VH_ARITH(VI, int, -) VH_ARITH(VI, int, *) VH_ARITH(VI, int, &) VH_ARITH(VI, int, |)
VH_CMP(VI, int, <) VH_CMP(VI, int, >) VH_CMP(VI, int, ==) VH_CMP(VI, int, !=)
VH_SCALAR(VI, int, VI, <<) VH_SCALAR(VI, int, VI, >>)
#undef VH_BIN
#undef VH_SCALAR
#undef VH_ARITH
#undef VH_CMP
VH_INLINE V operator-(const V& a) {
    V o;
    for (int k = 0; k < K; k++) o.r[k] = -a.r[k];
    return o;
}
VH_INLINE VI operator~(const VI& a) {
    VI o;
    for (int k = 0; k < K; k++) o.r[k] = ~a.r[k];
    return o;
}
VH_INLINE VI asi(const V& a) {
    VI o;
    for (int k = 0; k < K; k++) o.r[k] = (NI)a.r[k];
    return o;
}
VH_INLINE V asf(const VI& a) {
    V o;
    for (int k = 0; k < K; k++) o.r[k] = (NF)a.r[k];
    return o;
}
VH_INLINE VI to_int(const V& a) {
    VI o;
    for (int k = 0; k < K; k++) o.r[k] = __builtin_convertvector(a.r[k], NI);
    return o;
}
VH_INLINE V tofloat(const VI& a) {
    V o;
    for (int k = 0; k < K; k++) o.r[k] = __builtin_convertvector(a.r[k], NF);
    return o;
}
VH_INLINE V vsqrt(const V& a) {
    V o;
    for (int k = 0; k < K; k++)
        for (int i = 0; i < NL; i++) o.r[k][i] = __builtin_sqrtf(a.r[k][i]);
    return o;
}
#endif

VH_INLINE V vload(const float* p) { V r; __builtin_memcpy(&r, p, sizeof(V)); return r; }
VH_INLINE VI vloadi(const int* p) { VI r; __builtin_memcpy(&r, p, sizeof(VI)); return r; }
VH_INLINE void vstore(float* p, V a) { __builtin_memcpy(p, &a, sizeof(V)); }
VH_INLINE void vstorei(int* p, VI a) { __builtin_memcpy(p, &a, sizeof(VI)); }
// A stencil row of the grid: nodes 0..2 of 4 floats each (a 4th node's lanes ride along in V). Below AVX-512 a
// row is read and written node by node, 16 bytes each, and the 4th node is neither read (its lanes are 0) nor
// written (P2G adds 0 there): a row that starts one node after the row last stored then reads what that store
// wrote (store-to-load forwarding; a 32-byte access straddling two earlier stores waits for both to retire).
#if VIRHEO_VEC_BYTES == 64
VH_INLINE V row_load(const float* p) { return vload(p); }
VH_INLINE void row_add(float* p, V row) { vstore(p, vload(p) + row); }
#else
VH_INLINE V4 node_load(const float* p) { V4 r; __builtin_memcpy(&r, p, 16); return r; }
VH_INLINE void node_store(float* p, V4 a) { __builtin_memcpy(p, &a, 16); }
#if VIRHEO_VEC_BYTES == 32
VH_INLINE V row_load(const float* p) {
    V r;
    r.r[0] = __builtin_shufflevector(node_load(p), node_load(p + 4), 0, 1, 2, 3, 4, 5, 6, 7);
    r.r[1] = __builtin_shufflevector(node_load(p + 8), V4{}, 0, 1, 2, 3, 4, 5, 6, 7);
    return r;
}
VH_INLINE void row_add(float* p, const V& row) {
    node_store(p, node_load(p) + __builtin_shufflevector(row.r[0], row.r[0], 0, 1, 2, 3));
    node_store(p + 4, node_load(p + 4) + __builtin_shufflevector(row.r[0], row.r[0], 4, 5, 6, 7));
    node_store(p + 8, node_load(p + 8) + __builtin_shufflevector(row.r[1], row.r[1], 0, 1, 2, 3));
}
#else
VH_INLINE V row_load(const float* p) {
    V r;
    for (int k = 0; k < 3; k++) r.r[k] = node_load(p + 4 * k);
    r.r[3] = NF{};
    return r;
}
VH_INLINE void row_add(float* p, const V& row) {
    for (int k = 0; k < 3; k++) node_store(p + 4 * k, node_load(p + 4 * k) + row.r[k]);
}
#endif
#endif
VH_INLINE V splat(float a) { return V{} + a; }
VH_INLINE VI splati(int a) { return VI{} + a; }
#if VIRHEO_VEC_BYTES == 64
// lane-wise m ? a : b (m: -1 or 0 per lane): one masked blend; the bitwise form below costs AVX-512 two operations
VH_INLINE V sel(VI m, V a, V b) { return m ? a : b; }
VH_INLINE VI seli(VI m, VI a, VI b) { return m ? a : b; }
#else
VH_INLINE V sel(VI m, V a, V b) { return asf((asi(a) & m) | (asi(b) & ~m)); }
VH_INLINE VI seli(VI m, VI a, VI b) { return (a & m) | (b & ~m); }
#endif
VH_INLINE V vabs(V a) { return asf(asi(a) & 0x7fffffff); }
VH_INLINE V vmin(V a, V b) { return sel(a < b, a, b); }
VH_INLINE V vmax(V a, V b) { return sel(a > b, a, b); }
#if VIRHEO_VEC_BYTES == 64
VH_INLINE bool any(VI m) {
    int r = 0;
    for (int i = 0; i < W; i++) r |= m[i];
    return r != 0;
}
#else
VH_INLINE bool any(const VI& m) {  // the registers OR-ed first: NL lane reads instead of W
    NI x = m.r[0];
    for (int k = 1; k < K; k++) x |= m.r[k];
    int r = 0;
    for (int i = 0; i < NL; i++) r |= x[i];
    return r != 0;
}
#endif
#if VIRHEO_VEC_BYTES == 64
VH_INLINE V vfloor(V a) { return (V)_mm512_roundscale_ps((__m512)a, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC); }
VH_INLINE VI vfloor_i(V a) { return to_int(vfloor(a)); }  // floor as int32, |a| < 2^31
VH_INLINE V times_pow2(V y, V n) { return (V)_mm512_scalef_ps((__m512)y, (__m512)n); }  // y 2^n, n integral
#else
VH_INLINE VI vfloor_i(V a) {  // floor as int32, |a| < 2^31
    VI t = to_int(a);
    return t + (tofloat(t) > a);  // the mask is -1 where truncation rounded up
}
VH_INLINE V vfloor(V a) { return tofloat(vfloor_i(a)); }
VH_INLINE V times_pow2(V y, V n) { return y * asf((to_int(n) + 127) << 23); }  // y 2^n, n integral in [-126, 127]
#endif

// exp and log in float32 (range reduction by powers of two, minimax polynomials on the reduced interval),
// branch-free so that all lanes run them at once; relative error a few ulp.
VH_INLINE V vexp(V x) {
    x = vmin(vmax(x, splat(-87.0f)), splat(88.0f));
    V fx = vfloor(x * 1.44269504088896341f + 0.5f);
    V r = x - fx * 0.693359375f + fx * 2.12194440e-4f;  // x - n ln 2, ln 2 in two parts
    // 1 + r + r^2 (c0 + c1 r + .. + c5 r^5), the polynomial by Estrin's scheme (short dependency chains)
    V r2 = r * r, r4 = r2 * r2;
    V q01 = 5.0000001201e-1f + 1.6666665459e-1f * r, q23 = 4.1665795894e-2f + 8.3334519073e-3f * r;
    V q45 = 1.3981999507e-3f + 1.9875691500e-4f * r;
    V p = (q01 + r2 * q23) + r4 * q45;
    V y = p * r2 + (r + 1.0f);
    return times_pow2(y, fx);
}

VH_INLINE V vlog(V x) {  // x > 0 and normal
    VI bits = asi(x);
    VI e = ((bits >> 23) & 0xff) - 126;
    V m = asf((bits & 0x007fffff) | 0x3f000000);  // mantissa in [0.5, 1)
    VI small = m < 0.707106781186547524f;
    e = e + small;  // the mask is -1: one binade down
    m = sel(small, m + m, m) - 1.0f;
    V z = m * m, z2 = z * z, z4 = z2 * z2;
    // c0 + c1 m + .. + c8 m^8 by Estrin's scheme
    V q01 = 3.3333331174e-1f - 2.4999993993e-1f * m, q23 = 2.0000714765e-1f - 1.6668057665e-1f * m;
    V q45 = 1.4249322787e-1f - 1.2420140846e-1f * m, q67 = 1.1676998740e-1f - 1.1514610310e-1f * m;
    V p = ((q01 + z * q23) + z2 * (q45 + z * q67)) + z4 * 7.0376836292e-2f;
    V fe = tofloat(e);
    V y = p * (m * z) - fe * 2.12194440e-4f - 0.5f * z;
    return m + y + fe * 0.693359375f;
}

// x^(-1/3) for x > 0 and normal, without a division: a guess from the float's bits (exponent / -3, 4 %), then
// two steps y <- y (1 + h/3 + 2h^2/9), h = 1 - x y^3 (the series of (1 - h)^(-1/3): cubic, 4 % -> 3e-4 -> 1 ulp)
VH_INLINE V vrcbrt(V x) {
    V y = asf(to_int(tofloat(asi(x)) * (-1.0f / 3.0f)) + 1419967116);
    for (int it = 0; it < 2; it++) {
        V h = 1.0f - (x * y) * (y * y);
        y = y + (y * h) * (1.0f / 3.0f + (2.0f / 9.0f) * h);
    }
    return y;
}

// Lane patterns of a stencil row: lane 4k + c is component c of node k (k = 0..2; lanes 12-15: a 4th node
// that receives + 0).
static const float NODE_[3][W] = {{1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0},
                                  {0, 0, 0, 0, 1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0, 0},
                                  {0, 0, 0, 0, 0, 0, 0, 0, 1, 1, 1, 1, 0, 0, 0, 0}};
static const float COMP_[4][W] = {{1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0},
                                  {0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0},
                                  {0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 0},
                                  {0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1}};
static const float NODE_INDEX_[W] = {0, 0, 0, 0, 1, 1, 1, 1, 2, 2, 2, 2, 3, 3, 3, 3};  // k on node k's lanes
static const int IOTA_[W] = {0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15};
#define NODE0 vload(NODE_[0])
#define NODE1 vload(NODE_[1])
#define NODE2 vload(NODE_[2])
#define COMP(c) vload(COMP_[c])
// (sum_k a[4k + c])_c, c = 0..3: the three nodes of a stencil row added, in registers
#if VIRHEO_VEC_BYTES == 64
VH_INLINE V4 node_sum(V a) {
    return __builtin_shufflevector(a, a, 0, 1, 2, 3) + __builtin_shufflevector(a, a, 4, 5, 6, 7) +
           __builtin_shufflevector(a, a, 8, 9, 10, 11);
}
#elif VIRHEO_VEC_BYTES == 32
VH_INLINE V4 node_sum(const V& a) {
    return __builtin_shufflevector(a.r[0], a.r[0], 0, 1, 2, 3) + __builtin_shufflevector(a.r[0], a.r[0], 4, 5, 6, 7) +
           __builtin_shufflevector(a.r[1], a.r[1], 0, 1, 2, 3);
}
#else
VH_INLINE V4 node_sum(const V& a) { return a.r[0] + a.r[1] + a.r[2]; }
#endif
