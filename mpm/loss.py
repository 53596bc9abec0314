"""Captured silhouettes and the video loss of eq. 3, computed as the reference implementation does.

A captured 1920x1080 RGB frame is averaged over 2x2 blocks to the working size 960x540, turned gray
(0.299 R + 0.587 G + 0.114 B) and thresholded: gray > 130 is background, anything else material. The loss
of a frame is the fraction of pixels where simulated and captured masks differ (for binary masks the
squared difference of eq. 3 is the XOR); the loss of a video is the mean over its frames.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from mpm.params import WORKING_SIZE

BACKGROUND_ABOVE = 130  # gray > 130 is background in the captured frames
MAX_GREY_FRACTION = 0.01  # a silhouette has at most this fraction of pixels that are neither black nor white
_BLACK, _WHITE = 16, 239  # "nearly black" / "nearly white" for the binary test (per channel)


def read_image(path) -> np.ndarray:
    """An image file as an (H, W, 3) uint8 RGB array (alpha dropped, as cv::imread does)."""
    from PIL import Image, UnidentifiedImageError

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"image not found: {path}")
    try:
        with Image.open(path) as im:
            if im.mode in ("I;16", "I;16B", "I;16L", "I"):
                a = np.asarray(im, dtype=np.float64)
                a = np.clip(a / 257.0 if a.max() > 255 else a, 0, 255).astype(np.uint8)
                return np.repeat(a[..., None], 3, axis=2)
            return np.asarray(im.convert("RGB"))
    except (UnidentifiedImageError, OSError, SyntaxError) as exc:
        raise ValueError(f"{path.name}: not a readable image ({exc})") from None


def _as_rgb(image: np.ndarray, name: str) -> np.ndarray:
    a = np.asarray(image)
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3 or a.shape[2] not in (1, 3, 4):
        raise ValueError(f"{name}: expected an image array (H, W[, 3|4]), got shape {np.shape(image)}")
    a = a[..., :3] if a.shape[2] != 1 else np.repeat(a, 3, axis=2)
    if a.dtype == bool:
        return np.where(a, 0, 255).astype(np.uint8)  # True = material = black
    if not np.issubdtype(a.dtype, np.number):
        raise ValueError(f"{name}: image array must be numeric")
    return np.clip(a, 0, 255).astype(np.uint8) if a.dtype != np.uint8 else a


def grey_fraction(rgb: np.ndarray) -> float:
    """Fraction of pixels that are neither nearly black nor nearly white in all channels."""
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    hi = np.maximum(np.maximum(r, g), b)
    lo = np.minimum(np.minimum(r, g), b)
    binary = np.count_nonzero(hi <= _BLACK) + np.count_nonzero(lo >= _WHITE)
    return float(1.0 - binary / hi.size)


def load_reference(src, size=WORKING_SIZE) -> np.ndarray:
    """Captured silhouette -> (540, 960) bool material mask, preprocessed exactly like the reference.

    ``src`` is a path or an array. Accepted frames are 2x the working size (1920x1080: averaged over
    2x2 blocks) or already at the working size. A boolean array is taken as a mask (True = material).
    Anything else of the wrong size, or not a black-on-white silhouette, raises a one-line ValueError.
    """
    width, height = (int(v) for v in size)
    name = Path(src).name if isinstance(src, (str, Path)) else "image"
    if isinstance(src, np.ndarray) and src.dtype == bool and src.ndim == 2:
        if src.shape == (height, width):
            return src.copy()
        if src.shape == (2 * height, 2 * width):
            return src.reshape(height, 2, width, 2).mean(axis=(1, 3)) >= 0.5
        raise ValueError(f"{name}: mask is {src.shape[1]}x{src.shape[0]}, expected {2 * width}x{2 * height} "
                         f"or {width}x{height}")
    rgb = _as_rgb(read_image(src) if isinstance(src, (str, Path)) else src, name)
    h, w = rgb.shape[:2]
    if (w, h) not in ((2 * width, 2 * height), (width, height)):
        raise ValueError(f"{name}: frame is {w}x{h}, expected {2 * width}x{2 * height} (or {width}x{height})")
    grey = grey_fraction(rgb)
    if grey > MAX_GREY_FRACTION:
        raise ValueError(f"{name}: not a binary silhouette ({100 * grey:.1f}% of pixels are neither black nor "
                         f"white; expected black material on white)")
    if w == 2 * width:  # cv::resize INTER_LINEAR at exactly 1/2 = mean of each 2x2 block, rounded
        a = rgb.astype(np.uint16)
        small = (a[0::2, 0::2] + a[1::2, 0::2] + a[0::2, 1::2] + a[1::2, 1::2] + 2) // 4
    else:
        small = rgb
    small = small.astype(np.float32)
    gray = np.rint(0.299 * small[..., 0] + 0.587 * small[..., 1] + 0.114 * small[..., 2])
    return ~(gray > BACKGROUND_ABOVE)


def _check_pair(sim: np.ndarray, ref: np.ndarray) -> None:
    if sim.shape != ref.shape:
        raise ValueError(f"silhouette shapes differ: simulated {sim.shape} vs reference {ref.shape}")


def frame_loss(sim_mask, ref_mask) -> float:
    """Fraction of pixels where the two binary masks differ (squared difference of binary images)."""
    sim, ref = np.asarray(sim_mask, dtype=bool), np.asarray(ref_mask, dtype=bool)
    _check_pair(sim, ref)
    if sim.size == 0:
        raise ValueError("empty silhouettes")
    return float(np.count_nonzero(sim ^ ref)) / sim.size


def frame_losses(sim_frames, ref_frames) -> np.ndarray:
    """Per-frame losses of two equally long stacks of masks (F, height, width)."""
    sim, ref = np.asarray(sim_frames, dtype=bool), np.asarray(ref_frames, dtype=bool)
    if sim.ndim != 3 or ref.ndim != 3:
        raise ValueError(f"expected stacks of masks (F, height, width), got {sim.shape} and {ref.shape}")
    _check_pair(sim, ref)
    if len(sim) == 0:
        raise ValueError("no frames to compare")
    # frame by frame: count_nonzero over axes sums a cast copy, 4x slower
    return np.array([frame_loss(s, r) for s, r in zip(sim, ref)])


def video_loss(sim_frames, ref_frames) -> float:
    """L = (1/F) sum_k (1/|P|) sum_p (S_k(p) - R_k(p))^2 over frames k and pixels p."""
    return float(np.mean(frame_losses(sim_frames, ref_frames)))  # eq. 3


def iou(a, b) -> float:
    """Intersection over union of two binary masks (1.0 when both are empty)."""
    a, b = np.asarray(a, dtype=bool), np.asarray(b, dtype=bool)
    _check_pair(a, b)
    union = np.count_nonzero(a | b)
    return 1.0 if union == 0 else np.count_nonzero(a & b) / union
