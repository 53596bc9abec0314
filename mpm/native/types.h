// Values passed between the Python driver (mpm/native_engine.py) and every instruction-set build of kernel.h.
#pragma once

#include <cmath>

namespace virheo {

// particle flag bits and the error codes of a run: the values of mpm/solver_constants.py (a test compares them)
constexpr int HIDDEN = 1, PLASTIC = 2, FROZEN = 4;
constexpr int ERR_NAN = 1, ERR_LEFT_REACH = 2, ERR_SPEED = 3, ERR_INTERRUPTED = 4;

struct Params {
    int dim, dens, slipping, threads, substeps, n_frames, newton_iterations;
    float alpha, beta, flow_c;  // the flow rule: yield when alpha ||dev sigma|| > beta sigma_y; L_v b_e = -c ...
    float dx, mp, vol, kappa, mu, eta, n, sy, body[3], zmid, lh, slip, newton_tol, no_warm_start;
    double cfl, wave_speed, gravity, speed_limit, fps;
    float boxes[4][2][3];
    int lim[6];
    const double* frame_times;
};

struct Outputs {
    float* frames_x;  // (frames, N, dim) in the input order
    unsigned char* frames_flags;  // (frames, N)
    double* mean_j;  // (frames,) mean sqrt(det b_e) of the moving particles
    double* grid_mass;  // (frames,) mass on the last grid of the frame
};

struct Result {
    int error = 0;  // 0 or one of the ERR_ codes above
    double error_value = 0, dt_min = 1e300, dt_max = 0, vmax_seen = 0;
    long steps = 0, sorts = 0, refills = 0;
};

typedef int (*ProgressFn)(void* ctx, int frame);  // nonzero: stop

// The time-step schedule, mpm.engine_run.substeps (a test compares the two): the steps m and the step dt that take
// the run from t to t_target under the CFL condition dt <= cfl dx / (c + |v|max + g (t_target - t)).
struct Substeps {
    long m;
    double dt;
};
inline Substeps substeps(double t, double t_target, double vmax, double dx, double wave_speed, double gravity,
                         double cfl) {
    double dt_cfl = cfl * dx / (wave_speed + vmax + gravity * (t_target - t));
    long m = (long)std::ceil((t_target - t) / dt_cfl - 1e-9);
    if (m < 1) m = 1;
    return {m, (t_target - t) / m};
}

}  // namespace virheo
