"""The constants both MPM engines share, in one place that imports no Taichi: the Newton solve of the return
mapping (eq. 57), the flow rules' coefficients (eqs. 14-18), the particle flag bits, the error codes a step reports
and the error a blown-up simulation raises.

The native engine (mpm/native/kernel.h) holds the same flag bits and error codes as C++ constants;
tests/test_solver_paths.py reads them there and compares them with these.
"""
from dataclasses import dataclass

import numpy as np

from mpm.params import FLOW_RULES, check_flow_rule

NEWTON_ITERATIONS = 8
CBRT_ITERATIONS = 64  # cap of the Halley cube root (it doubles or halves per iteration far from the root)
CBRT_TOL = 1e-5  # relative change at which the cube root stops (error left ~ CBRT_TOL^3)
# early exit of the Taichi solve once a Newton step in log(e) is below this: the error left is about
# G''/(2 G') step^2 <= (1/n - 1)^2/8 step^2 < 2e-9 for n >= 0.3, below f32 resolution
NEWTON_TOL = 1e-4
NO_WARM_START = 1e30  # log(e) start of a particle that was elastic last step: the solve starts at log(e_trial)
SQRT2 = float(np.sqrt(2.0))
SQRT2_3 = float(np.sqrt(2.0 / 3.0))

HIDDEN, PLASTIC, FROZEN = 1, 2, 4  # particle flag bits
# what a step reports (0: none); ERR_SPEED carries the speed, ERR_INTERRUPTED is the native engine's stop on request
ERR_NAN, ERR_LEFT_REACH, ERR_SPEED, ERR_INTERRUPTED = 1, 2, 3, 4
ERRORS = {ERR_NAN: "a particle position became NaN", ERR_LEFT_REACH: "particles left the region the flow can reach"}


class SimulationError(RuntimeError):
    """The simulation blew up (NaN, runaway speed, particles leaving the reachable region), on any engine."""


@dataclass(frozen=True)
class FlowRule:
    """q = alpha*||dev sigma||_F is compared with beta*sigma_y; L_v b_e = -c*gamma_HB*s_hat*b_e."""

    alpha: float
    beta: float
    c: float


_RULES = dict(zip(FLOW_RULES, (
    FlowRule(alpha=1.0 / SQRT2, beta=1.0, c=SQRT2),  # eqs. 14, 15, 18
    FlowRule(alpha=1.0, beta=SQRT2_3, c=2.0),  # yue2015: von Mises, no 1/sqrt(2)
)))


def get_flow_rule(name: str) -> FlowRule:
    """The coefficients of flow rule ``name`` ("paper" or "yue2015")."""
    return _RULES[check_flow_rule(name)]
