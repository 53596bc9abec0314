// mpm._native: the native CPU engine of the MPM dam-break (kernel.h), one build per instruction set chosen
// at run time from the CPU's features, so that a build moved to an older CPU runs its generic path.
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <algorithm>
#include <condition_variable>
#include <functional>
#include <mutex>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <string>
#include <thread>
#include <vector>

#include "types.h"

#if defined(__x86_64__) || defined(_M_X64)
#define VIRHEO_X86 1
#include <immintrin.h>
#endif

namespace virheo {
// Subnormal floats (below 1.2e-38) arise where the tail of a stencil weight meets a tiny mass or momentum, and on
// x86 and ARM every operation on one takes a slow microcode path (8 % of a 70 x 70 mm run). While it simulates,
// the engine flushes them to zero (they are 1e-38 of any value that matters) and gives the caller its own mode back.
struct FlushDenormals {
#if VIRHEO_X86
    unsigned int saved = _mm_getcsr();
    void on() { _mm_setcsr(saved | 0x8040u); }  // FTZ (bit 15) and DAZ (bit 6)
    void off() { _mm_setcsr(saved); }
#elif defined(__aarch64__) && (defined(__GNUC__) || defined(__clang__))
    unsigned long saved = fpcr();
    static unsigned long fpcr() {
        unsigned long v;
        __asm__ __volatile__("mrs %0, fpcr" : "=r"(v));
        return v;
    }
    void on() { __asm__ __volatile__("msr fpcr, %0" : : "r"(saved | (1ul << 24))); }  // FZ
    void off() { __asm__ __volatile__("msr fpcr, %0" : : "r"(saved)); }
#else
    void on() {}
    void off() {}
#endif
    FlushDenormals() { on(); }
    ~FlushDenormals() { off(); }
};
}  // namespace virheo

#if VIRHEO_X86 && (defined(__GNUC__) || defined(__clang__))
#if defined(__clang__)
#pragma clang attribute push(__attribute__((target("avx512f,avx512vl,avx512dq,avx512bw,avx2,fma,bmi2"))), \
                             apply_to = function)
#else
#pragma GCC push_options
#pragma GCC target("avx512f,avx512vl,avx512dq,avx512bw,avx2,fma,bmi2,prefer-vector-width=512")
#endif
#define VIRHEO_ISA isa_avx512
#define VIRHEO_VEC_BYTES 64
#include "kernel.h"
#undef VIRHEO_ISA
#undef VIRHEO_VEC_BYTES
#if defined(__clang__)
#pragma clang attribute pop
#pragma clang attribute push(__attribute__((target("avx2,fma,bmi2"))), apply_to = function)
#else
#pragma GCC pop_options
#pragma GCC push_options
#pragma GCC target("avx2,fma,bmi2")
#endif
// 32-byte registers; the grid's stencil rows are read and written 16 bytes (one node) at a time (simd.h: row_add)
#define VIRHEO_ISA isa_avx2
#define VIRHEO_VEC_BYTES 32
#include "kernel.h"
#undef VIRHEO_ISA
#undef VIRHEO_VEC_BYTES
#if defined(__clang__)
#pragma clang attribute pop
#else
#pragma GCC pop_options
#endif
#define VIRHEO_HAVE_X86_PATHS 1
#endif

// SSE2 on x86-64, NEON on 64-bit ARM: both have 16-byte registers
#define VIRHEO_ISA isa_generic
#define VIRHEO_VEC_BYTES 16
#include "kernel.h"
#undef VIRHEO_ISA
#undef VIRHEO_VEC_BYTES

namespace {

// the instruction sets this CPU runs, best first
std::vector<std::string> supported_isas() {
    std::vector<std::string> out;
#ifdef VIRHEO_HAVE_X86_PATHS
    __builtin_cpu_init();
    if (__builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl") &&
        __builtin_cpu_supports("avx512dq") && __builtin_cpu_supports("avx512bw") && __builtin_cpu_supports("fma"))
        out.push_back("avx512");
    if (__builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma") && __builtin_cpu_supports("bmi2"))
        out.push_back("avx2");
#endif
    out.push_back("generic");
    return out;
}

bool isa_ok(const std::string& isa) {
    for (auto& s : supported_isas())
        if (s == isa) return true;
    return false;
}

struct Buffer {
    Py_buffer view{};
    bool held = false;
    ~Buffer() {
        if (held) PyBuffer_Release(&view);
    }
};

// a contiguous buffer of at least `count` items of `itemsize` bytes (writable if asked)
bool get_buffer(PyObject* obj, Buffer& b, Py_ssize_t itemsize, Py_ssize_t count, bool writable, const char* name) {
    int flags = PyBUF_C_CONTIGUOUS | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, &b.view, flags) != 0) return false;
    b.held = true;
    if (b.view.len < itemsize * count) {
        PyErr_Format(PyExc_ValueError, "%s: buffer of %zd bytes, need %zd", name, b.view.len, itemsize * count);
        return false;
    }
    return true;
}

struct ProgressCtx {
    PyObject* callback;
    PyThreadState** saved;
    virheo::FlushDenormals* flush;
};

int call_progress(void* ctx, int frame) {
    auto* c = static_cast<ProgressCtx*>(ctx);
    c->flush->off();  // Python runs in the caller's floating-point mode
    PyEval_RestoreThread(*c->saved);
    int stop = 0;
    if (PyErr_CheckSignals() != 0) {
        stop = 1;
    } else if (c->callback != Py_None) {
        PyObject* r = PyObject_CallFunction(c->callback, "i", frame);
        if (!r) stop = 1;
        Py_XDECREF(r);
    }
    *c->saved = PyEval_SaveThread();
    c->flush->on();
    return stop;
}

// The run's parameters by name (a dict from mpm.native_engine.NativeRun.params), into the fields of Params.
bool read_params(PyObject* d, virheo::Params& P, int& n) {
    if (!PyDict_Check(d)) {
        PyErr_SetString(PyExc_TypeError, "native engine: the parameters must be a dict");
        return false;
    }
    struct Field {
        const char* name;
        float* f;
        double* g;
        int* i;
    };
    const Field fields[] = {
        {"dim", nullptr, nullptr, &P.dim}, {"density_correction", nullptr, nullptr, &P.dens},
        {"slipping", nullptr, nullptr, &P.slipping}, {"threads", nullptr, nullptr, &P.threads},
        {"substeps", nullptr, nullptr, &P.substeps}, {"n_particles", nullptr, nullptr, &n},
        {"n_frames", nullptr, nullptr, &P.n_frames}, {"newton_iterations", nullptr, nullptr, &P.newton_iterations},
        {"alpha", &P.alpha}, {"beta", &P.beta}, {"flow_c", &P.flow_c},
        {"dx", &P.dx}, {"particle_mass", &P.mp}, {"particle_volume", &P.vol}, {"kappa", &P.kappa}, {"mu", &P.mu},
        {"eta", &P.eta}, {"n", &P.n}, {"sigma_y", &P.sy}, {"body_x", &P.body[0]}, {"body_y", &P.body[1]},
        {"body_z", &P.body[2]}, {"plane_z", &P.zmid}, {"half_length_cells", &P.lh}, {"slip", &P.slip},
        {"newton_tol", &P.newton_tol}, {"no_warm_start", &P.no_warm_start},
        {"cfl", nullptr, &P.cfl}, {"wave_speed", nullptr, &P.wave_speed}, {"gravity", nullptr, &P.gravity},
        {"speed_limit", nullptr, &P.speed_limit}, {"fps", nullptr, &P.fps},
    };
    if (PyDict_Size(d) != (Py_ssize_t)(sizeof(fields) / sizeof(fields[0]))) {
        PyErr_Format(PyExc_ValueError, "native engine: %zd parameters given, %zu expected", PyDict_Size(d),
                     sizeof(fields) / sizeof(fields[0]));
        return false;
    }
    for (const Field& field : fields) {
        PyObject* v = PyDict_GetItemString(d, field.name);
        if (!v) {
            PyErr_Format(PyExc_ValueError, "native engine: parameter %s missing", field.name);
            return false;
        }
        double x = PyFloat_AsDouble(v);
        if (x == -1.0 && PyErr_Occurred()) return false;
        if (field.f) *field.f = (float)x;
        if (field.g) *field.g = x;
        if (field.i) *field.i = (int)x;
    }
    return true;
}

// simulate(pos, flags, params, boxes, lim, frame_times, out_x, out_flags, out_meanj, out_mass, progress, isa)
//   -> (error, error_value, steps, dt_min, dt_max, vmax_seen, sorts, refills); params: a dict (read_params)
PyObject* py_simulate(PyObject*, PyObject* args) {
    PyObject *o_pos, *o_flags, *o_params, *o_boxes, *o_lim, *o_times, *o_x, *o_f, *o_j, *o_m, *progress;
    const char* isa;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOOOs", &o_pos, &o_flags, &o_params, &o_boxes, &o_lim, &o_times, &o_x,
                          &o_f, &o_j, &o_m, &progress, &isa))
        return nullptr;
    virheo::Params P{};
    int n = 0;
    if (!read_params(o_params, P, n)) return nullptr;
    int dim = P.dim, frames = P.n_frames;
    if ((dim != 2 && dim != 3) || n <= 0 || frames <= 0) {
        PyErr_SetString(PyExc_ValueError, "native engine: dim must be 2 or 3 and the scene must hold particles");
        return nullptr;
    }
    if (!isa_ok(isa)) {
        PyErr_Format(PyExc_ValueError, "native engine: this CPU does not run the %s path", isa);
        return nullptr;
    }
    Buffer pos, fl, bx, lim, times, ox, of, oj, om;
    if (!get_buffer(o_pos, pos, 8, (Py_ssize_t)n * dim, false, "positions") ||
        !get_buffer(o_flags, fl, 4, n, false, "flags") || !get_buffer(o_boxes, bx, 8, 24, false, "boxes") ||
        !get_buffer(o_lim, lim, 4, 6, false, "lim") || !get_buffer(o_times, times, 8, frames, false, "frame_times") ||
        !get_buffer(o_x, ox, 4, (Py_ssize_t)frames * n * dim, true, "out_x") ||
        !get_buffer(o_f, of, 1, (Py_ssize_t)frames * n, true, "out_flags") ||
        !get_buffer(o_j, oj, 8, frames, true, "out_mean_j") || !get_buffer(o_m, om, 8, frames, true, "out_grid_mass"))
        return nullptr;
    const double* B = static_cast<const double*>(bx.view.buf);
    for (int b = 0; b < 4; b++)
        for (int s = 0; s < 2; s++)
            for (int a = 0; a < 3; a++) P.boxes[b][s][a] = (float)B[(b * 2 + s) * 3 + a];
    std::memcpy(P.lim, lim.view.buf, sizeof(P.lim));
    P.frame_times = static_cast<const double*>(times.view.buf);
    virheo::Outputs out{static_cast<float*>(ox.view.buf), static_cast<unsigned char*>(of.view.buf),
                             static_cast<double*>(oj.view.buf), static_cast<double*>(om.view.buf)};
    const double* ppos = static_cast<const double*>(pos.view.buf);
    const int* pflags = static_cast<const int*>(fl.view.buf);
    std::string which(isa);
    PyThreadState* saved = nullptr;
    virheo::FlushDenormals flush;  // until the end of this call: worker threads set it for themselves (kernel.h)
    ProgressCtx ctx{progress, &saved, &flush};
    virheo::Result r;
    saved = PyEval_SaveThread();
    try {
#ifdef VIRHEO_HAVE_X86_PATHS
        if (which == "avx512")
            r = isa_avx512::simulate(P, ppos, pflags, n, out, call_progress, &ctx);
        else if (which == "avx2")
            r = isa_avx2::simulate(P, ppos, pflags, n, out, call_progress, &ctx);
        else
#endif
            r = isa_generic::simulate(P, ppos, pflags, n, out, call_progress, &ctx);
    } catch (const std::bad_alloc&) {
        flush.off();
        PyEval_RestoreThread(saved);
        PyErr_SetString(PyExc_MemoryError, "native engine: out of memory");
        return nullptr;
    }
    flush.off();
    PyEval_RestoreThread(saved);
    if (r.error == virheo::ERR_INTERRUPTED) {
        if (!PyErr_Occurred()) PyErr_SetString(PyExc_KeyboardInterrupt, "");
        return nullptr;
    }
    return Py_BuildValue("(idlddd ll)", r.error, r.error_value, r.steps, r.dt_min, r.dt_max, r.vmax_seen, r.sorts,
                         r.refills);
}

// return_mapping(be_trial, be_old, par, alpha, beta, c, iterations, newton_tol, no_warm_start, out, plastic, log_e,
//                isa)
PyObject* py_return_mapping(PyObject*, PyObject* args) {
    PyObject *o_bt, *o_bo, *o_par, *o_out, *o_pl, *o_le;
    int iterations;
    double tol, nws, alpha, beta, c;
    const char* isa;
    if (!PyArg_ParseTuple(args, "OOOdddiddOOOs", &o_bt, &o_bo, &o_par, &alpha, &beta, &c, &iterations, &tol, &nws,
                          &o_out, &o_pl, &o_le, &isa))
        return nullptr;
    if (!isa_ok(isa)) {
        PyErr_Format(PyExc_ValueError, "native engine: this CPU does not run the %s path", isa);
        return nullptr;
    }
    Buffer bt, bo, par, out, pl, le;
    if (!get_buffer(o_pl, pl, 4, 0, true, "plastic")) return nullptr;
    Py_ssize_t n = pl.view.len / 4;
    if (!get_buffer(o_bt, bt, 4, n * 9, false, "be_trial") || !get_buffer(o_bo, bo, 4, n * 9, false, "be_old") ||
        !get_buffer(o_par, par, 4, n * 6, false, "par") || !get_buffer(o_out, out, 4, n * 9, true, "out") ||
        !get_buffer(o_le, le, 4, n, true, "log_e"))
        return nullptr;
    auto args_of = [&](auto fn) {
        fn(static_cast<const float*>(bt.view.buf), static_cast<const float*>(bo.view.buf),
           static_cast<const float*>(par.view.buf), (int)n, {(float)alpha, (float)beta, (float)c}, iterations, (float)tol, (float)nws,
           static_cast<float*>(out.view.buf), static_cast<int*>(pl.view.buf), static_cast<float*>(le.view.buf));
    };
    std::string which(isa);
#ifdef VIRHEO_HAVE_X86_PATHS
    if (which == "avx512")
        args_of(isa_avx512::return_mapping_batch);
    else if (which == "avx2")
        args_of(isa_avx2::return_mapping_batch);
    else
#endif
        args_of(isa_generic::return_mapping_batch);
    Py_RETURN_NONE;
}

// Runs of an offset list whose rows (equal dy, dy ascending) hold consecutive dx, ascending: each row is
// [first, last) of the list.  The disk footprints of mpm/silhouette.py are such lists.
struct OffsetRow {
    int64_t dy;
    Py_ssize_t first, last;
};

std::vector<OffsetRow> offset_rows(const int64_t* dy, Py_ssize_t count) {
    std::vector<OffsetRow> rows;
    for (Py_ssize_t j = 0; j < count; j++)
        if (rows.empty() || rows.back().dy != dy[j])
            rows.push_back({dy[j], j, j + 1});
        else
            rows.back().last = j + 1;
    return rows;
}

// splat(cx, cy, frac, r2, dx, dy, sure_dx, sure_dy, crop, rows, cols): the particles' disks of a silhouette
// (mpm/silhouette.py, render) set in `crop` (uint8, rows x cols, row-major).  Particle i sits in pixel (cx[i], cy[i])
// of the crop at (frac[2i], frac[2i+1]) inside it.  Where that pixel lies in the crop, its "sure" offsets are set;
// and every offset (dx, dy) whose pixel centre lies within sqrt(r2[i]) of it, tested in float32 as the numpy path
// tests it, (dx + 0.5 - fx)^2 + (dy + 0.5 - fy)^2 <= r2 (built for the baseline target, where C++17 does not contract
// to fused multiply-adds), so both paths set the same pixels.  Along a row of offsets the test's left side falls,
// then rises (float rounding is monotone), so the offsets that pass are one run: found from its two ends and set
// at once.
PyObject* py_splat(PyObject*, PyObject* args) {
    PyObject *o_cx, *o_cy, *o_frac, *o_r2, *o_dx, *o_dy, *o_sx, *o_sy, *o_crop;
    Py_ssize_t rows, cols;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOnn", &o_cx, &o_cy, &o_frac, &o_r2, &o_dx, &o_dy, &o_sx, &o_sy, &o_crop, &rows,
                          &cols))
        return nullptr;
    Buffer cx, cy, frac, r2, dx, dy, sx, sy, crop;
    if (!get_buffer(o_cx, cx, 8, 0, false, "cx") || !get_buffer(o_dx, dx, 8, 0, false, "dx") ||
        !get_buffer(o_sx, sx, 8, 0, false, "sure_dx"))
        return nullptr;
    const Py_ssize_t n = cx.view.len / 8, m = dx.view.len / 8, s = sx.view.len / 8;
    if (!get_buffer(o_cy, cy, 8, n, false, "cy") || !get_buffer(o_frac, frac, 4, 2 * n, false, "frac") ||
        !get_buffer(o_r2, r2, 4, n, false, "r2") || !get_buffer(o_dy, dy, 8, m, false, "dy") ||
        !get_buffer(o_sy, sy, 8, s, false, "sure_dy") || !get_buffer(o_crop, crop, 1, rows * cols, true, "crop"))
        return nullptr;
    const auto* pcx = static_cast<const int64_t*>(cx.view.buf);
    const auto* pcy = static_cast<const int64_t*>(cy.view.buf);
    const auto* pf = static_cast<const float*>(frac.view.buf);
    const auto* pr2 = static_cast<const float*>(r2.view.buf);
    const auto* pdx = static_cast<const int64_t*>(dx.view.buf);
    const auto* psx = static_cast<const int64_t*>(sx.view.buf);
    auto* out = static_cast<unsigned char*>(crop.view.buf);
    const std::vector<OffsetRow> disk = offset_rows(static_cast<const int64_t*>(dy.view.buf), m);
    const std::vector<OffsetRow> sure = offset_rows(static_cast<const int64_t*>(sy.view.buf), s);
    Py_BEGIN_ALLOW_THREADS
    std::vector<float> ox(m);
    for (Py_ssize_t j = 0; j < m; j++) ox[j] = (float)pdx[j] + 0.5f;
    auto set_run = [&](int64_t y, int64_t x0, int64_t x1) {  // pixels x0..x1 of row y, inside the crop
        if (y < 0 || y >= rows) return;
        x0 = std::max<int64_t>(x0, 0);
        x1 = std::min<int64_t>(x1, cols - 1);
        if (x0 <= x1) std::memset(out + y * cols + x0, 1, (size_t)(x1 - x0 + 1));
    };
    // the sure footprints first: most disks then fall on pixels already set, and their rows need no test
    for (Py_ssize_t i = 0; i < n; i++) {
        const int64_t x = pcx[i], y = pcy[i];
        if (x >= 0 && x < cols && y >= 0 && y < rows)
            for (const OffsetRow& r : sure) set_run(y + r.dy, x + psx[r.first], x + psx[r.last - 1]);
    }
    // pixels set per row up to each column, after the sure footprints (a row found not all set is tested, so counts
    // that miss the disks set since cost time, not pixels)
    std::vector<int32_t> before((size_t)rows * (size_t)(cols + 1));
    for (Py_ssize_t y = 0; y < rows; y++) {
        int32_t* c = before.data() + y * (cols + 1);
        c[0] = 0;
        for (Py_ssize_t x = 0; x < cols; x++) c[x + 1] = c[x] + out[y * cols + x];
    }
    auto all_set = [&](int64_t y, int64_t x0, int64_t x1) {  // every pixel x0..x1 of row y set, or outside the crop
        if (y < 0 || y >= rows) return true;
        x0 = std::max<int64_t>(x0, 0);
        x1 = std::min<int64_t>(x1, cols - 1);
        if (x0 > x1) return true;
        const int32_t* c = before.data() + y * (cols + 1);
        return c[x1 + 1] - c[x0] == x1 - x0 + 1;
    };
    for (Py_ssize_t i = 0; i < n; i++) {
        const int64_t x = pcx[i], y = pcy[i];
        const float fx = pf[2 * i], fy = pf[2 * i + 1], rr = pr2[i];
        for (const OffsetRow& r : disk) {
            if (all_set(y + r.dy, x + pdx[r.first], x + pdx[r.last - 1])) continue;
            const float b = ((float)r.dy + 0.5f) - fy, b2 = b * b;
            auto pass = [&](Py_ssize_t j) {
                const float a = ox[j] - fx, a2 = a * a;
                return a2 + b2 <= rr;
            };
            Py_ssize_t lo = r.first, hi = r.last - 1;
            while (lo <= hi && !pass(lo)) lo++;
            if (lo > hi) continue;
            while (!pass(hi)) hi--;
            set_run(y + r.dy, x + pdx[lo], x + pdx[hi]);
        }
    }
    Py_END_ALLOW_THREADS
    Py_RETURN_NONE;
}

PyObject* py_isas(PyObject*, PyObject*) {
    auto isas = supported_isas();
    PyObject* list = PyList_New((Py_ssize_t)isas.size());
    for (size_t i = 0; i < isas.size(); i++) PyList_SET_ITEM(list, i, PyUnicode_FromString(isas[i].c_str()));
    return list;
}

PyObject* py_compiled(PyObject*, PyObject*) {
#ifdef VIRHEO_HAVE_X86_PATHS
    return Py_BuildValue("[sss]", "avx512", "avx2", "generic");
#else
    return Py_BuildValue("[s]", "generic");
#endif
}

PyObject* py_substeps(PyObject*, PyObject* args) {
    double t, t_target, vmax, dx, wave_speed, gravity, cfl;
    if (!PyArg_ParseTuple(args, "ddddddd", &t, &t_target, &vmax, &dx, &wave_speed, &gravity, &cfl)) return nullptr;
    const virheo::Substeps s = virheo::substeps(t, t_target, vmax, (double)(float)dx, wave_speed, gravity, cfl);
    return Py_BuildValue("(ld)", s.m, s.dt);
}

PyMethodDef methods[] = {
    {"simulate", py_simulate, METH_VARARGS, "Run a whole dam-break simulation (see mpm/native_engine.py)."},
    {"return_mapping", py_return_mapping, METH_VARARGS, "The return mapping of eq. 57 over a batch."},
    {"isas", py_isas, METH_NOARGS, "Instruction-set paths this CPU runs, best first."},
    {"splat", py_splat, METH_VARARGS, "The particles' disks of a silhouette (see mpm/silhouette.py)."},
    {"compiled", py_compiled, METH_NOARGS, "Instruction-set paths compiled into this build."},
    {"substeps", py_substeps, METH_VARARGS,
     "(steps, dt) of the time-step schedule from t to t_target (dx rounded to float, as the engine holds it)."},
    {nullptr, nullptr, 0, nullptr}};

PyModuleDef module = {PyModuleDef_HEAD_INIT, "_native", "Native CPU engine of the MPM dam-break.", -1, methods};

}  // namespace

// the calling convention of simulate, return_mapping, substeps and splat: mpm.native_engine.INTERFACE must match, else the build is stale
constexpr long INTERFACE = 4;

PyMODINIT_FUNC PyInit__native(void) {
    PyObject* m = PyModule_Create(&module);
    if (m && PyModule_AddIntConstant(m, "INTERFACE", INTERFACE) < 0) {
        Py_DECREF(m);
        return nullptr;
    }
    return m;
}
