"""Benchmark: silhouette rendering speed, footage loading, and the camera fit on the shared experiments.

    python bench/bench_silhouette.py            # synthetic particle clouds + shared data when present

Prints (1) wall time of render_frames for 8 frames of 250-400k particles (250: a 5 mm model), with the native
extension's splat where it is built and with the numpy one, (2) time to
load an experiment folder (8 PNGs at 1920x1080 -> masks at 960x540), (3) per shared experiment the IoU of the
projected initial cuboid with frame 1, as stated and with W and H swapped. Numbers go to docs/performance.md.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from mpm import experiment, native_engine  # noqa: E402
from mpm.camera import Camera  # noqa: E402
from mpm.datasets import data_dir  # noqa: E402
from mpm.silhouette import render_frames  # noqa: E402
from measured import how_measured  # noqa: E402  (bench/ is this script's folder)


def cloud(n_target: int, seed: int = 0) -> tuple[np.ndarray, float]:
    """A slumped-looking particle cloud (a cuboid sheared forward) with about n_target particles."""
    w, h, d = 0.04, 0.03, 0.04
    spacing = (w * h * d / n_target) ** (1 / 3)
    axes = [np.arange(spacing / 2, length, spacing) for length in (w, h, d)]
    p = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    p[:, 0] += 0.6 * (h - p[:, 1]) * (p[:, 0] / w)  # shear the foot forward
    p += np.random.default_rng(seed).normal(0, 0.1 * spacing, p.shape)
    return p, spacing


def best_of(fn, repeats=3) -> float:
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return min(times)


_available = native_engine.available


def main() -> None:
    cam = Camera.default()
    print(f"# measured: {how_measured()}", flush=True)
    print("render_frames: 8 frames at 960x540 (best of 3; the machine is shared, numbers are noisy)")
    native = native_engine.available()
    print(f"native splat: {'built' if native else 'not available (' + native_engine.why_unavailable() + ')'}")
    print(f"{'particles':>10} {'spacing mm':>10} {'total s':>8} {'per frame ms':>12} {'numpy splat, per frame ms':>26}")
    for n in (250, 2_000, 20_000, 50_000, 100_000, 200_000, 400_000):
        p, s = cloud(n)
        frames = [p + np.array([0.0005 * k, 0, 0]) for k in range(8)]
        t = best_of(lambda: render_frames(frames, cam, spacing_m=s))
        native_engine.available = lambda: False
        try:
            t_numpy = best_of(lambda: render_frames(frames, cam, spacing_m=s))
        finally:
            native_engine.available = _available
        print(f"{len(p):>10} {1e3 * s:>10.2f} {t:>8.3f} {1e3 * t / 8:>12.1f} {1e3 * t_numpy / 8:>26.1f}")

    if data_dir() is None:
        print("shared data absent: skipping the footage part")
        return
    folders = experiment.iter_shared()
    t = time.perf_counter()
    exps = [experiment.load(f) for f in folders]
    dt = time.perf_counter() - t
    print(f"\nexperiment.load: {len(exps)} folders in {dt:.2f} s ({1e3 * dt / len(exps):.0f} ms per folder)")
    print(f"\n{'experiment':52} {'W x H x D mm':>16} {'IoU':>6} {'swapped':>8}")
    for e in exps:
        fit, swapped = experiment.cuboid_fit(e)
        dims = f"{e.width_mm:g}x{e.height_mm:g}x{e.depth_mm:g}"
        print(f"{e.name:52} {dims:>16} {fit:>6.3f} {swapped:>8.3f}")


if __name__ == "__main__":
    main()
