"""Does the camera view change the loss structure? (paper section 5.1 and Fig. 7: "changing the view ... had little
impact on the loss structure")

For each (material, setup) pair, footage is emulated through two cameras: the default front view
(``mpm.camera.Camera.default``, in front of the box and 30 deg above) and the same camera swung ``--yaw`` degrees about
the vertical through the point it looks at, towards the flow's front. Through each camera the finite-difference
Hessian of the MPM loss (eq. 3) is taken at the ground truth (18-point stencil of ``similarity.fd_hessian``), and the
script prints each view's loss normal q_max, condition number, and the angle between the two views' normals.

    python bench/bench_view_dependence.py [--yaw 40] [--cell-mm 5] [--fd-step 0.05] [--store PATH] [--workers 2]
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from mpm.camera import Camera  # noqa: E402
from mpm.forward import Forward  # noqa: E402
from mpm.params import Material, Setup  # noqa: E402
from similarity.emulation import emulate, probe_losses  # noqa: E402
from similarity.fd_hessian import angle_deg, hessian_from_stencil, spectrum, stencil  # noqa: E402
from similarity.presets import Preset  # noqa: E402
from measured import how_measured  # noqa: E402  (bench/ is this script's folder)

# inside the region the landscape studies sample; setups from both ends of the setup space
PAIRS = (((3.45, 0.738, 6.26), (42.0, 38.0)), ((9.82, 0.705, 12.9), (64.0, 37.0)), ((10.0, 0.6, 10.0), (30.0, 20.0)),
         ((10.0, 0.6, 10.0), (70.0, 70.0)))


def swung(camera: Camera, yaw_deg: float) -> Camera:
    """``camera`` rotated by ``yaw_deg`` about the vertical (+y) through the floor point on its optical axis."""
    eye = np.asarray(camera.eyepos_m)
    axis = -camera.rotation[:, 2]  # the camera looks along its local -z
    target = eye + axis * (-eye[1] / axis[1])  # where the optical axis meets the floor y = 0
    a = math.radians(yaw_deg)
    turn = np.array([[math.cos(a), 0.0, math.sin(a)], [0.0, 1.0, 0.0], [-math.sin(a), 0.0, math.cos(a)]])
    w, x, y, z = camera.quat  # q_yaw * q (Hamilton product), q_yaw = (cos a/2, 0, sin a/2, 0)
    c, s = math.cos(a / 2), math.sin(a / 2)
    quat = (c * w - s * y, c * x + s * z, c * y + s * w, c * z - s * x)
    return Camera(eyepos_m=tuple(target + turn @ (eye - target)), quat=quat, fov_deg=camera.fov_deg,
                  window_size=camera.window_size)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--yaw", type=float, default=40.0, help="swing of the second camera in degrees (default 40)")
    ap.add_argument("--cell-mm", type=float, default=5.0, help="cell width of footage and fit (default 5, the demo's)")
    ap.add_argument("--fd-step", type=float, default=0.05, help="stencil step in normalised units (default 0.05)")
    ap.add_argument("--store", default="bench-view-store", help="simulation store folder")
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args(argv)
    forward = Forward(a.store, workers=a.workers)
    preset = Preset("bench", generations=1, cell_mm=a.cell_mm, ppc=1)
    views = {"front": Camera.default(), f"swung {a.yaw:g} deg": swung(Camera.default(), a.yaw)}
    offsets = stencil(a.fd_step)
    angles = []
    print(f"# measured: {how_measured()}", flush=True)
    print(f"FD loss normal (d eta, d n, d sigma_Y normalised) per view, {a.cell_mm:g} mm cells, step {a.fd_step:g}")
    try:
        for mat, (w, h) in PAIRS:
            t0 = time.perf_counter()
            m, setup = Material(*mat), Setup(w, h)
            normals = []
            for name, camera in views.items():
                shot = emulate(m, [setup], preset=preset, camera=camera, forward=forward)[0]
                losses = probe_losses([(m, shot)], offsets, preset.search, forward)[0]
                spec = spectrum(hessian_from_stencil(losses, a.fd_step))
                normals.append(spec.q_max)
                print(f"  {mat} in {setup} mm, {name:>14}: q_max {np.round(spec.q_max, 3)}, "
                      f"condition {spec.condition:5.1f}, mean stencil loss {np.mean(losses):.4f}")
            angles.append(float(angle_deg(*normals)))
            print(f"    angle between the views' normals: {angles[-1]:.1f} deg   ({time.perf_counter() - t0:.0f} s)",
                  flush=True)
    finally:
        forward.close()
    print(f"median angle over {len(angles)} pairs: {np.median(angles):.1f} deg (max {max(angles):.1f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
