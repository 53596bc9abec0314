"""Dam-break scene (numpy only, no Taichi): lattice, walls, visibility rule, validation."""
import math
from types import SimpleNamespace as NS

import numpy as np
import pytest

from mpm import scene as sc
from mpm.params import Material, Setup, frame_times


def _scene(w_mm, h_mm, cell_mm=1.26, depth_mm=40.0, dim=3, density=1000.0):
    return sc.DamBreak.build(NS(width_mm=w_mm, height_mm=h_mm), density=density, cell_mm=cell_mm,
                             depth_mm=depth_mm, dim=dim)


@pytest.mark.parametrize("w, h, shape", [(20, 20, (35, 35, 69)), (25, 20, (43, 35, 69)), (70, 70, (114, 114, 69)),
                                         (20, 21, (35, 36, 69))])
def test_lattice_counts_match_the_reference(w, h, shape):
    """The reference implementation's lattice: nd = ceil((max - min) / (dx/2)) per axis at 1.26 mm cells."""
    s = _scene(w, h)
    assert s.lattice_shape() == shape
    assert s.n_particles == math.prod(shape)
    p = s.particles()
    assert p.shape == (math.prod(shape), 3)
    assert np.allclose(p[0], -sc.OVERLAP_M + 0.5 * s.spacing_m)  # cell-centred, no jitter
    assert p[1, 0] > p[0, 0] and p[1, 1] == p[0, 1]  # x index fastest
    # the block overshoots W and H by less than one spacing
    assert w * 1e-3 <= p[:, 0].max() + s.half_length_m < w * 1e-3 + s.spacing_m
    assert s.particle_volume == pytest.approx(s.spacing_m ** 3)
    assert s.half_length_m == pytest.approx(s.cell_m / 4)


def test_walls_freeze_the_overlap_and_hide_floor_and_near_wall():
    """All overlap layers frozen; floor and near-side-wall layers hidden, back-wall and
    far-side-wall coating visible; the material itself is neither."""
    s = _scene(20, 21)
    p = s.particles()
    frozen, hidden = s.frozen_and_hidden(p)
    d = s.depth_m
    inside = (p[:, 0] > 0) & (p[:, 1] > 0) & (p[:, 2] > 0) & (p[:, 2] < d)
    assert not frozen[inside].any() and not hidden[inside].any()
    # the block's last column overshoots x = W, past the side walls' end: free there
    assert frozen[~inside & (p[:, 0] <= s.width_m)].all()
    assert not frozen[p[:, 0] > s.width_m][p[p[:, 0] > s.width_m, 1] > 0].any()
    floor = p[:, 1] < 0
    near = (p[:, 2] > d) & (p[:, 1] > 0) & (p[:, 0] <= s.width_m)
    assert hidden[floor].all() and hidden[near].all()
    coat = ~floor & ((p[:, 0] < 0) | (p[:, 2] < 0)) & (p[:, 2] <= d)
    assert coat.sum() > 0 and not hidden[coat].any()
    nx, ny, nz = s.lattice_shape()
    assert floor.sum() == 2 * nx * nz  # two particle layers in the floor at 1.26 mm cells


def test_plane_strain_section_meets_only_floor_and_back_wall():
    s = _scene(30, 20, cell_mm=3.0, dim=2)
    p = s.particles()
    assert p.shape[1] == 2
    frozen, hidden = s.frozen_and_hidden(p)
    assert np.array_equal(frozen, (p[:, 0] < 0) | (p[:, 1] < 0))
    assert np.array_equal(hidden, p[:, 1] < 0)
    assert s.particle_volume == pytest.approx(s.spacing_m ** 2)


def test_wave_speed_frames_and_reach():
    assert sc.elastic_wave_speed(1000.0) == pytest.approx(math.sqrt((1e4 + 4e3 / 3) / 1000.0))
    assert np.allclose(frame_times(), np.arange(1, 9) / 24)
    s = _scene(30, 20, cell_mm=3.0)
    lo, hi = s.reach()
    blo, bhi = s.block()
    assert np.all(lo < blo) and np.all(hi > bhi)
    # the inviscid front speed 2 sqrt(gH) for 1/3 s stays inside
    assert hi[0] - s.width_m > 2 * math.sqrt(9.81 * s.height_m) / 3
    # side walls contain at least one grid node even for coarse cells
    for cell in (1.0, 3.0, 4.5):
        b = _scene(30, 20, cell_mm=cell).boxes()
        assert np.all(b[2:, 1, 2] - b[2:, 0, 2] >= cell * 1e-3)


@pytest.mark.parametrize("kw, match", [
    (dict(setup=NS(width_mm=19, height_mm=30)), "width"),
    (dict(setup=NS(width_mm=30, height_mm=71)), "height"),
    (dict(setup=NS(width_mm=30)), "height_mm"),
    (dict(density=0.0), "density"),
    (dict(density=float("nan")), "density"),
    (dict(cell_mm=0.0), "cell"),
    (dict(depth_mm=-1.0), "depth"),
    (dict(dim=4), "dim"),
])
def test_bad_scene_input_is_a_one_line_value_error(kw, match):
    args = dict(setup=NS(width_mm=30, height_mm=20), density=1000.0, cell_mm=3.0, depth_mm=40.0, dim=3)
    args.update(kw)
    setup = args.pop("setup")
    with pytest.raises(ValueError, match=match) as e:
        sc.DamBreak.build(setup, **args)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("mat, match", [((0.0, 1.0, 0.0), "eta=0 Pa s"), ((1.0, 0.0, 0.0), "n=0 is"),
                                        ((1.0, 1.0, -1.0), "sigma_y=-1 Pa"), ((float("inf"), 1.0, 0.0), "eta=inf")])
def test_unphysical_material_is_one_line_with_the_same_wording_everywhere(mat, match):
    from mpm.shear import simple_shear

    messages = []
    for make in (lambda: Material(*mat), lambda: Material.of(NS(eta=mat[0], n=mat[1], sigma_y=mat[2])),
                 lambda: simple_shear([1.0, mat[0]], [1.0, mat[1]], [0.0, mat[2]], t_end=1e-3)):
        with pytest.raises(ValueError, match=match) as e:
            make()
        messages.append(str(e.value))
    assert len(set(messages)) == 1 and "unphysical" in messages[0] and "\n" not in messages[0]


def test_setup_outside_the_range_has_the_same_wording_everywhere():
    with pytest.raises(ValueError) as built:
        sc.DamBreak.build(NS(width_mm=75, height_mm=30), density=1000.0, cell_mm=3.0)
    with pytest.raises(ValueError) as checked:
        Setup(75, 30).check_in_space()
    assert str(built.value) == str(checked.value) == "width_mm=75 lies outside the setup space 20..70 mm"
