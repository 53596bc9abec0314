"""Silhouettes from particles: exact disk coverage, agreement with the projected box, no holes."""
import numpy as np
import pytest
from scipy import ndimage
from skimage.morphology import disk

from mpm import native_engine
from mpm.camera import Camera
from mpm.loss import iou
from mpm.silhouette import (REFERENCE_RADIUS_M, REFERENCE_SPACING_M, _morph, _sure_offsets, box_corners,
                            box_mask, default_radius_m, render, render_frames)

CAM = Camera.default()


def cuboid(width, height, depth, spacing, jitter=0.0, seed=0):
    axes = [np.arange(spacing / 2, length, spacing) for length in (width, height, depth)]
    p = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    return p + np.random.default_rng(seed).normal(0.0, jitter * spacing, p.shape)


def brute_force(points, camera, radius, size=(960, 540)):
    """Pixels whose centres are within each particle's projected radius (no shortcuts)."""
    w, h = size
    uv = camera.project(points, size)
    r = camera.focal_px(h) * radius / camera.depth(points)
    mask = np.zeros((h, w), dtype=bool)
    for (u, v), rp in zip(uv, r):
        c0, c1 = max(int(u - rp) - 1, 0), min(int(u + rp) + 2, w)
        r0, r1 = max(int(v - rp) - 1, 0), min(int(v + rp) + 2, h)
        if c0 >= c1 or r0 >= r1:
            continue
        cols, rows = np.meshgrid(np.arange(c0, c1) + 0.5, np.arange(r0, r1) + 0.5)
        mask[r0:r1, c0:c1] |= (cols - u) ** 2 + (rows - v) ** 2 <= rp ** 2
    return mask


@pytest.mark.parametrize("radius", [0.4e-3, 1.0e-3, 3.0e-3])
def test_splats_cover_exactly_the_pixel_centres_inside_each_disk(radius):
    rng = np.random.default_rng(3)
    pts = rng.uniform([0.0, 0.0, 0.0], [0.05, 0.03, 0.04], size=(300, 3))
    expected = brute_force(pts, CAM, radius)
    got = render(pts, CAM, radius_m=radius, closing_px=0)
    assert np.array_equal(got, expected)


@pytest.mark.parametrize("density", [0.005, 0.02, 0.2, 0.6])
@pytest.mark.parametrize("r_min", [0.8, 3.2, 10.5, 40.0])
def test_morphology_by_rows_is_scipys(r_min, density):
    # dilation, erosion (outside the image False) and closing by the 'sure' footprint and by a disk, computed by
    # rows, pixel for pixel as scipy's; set pixels on the edges, and footprints wider than the image
    rng = np.random.default_rng(int(r_min * 10 + density * 100))
    mask = rng.random((60, 90)) < density
    mask[0, 5] = mask[59, 89] = mask[30, 0] = True
    for fp in (_sure_offsets(r_min), disk(int(r_min) // 2)):
        dilated = _morph(mask, fp, erode=False)
        assert np.array_equal(dilated, ndimage.binary_dilation(mask, structure=fp))
        assert np.array_equal(_morph(mask, fp, erode=True), ndimage.binary_erosion(mask, structure=fp, border_value=0))
        assert np.array_equal(_morph(dilated, fp, erode=True),
                              ndimage.binary_closing(mask, structure=fp, border_value=0))


def test_dense_cuboid_shortcut_is_exact():
    pts = cuboid(0.02, 0.02, 0.02, 1.0e-3, jitter=0.1)
    got = render(pts, CAM, radius_m=1.0e-3, closing_px=0)
    # only pixels near the outline can differ if the interior shortcut were wrong: compare on the band
    assert np.array_equal(got, brute_force(pts, CAM, 1.0e-3))
    assert not (got ^ ndimage.binary_fill_holes(got)).any()


def test_cuboid_of_particles_matches_projected_box():
    # particles fill [0, W] x [0, H] x [0, D]; disks of half the spacing reach exactly the faces
    s = REFERENCE_SPACING_M
    pts = cuboid(0.03, 0.02, 0.04, s, jitter=0.15)
    box = box_mask(CAM, 0.03, 0.02, 0.04)
    assert iou(render(pts, CAM, radius_m=s / 2), box) > 0.95
    # the default surface sits (radius - s/2) outside the material, as the reference's skinned surface
    off = default_radius_m(s) - s / 2
    grown = box_mask(CAM, 0.03 + 2 * off, 0.02 + 2 * off, 0.04 + 2 * off)  # shifted below by -off
    shifted = render(pts + off, CAM, spacing_m=s)
    assert iou(shifted, grown) > 0.95
    assert np.count_nonzero(box & ~render(pts, CAM, spacing_m=s)) < 0.002 * box.sum()


@pytest.mark.parametrize("spacing", [1.26e-3, 2.5e-3, 4e-3])
def test_sparse_particles_leave_no_holes(spacing):
    pts = cuboid(0.03, 0.03, 0.04, spacing, jitter=0.1)
    off = default_radius_m(spacing) - spacing / 2  # the surface's distance outside the material
    mask = render(pts + off, CAM, spacing_m=spacing)
    assert np.array_equal(mask, ndimage.binary_fill_holes(mask))
    grown = box_mask(CAM, 0.03 + 2 * off, 0.03 + 2 * off, 0.04 + 2 * off)
    assert np.count_nonzero(mask & ~grown) <= 0.002 * grown.sum()  # not beyond the surface (jitter aside)
    # spheres of radius r round the box's edges: the deficit is confined to a band of width ~r
    assert iou(mask, grown) > (0.95 if spacing < 2e-3 else 0.75)


def test_default_radius():
    assert default_radius_m() == REFERENCE_RADIUS_M
    assert default_radius_m(REFERENCE_SPACING_M) == pytest.approx(REFERENCE_RADIUS_M)
    assert default_radius_m(2.52e-3) >= 0.75 * 2.52e-3
    assert default_radius_m(1.0e-3) == REFERENCE_RADIUS_M
    with pytest.raises(ValueError):
        default_radius_m(0.0)


def test_degenerate_inputs():
    empty = render(np.zeros((0, 3)), CAM)
    assert empty.shape == (540, 960) and not empty.any()
    behind = render([[0.09, 0.135, 0.5]], CAM)  # behind the eye
    assert not behind.any()
    with_nan = render([[0.01, 0.01, 0.01], [np.nan, 0, 0]], CAM)
    assert with_nan.sum() == render([[0.01, 0.01, 0.01]], CAM).sum() > 0
    with pytest.raises(ValueError):
        render(np.zeros((5, 2)), CAM)
    assert render([[0.01, 0.01, 0.01]], CAM, (480, 270)).shape == (270, 480)


def test_box_corners_and_mask():
    c = box_corners(0.03, 0.02, 0.04)
    assert c.shape == (8, 3) and c.max(axis=0).tolist() == [0.03, 0.02, 0.04]
    small, big = box_mask(CAM, 0.02, 0.02, 0.04), box_mask(CAM, 0.04, 0.02, 0.04)
    assert small.sum() > 0 and (small & ~big).sum() == 0


def test_render_frames_stacks_the_frames_in_order():
    """render_frames is render per frame; a cuboid moved along +x moves its silhouette right."""
    base = cuboid(0.02, 0.02, 0.04, 1.5e-3)
    frames = [base + np.array([0.004 * k, 0.0, 0.0]) for k in range(3)]
    masks = render_frames(frames, CAM, (480, 270), spacing_m=1.5e-3)
    assert masks.shape == (3, 270, 480) and masks.dtype == bool
    for mask, f in zip(masks, frames):
        assert np.array_equal(mask, render(f, CAM, (480, 270), spacing_m=1.5e-3))
    right = [np.flatnonzero(m.any(axis=0)).max() for m in masks]
    assert right[0] < right[1] < right[2]
    assert render_frames([], CAM, (480, 270)).shape == (0, 270, 480)


def test_particles_beyond_the_image_edge():
    # a camera close to a slab so that the slab overflows the image on every side
    cam = Camera(eyepos_m=(0.015, 0.01, 0.03), quat=(1.0, 0.0, 0.0, 0.0))
    pts = cuboid(0.06, 0.04, 0.004, 1.0e-3, jitter=0.1) - np.array([0.015, 0.01, 0.0])
    pts = pts[np.random.default_rng(5).random(len(pts)) < 0.3]  # sparse: exercise the edge particles too
    got = render(pts, cam, (320, 180), radius_m=0.8e-3, closing_px=0)
    assert got[0].any() and got[-1].any() and got[:, 0].any() and got[:, -1].any()
    assert np.array_equal(got, brute_force(pts, cam, 0.8e-3, (320, 180)))


@pytest.mark.skipif(not native_engine.available(), reason=native_engine.why_unavailable() or "native engine absent")
@pytest.mark.parametrize("seed", range(6))
def test_native_splat_sets_the_same_pixels_as_numpy(seed, monkeypatch):
    """The native extension's splat against the numpy one, pixel for pixel: dense lattices (most particles deep inside),
    sparse clouds, radii from under a pixel to tens of pixels, particles beyond the image's edges."""
    rng = np.random.default_rng(seed)
    cam = Camera(eyepos_m=(0.015, 0.01, 0.03), quat=(1.0, 0.0, 0.0, 0.0)) if seed % 3 == 2 else CAM
    spacing = rng.uniform(0.5e-3, 5e-3)
    pts = cuboid(0.06, 0.03, 0.04, spacing, jitter=rng.uniform(0, 0.5), seed=seed)
    if seed % 2:
        pts = pts[rng.random(len(pts)) < 0.2]
    cases = [dict(spacing_m=spacing), dict(radius_m=rng.uniform(0.05e-3, 4e-3), closing_px=0)]
    native = [render(pts, cam, (480, 270), **kw) for kw in cases]
    monkeypatch.setattr(native_engine, "available", lambda: False)
    for got, kw in zip(native, cases):
        assert np.array_equal(got, render(pts, cam, (480, 270), **kw))
        assert got.any()
