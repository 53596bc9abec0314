"""Binary silhouettes of simulated material seen through a calibrated :class:`~mpm.camera.Camera`.

Each particle is splatted as a disk of world radius :func:`default_radius_m` (it covers the pixels whose
centres lie within its projected radius), then a small morphological closing fills pinholes. This stands
in for the reference implementation's skinned, rasterised surface. Masks are boolean (height, width),
True = material, pixel (row, col) covering the image area [col, col+1) x [row, row+1) of
:meth:`Camera.project`.
"""
from __future__ import annotations

import math

import numpy as np
from scipy import ndimage
from scipy.spatial import ConvexHull, QhullError
from skimage.draw import polygon as fill_polygon
from skimage.morphology import disk

from mpm import native_engine
from mpm.camera import Camera, image_size_of
from mpm.params import WORKING_SIZE

REFERENCE_SPACING_M = 0.63e-3  # particle spacing of the reference simulations (cell 1.26 mm / 2)
REFERENCE_RADIUS_M = 1.0e-3  # splat radius equivalent to the reference skinned surface at that spacing

# the 12 edges of a box whose corners are numbered by bits (x, y, z) = (i & 1, i >> 1 & 1, i >> 2 & 1)
BOX_EDGES = tuple((a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1)


def default_radius_m(spacing_m: float | None = None) -> float:
    """Splat radius: 1.0 mm (the reference's skinned surface), at least 0.75 x the particle spacing.

    Measured on the Worcestershire setup-2 footage (docs/method/forward-model.md): with cells of 1.5-3 mm
    (spacing 0.75-1.5 mm) a radius of 1.0-1.2 mm is within 1e-4 of the best loss at every resolution,
    while keeping the surface a fixed distance beyond the material (1.0 mm + (spacing - 0.63 mm)/2)
    scores up to 1.5e-4 worse at the coarse end. 0.75 x spacing keeps sparse lattices gap-free.
    """
    if spacing_m is None:
        return REFERENCE_RADIUS_M
    if not spacing_m > 0:
        raise ValueError(f"particle spacing must be positive, got {spacing_m!r}")
    return max(REFERENCE_RADIUS_M, 0.75 * float(spacing_m))


def _disk_offsets(r_max: float) -> tuple[np.ndarray, np.ndarray]:
    """Pixel offsets (dx, dy) whose centres can lie within r_max of a point in the pixel [0, 1)^2."""
    k = int(math.ceil(r_max + 0.5))
    dy, dx = np.mgrid[-k:k + 1, -k:k + 1]
    gap_x = np.maximum(np.abs(dx) - 0.5, 0.0)
    gap_y = np.maximum(np.abs(dy) - 0.5, 0.0)
    keep = gap_x ** 2 + gap_y ** 2 <= r_max ** 2
    return dx[keep].astype(np.int64), dy[keep].astype(np.int64)


def _sure_offsets(r_min: float) -> np.ndarray | None:
    """Footprint of the pixels covered by a disk of radius r_min placed anywhere in the pixel [0, 1)^2."""
    k = int(math.floor(r_min))
    dy, dx = np.mgrid[-k:k + 1, -k:k + 1]
    sure = (np.abs(dx) + 0.5) ** 2 + (np.abs(dy) + 0.5) ** 2 <= r_min ** 2
    return sure if sure.any() else None


def _row_halfwidths(footprint: np.ndarray) -> np.ndarray:
    """Half-widths a[r] of a point-symmetric footprint (odd sizes, centred) whose every row r is the run of
    columns [c - a, c + a] around the centre column c (-1 for an empty row): the disks used here."""
    fp = np.asarray(footprint, dtype=bool)
    n = fp.sum(axis=1)
    a = np.where(n > 0, n // 2, -1).astype(np.int64)
    centred = np.abs(np.arange(fp.shape[1]) - fp.shape[1] // 2)[None, :] <= a[:, None]
    if not np.array_equal(fp, centred):  # an even run, or one off the middle, differs
        raise ValueError("footprint rows must be runs centred on the middle column")
    if (a < 0).all():
        raise ValueError("empty footprint")
    return a


def _morph(mask: np.ndarray, footprint: np.ndarray, erode: bool) -> np.ndarray:
    """Binary dilation (erode False) or erosion of ``mask`` by a disk-like ``footprint`` (see
    :func:`_row_halfwidths`), pixels outside the image False: ``scipy.ndimage.binary_dilation`` /
    ``binary_erosion`` with ``border_value=0``, computed by rows: the image's rows dilated (eroded) by each
    footprint row's run of columns, one column wider per pass, then shifted over the footprint's rows and combined
    (a few passes over the image instead of one per footprint element)."""
    a = _row_halfwidths(footprint)
    h, w = mask.shape
    need = set(int(k) for k in a[a >= 0])
    runs, run = {}, mask.copy()  # run: the rows dilated (eroded) by [-k, k], for k = 0, 1, ..
    for k in range(max(need) + 1):
        if k:
            prev = run.copy()
            if erode:
                run[:, 1:] &= prev[:, :-1]
                run[:, :-1] &= prev[:, 1:]
                run[:, :1] = False  # the column beyond the edge is False
                run[:, -1:] = False
            else:
                run[:, 1:] |= prev[:, :-1]
                run[:, :-1] |= prev[:, 1:]
        if k in need:
            runs[k] = run.copy()
    out = np.full_like(mask, erode)
    c = len(a) // 2
    for r, k in enumerate(a):
        if k < 0:
            continue
        d = r - c  # dilation: out[y] |= run[y - d]; erosion: out[y] &= run[y + d] (symmetric footprint)
        src = runs[int(k)]
        shift = d if not erode else -d
        lo, hi = max(shift, 0), min(h + shift, h)  # rows y of out whose source row y - shift lies in the image
        if lo >= hi:  # the footprint row reaches past the image: nothing to add, everything eroded
            if erode:
                out[:] = False
            continue
        if erode:
            out[lo:hi] &= src[lo - shift:hi - shift]
            out[:lo] = False
            out[hi:] = False
        else:
            out[lo:hi] |= src[lo - shift:hi - shift]
    return out


def _splat(shape, cx, cy, frac, r2, r_max: float, sure) -> np.ndarray:
    """The particles' disks in a crop (bool, ``shape``): particle i in pixel (cx, cy) of the crop, at ``frac`` inside
    it, covers the pixels of :func:`_disk_offsets` ``(r_max)`` whose centres lie within sqrt(r2) of it (float32).  The
    pixels every particle covers wherever it sits inside its own pixel (the ``sure`` footprint of
    :func:`_sure_offsets`, or None) are stamped at once by a dilation; then only particles near the edge of that
    coverage can add pixels, so the deep-interior ones are skipped."""
    ch, cw = shape
    crop = np.zeros(shape, dtype=bool)
    dx, dy = _disk_offsets(r_max)
    if sure is not None:
        in_crop = (cx >= 0) & (cx < cw) & (cy >= 0) & (cy < ch)
        k = int(math.ceil(r_max + 0.5))
        crop[cy[in_crop], cx[in_crop]] = True
        crop = _morph(crop, sure, erode=False)
        interior = ndimage.minimum_filter(crop, size=2 * k + 1, mode="constant", cval=False)
        edge = ~(in_crop & interior[np.clip(cy, 0, ch - 1), np.clip(cx, 0, cw - 1)])
        cx, cy, frac, r2 = cx[edge], cy[edge], frac[edge], r2[edge]
    ox = dx.astype(np.float32) + 0.5
    oy = dy.astype(np.float32) + 0.5
    r2 = r2[:, None]
    chunk = max(1, 4_000_000 // max(len(dx), 1))
    for s in range(0, len(cx), chunk):
        fx, fy = frac[s:s + chunk, 0:1], frac[s:s + chunk, 1:2]
        hit = (ox[None, :] - fx) ** 2 + (oy[None, :] - fy) ** 2 <= r2[s:s + chunk]
        px = (cx[s:s + chunk, None] + dx[None, :])[hit]
        py = (cy[s:s + chunk, None] + dy[None, :])[hit]
        good = (px >= 0) & (px < cw) & (py >= 0) & (py < ch)
        crop[py[good], px[good]] = True
    return crop


def _splat_native(shape, cx, cy, frac, r2, r_max: float, sure) -> np.ndarray:
    """:func:`_splat` by the native extension (``mpm._native.splat``): the same pixels (float32 arithmetic in the same
    order); the sure footprints first, then each particle's disk, row by row, skipping rows already set."""
    ch, cw = shape
    dx, dy = _disk_offsets(r_max)
    out = np.zeros(shape, dtype=np.uint8)
    if sure is None:
        sdx = sdy = np.zeros(0, np.int64)
    else:
        ys, xs = np.nonzero(sure)
        sdy, sdx = (ys - sure.shape[0] // 2).astype(np.int64), (xs - sure.shape[1] // 2).astype(np.int64)
    native_engine._native.splat(np.ascontiguousarray(cx, np.int64), np.ascontiguousarray(cy, np.int64),
                                np.ascontiguousarray(frac, np.float32), np.ascontiguousarray(r2, np.float32),
                                np.ascontiguousarray(dx, np.int64), np.ascontiguousarray(dy, np.int64), sdx, sdy, out,
                                ch, cw)
    return out.view(bool)


def render(positions_m, camera: Camera, image_size=WORKING_SIZE, radius_m: float | None = None, *,
           spacing_m: float | None = None, closing_px: int | None = None) -> np.ndarray:
    """Silhouette (height, width) bool of particles at ``positions_m`` (N, 3), metres, reference frame.

    radius_m: world radius of each particle's disk (default :func:`default_radius_m` of ``spacing_m``);
    its projected radius follows each particle's depth. closing_px: radius in pixels of the closing that
    fills gaps between particles (default 1 pixel, or a quarter of the projected spacing if larger;
    0 disables it).
    """
    width, height = image_size_of(image_size)
    mask = np.zeros((height, width), dtype=bool)
    p = np.asarray(positions_m, dtype=np.float64)
    if p.size == 0:
        return mask
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"positions must have shape (N, 3), got {p.shape}")
    p = p[np.isfinite(p).all(axis=1)]
    radius = default_radius_m(spacing_m) if radius_m is None else float(radius_m)
    if not radius > 0:
        raise ValueError(f"splat radius must be positive, got {radius_m!r}")

    uv, depth = camera.project_with_depth(p, (width, height))
    ok = np.isfinite(uv).all(axis=1)
    uv, depth = uv[ok], depth[ok]
    focal = camera.focal_px(height)
    r_px = focal * radius / depth
    inside = ((uv[:, 0] > -r_px) & (uv[:, 0] < width + r_px) & (uv[:, 1] > -r_px) & (uv[:, 1] < height + r_px))
    uv, r_px, depth = uv[inside], r_px[inside], depth[inside]
    if len(uv) == 0:
        return mask
    if closing_px is None:
        closing_px = 1
        if spacing_m is not None:
            closing_px = max(1, int(round(0.25 * focal * spacing_m / float(np.median(depth)))))

    r_max = float(r_px.max())
    margin = int(math.ceil(r_max)) + 2 + max(int(closing_px), 0)
    cells = np.floor(uv).astype(np.int64)
    # work in a crop around the particles (plus margin for disks and closing)
    x0 = max(int(cells[:, 0].min()) - margin, 0)
    y0 = max(int(cells[:, 1].min()) - margin, 0)
    x1 = min(int(cells[:, 0].max()) + margin + 1, width)
    y1 = min(int(cells[:, 1].max()) + margin + 1, height)
    cw, ch = x1 - x0, y1 - y0
    cx, cy = cells[:, 0] - x0, cells[:, 1] - y0
    frac = (uv - cells).astype(np.float32)
    splat = _splat_native if native_engine.available() else _splat
    crop = splat((ch, cw), cx, cy, frac, r_px.astype(np.float32) ** 2, r_max, _sure_offsets(float(r_px.min())))
    if closing_px and closing_px > 0:
        closing = disk(int(closing_px))
        crop = _morph(_morph(crop, closing, erode=False), closing, erode=True)  # binary closing, border False
    mask[y0:y1, x0:x1] = crop
    return mask


def render_frames(frames, camera: Camera, image_size=WORKING_SIZE, radius_m: float | None = None, *,
                  spacing_m: float | None = None, closing_px: int | None = None) -> np.ndarray:
    """Stack (F, height, width) of :func:`render` for each particle array in ``frames``."""
    width, height = image_size_of(image_size)
    out = [render(p, camera, (width, height), radius_m, spacing_m=spacing_m, closing_px=closing_px)
           for p in frames]
    return np.stack(out) if out else np.zeros((0, height, width), dtype=bool)


def box_corners(width_m: float, height_m: float, depth_m: float) -> np.ndarray:
    """(8, 3) corners of the box [0, W] x [0, H] x [0, D]; corner i has (x, y, z) bits (i&1, i>>1&1, i>>2&1)."""
    i = np.arange(8)
    return np.stack([(i & 1) * width_m, (i >> 1 & 1) * height_m, (i >> 2 & 1) * depth_m], axis=1).astype(float)


def polygon_mask(points_uv, image_size=WORKING_SIZE) -> np.ndarray:
    """Fill the convex hull of continuous pixel points (u, v): pixels whose centres lie inside."""
    width, height = image_size_of(image_size)
    pts = np.asarray(points_uv, dtype=float)
    mask = np.zeros((height, width), dtype=bool)
    pts = pts[np.isfinite(pts).all(axis=1)]
    if len(pts) < 3:
        return mask
    try:
        hull = pts[ConvexHull(pts).vertices]
    except QhullError:  # degenerate (collinear) outline: no area
        return mask
    # skimage puts pixel (r, c) at the point (r, c); our pixel centres are at (row + 0.5, col + 0.5)
    rr, cc = fill_polygon(hull[:, 1] - 0.5, hull[:, 0] - 0.5, shape=(height, width))
    mask[rr, cc] = True
    return mask


def box_mask(camera: Camera, width_m: float, height_m: float, depth_m: float,
             image_size=WORKING_SIZE) -> np.ndarray:
    """Silhouette of the solid box [0, W] x [0, H] x [0, D] (the initial cuboid): its projected hull."""
    return polygon_mask(camera.project(box_corners(width_m, height_m, depth_m), image_size), image_size)
