"""A cheap deterministic stand-in for the MPM forward model (tests of the store, batch and estimator).

The "silhouette" is a side view of a slumping half-ellipse: the front runs out from W towards a
final length set by a yield height sigma_y / (rho g), on a time scale set by (eta, n).  All three
parameters change the pictures smoothly, so CMA-ES can recover them.  It ignores the camera and
rasterises straight into an ``image_size`` grid spanning 0..0.16 m x 0..0.09 m.

``simulate_flaky`` fails (RuntimeError, as SimulationError would) for a fixed quarter of all
requests, chosen by their key.  ``$FAKE_FORWARD_LOG`` (optional) gets one line per simulation run.
"""
from __future__ import annotations

import os
import time

import numpy as np

from mpm.store import SimRequest, SimResult

G = 9.81
TIMES = np.arange(1, 9) / 24.0


def _profiles(r: SimRequest):
    w, h = r.width_mm * 1e-3, r.height_mm * 1e-3
    h_yield = r.sigma_y / (r.density * G)  # height a yield stress can hold
    runout = max(0.0, h - 0.5 * h_yield) * 2.0 * (0.4 + r.n)  # spreading potential
    tau = 0.01 + 0.25 * (r.eta / 30.0) ** r.n  # viscous time scale
    front = w + runout * (1.0 - np.exp(-TIMES / tau))
    return front, w * h


def simulate(request: SimRequest) -> SimResult:
    delay = float(os.environ.get("FAKE_FORWARD_DELAY", "0"))
    if delay:
        time.sleep(delay)
    log = os.environ.get("FAKE_FORWARD_LOG")
    if log:
        with open(log, "a") as fh:
            fh.write(request.key + "\n")
    front, area = _profiles(request)
    wpx, hpx = request.image_size
    x = (np.arange(wpx) + 0.5) * (0.16 / wpx)
    y = (np.arange(hpx)[::-1] + 0.5) * (0.09 / hpx)  # row 0 at the top
    frames = np.zeros((len(TIMES), hpx, wpx), bool)
    for k, L in enumerate(front):
        top = area / (np.pi / 4.0 * L)  # quarter-ellipse of the same area
        prof = top * np.sqrt(np.clip(1.0 - (x / L) ** 2, 0.0, None))
        frames[k] = y[:, None] <= prof[None, :]
    # the work a simulation of this box would do (particles x steps), as the engine's stats report it
    spacing_mm = (request.model.cell_mm or 2.5) / (request.model.ppc or 1)
    particles = int(request.width_mm * request.height_mm * request.depth_mm / spacing_mm**3)
    return SimResult(frames, front, TIMES.copy(), {"model": "fake", "n_particles": particles,
                                                   "steps": int(1.0 / (3.0 * 1.4e-4 * (request.model.cell_mm or 2.5)))})


def simulate_flaky(request: SimRequest) -> SimResult:
    if int(request.key[:8], 16) % 4 == 0:
        raise RuntimeError("fake blow-up")
    return simulate(request)
