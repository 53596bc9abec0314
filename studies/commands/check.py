"""``virheo check DIR``: validate an experiment folder (settings, camera, 8 silhouettes) and its setup against frame 1

Validate an experiment folder: settings.xml, camera_params.xml and config_01..08.png (1920x1080 black-on-white
silhouettes). Projects the initial cuboid onto frame 1 and reports its IoU (also with W and H swapped); with
--overlay, draws it. Exit 0: fine; 1: usable but suspicious; 2: invalid (the same setups and footage that `virheo
estimate` refuses).
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from mpm import experiment
from mpm.silhouette import BOX_EDGES, box_corners

from studies.commands.context import add_command


def register(subparsers) -> None:
    p = add_command(subparsers, __doc__)
    p.add_argument("dir", metavar="DIR", help="experiment folder")
    p.add_argument("--overlay", metavar="FILE.png", default=None,
                   help="write an image of the projected cuboid (setup in mm from settings.xml) over frame 1")
    p.set_defaults(func=run)


def overlay_image(exp: experiment.Experiment, *, show_swapped: bool = False, scale: int = 2,
                  margin_px: int = 40) -> np.ndarray:
    """RGB image around the specimen: frame 1 (material grey on white) upscaled ``scale`` times, the
    stated cuboid's edges in red and, when ``show_swapped``, the W/H-swapped cuboid's in blue."""
    from skimage.draw import line

    frame = exp.frames[0].repeat(scale, axis=0).repeat(scale, axis=1)
    height, width = frame.shape
    img = np.full(frame.shape + (3,), 255, dtype=np.uint8)
    img[frame] = (150, 150, 150)
    boxes = [((exp.width_mm, exp.height_mm), (220, 0, 0))]
    if show_swapped:
        boxes.append(((exp.height_mm, exp.width_mm), (0, 60, 230)))
    region = [np.argwhere(frame)[:, ::-1]] if frame.any() else []
    for (w_mm, h_mm), colour in boxes:
        uv = exp.camera.project(box_corners(w_mm / 1000, h_mm / 1000, exp.depth_mm / 1000), (width, height))
        for a, b in BOX_EDGES:
            if not np.isfinite(uv[[a, b]]).all():
                continue
            (c0, r0), (c1, r1) = np.floor(np.clip(uv[[a, b]], -1e5, 1e5)).astype(int)
            rr, cc = line(r0, c0, r1, c1)
            ok = (rr >= 0) & (rr < height) & (cc >= 0) & (cc < width)
            img[rr[ok], cc[ok]] = colour
            region.append(np.stack([cc[ok], rr[ok]], axis=1))
    pts = np.concatenate(region) if region else np.zeros((0, 2), dtype=int)
    if len(pts) == 0:
        return img
    x0, y0 = np.maximum(pts.min(axis=0) - margin_px * scale, 0)
    x1, y1 = np.minimum(pts.max(axis=0) + margin_px * scale + 1, (width, height))
    return img[y0:y1, x0:x1]


def run(args) -> int:
    from studies.commands.estimate import load_experiments

    out = Path(args.overlay) if args.overlay else None
    if out is not None:
        if out.is_dir():
            raise ValueError(f"--overlay {out} is a folder: name a .png file")
        if out.suffix.lower() != ".png":
            raise ValueError(f"--overlay must name a .png file, got {out}")
    exp = load_experiments([args.dir], "check")[0]
    fit, swapped = experiment.cuboid_fit(exp)
    notes = experiment.setup_warnings(exp)
    flagged = swapped > fit + experiment.SWAP_MARGIN
    if out is not None:
        from PIL import Image

        from mpm.files import atomic_write

        image = Image.fromarray(overlay_image(exp, show_swapped=flagged))
        atomic_write(out, lambda fh: image.save(fh, format="PNG"))

    fractions = exp.frames.reshape(len(exp.frames), -1).mean(axis=1)
    w, h = exp.image_size
    print(f"{exp.name}: setup W {exp.width_mm:g} x H {exp.height_mm:g} mm, depth {exp.depth_mm:g} mm, "
          f"density {exp.density:g} kg/m^3")
    print(f"  frames: {len(exp.frames)} silhouettes at {w}x{h}, material {100 * fractions.min():.2f}-"
          f"{100 * fractions.max():.2f}% of the image")
    if exp.initial_material:
        m = exp.initial_material
        print(f"  initial material: eta {m['eta']:.4g} Pa s^n, n {m['n']:.4g}, sigma_y {m['sigma_y']:.4g} Pa")
    print(f"  initial cuboid vs frame 1: IoU {fit:.3f} (W and H swapped: {swapped:.3f})")
    if out is not None:
        print(f"  overlay: {out}" + (" (red: stated setup, blue: swapped)" if flagged else " (red: stated setup)"))
    for note in notes:
        sys.stderr.write(f"virheo check: warning: {note}\n")
    warned = len(notes) + len(exp.warnings)
    print("  status: " + (f"usable but suspicious ({warned} warning{'s' * (warned > 1)})" if warned else "ok"))
    return 1 if warned else 0
