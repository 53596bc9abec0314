"""Navier slip of floor and walls (mpm.solver): the no-slip limit and the analytic sliding layer."""
from types import SimpleNamespace as NS

import numpy as np
import pytest

from mpm import scene as sc
from mpm import engine, solver
from mpm.camera import Camera
from mpm.loss import iou
from mpm.model import ForwardModel

RUNNY = NS(eta=0.55, n=0.81, sigma_y=1.95)  # the Worcestershire sauce of Table 1, a thin runny film
SETUP = NS(width_mm=30, height_mm=20)


def _run(**kw):
    return solver.simulate(RUNNY, SETUP, density=1200.0, cell_mm=5.0, camera=Camera.default(),
                           image_size=(320, 180), **kw)


def test_slip_length_to_zero_is_the_sticking_floor(mpm_engine):
    stick = _run(slip_length_m=0.0)
    tiny = _run(slip_length_m=1e-9)
    assert np.abs(tiny.front_m - stick.front_m).max() < 1e-6
    assert min(iou(a, b) for a, b in zip(stick.silhouettes, tiny.silhouettes)) > 0.999
    # a real slip length lets the film run further: the runout grows with b
    slip = _run(slip_length_m=3e-3)
    assert slip.front_m[-1] > stick.front_m[-1] + 2e-3


def test_the_coating_inside_slipping_walls_stays_unstrained(monkeypatch):
    """Particles inside a wall box are frozen. Under slip their wall nodes move, so a strain integrated there
    at rest would grow without bound and push the material beside them (3D runs at 1.5 mm cells with
    slipping side walls blew up that way): the coating keeps its elastic state b_e = I. (Taichi only: the
    native engine does not hand out its particles' b_e.)"""
    monkeypatch.setenv("VIRHEO_ARCH", "taichi-cpu")
    scene = sc.DamBreak.build(SETUP, density=1200.0, cell_mm=3.0, dim=3)
    eng = engine.engine(3, "f32")
    run = solver._Run(eng, scene, RUNNY.eta, RUNNY.n, RUNNY.sigma_y, False, slip_m=2e-3)
    coating, _ = scene.frozen_and_hidden(scene.particles())
    run.execute()
    be = eng.be.to_numpy()[: run.count]
    assert coating.sum() > 500 and (~coating).sum() > 500
    assert np.array_equal(be[coating], np.broadcast_to(np.eye(3, dtype=be.dtype), be[coating].shape))
    # the material itself deforms (the test would pass vacuously on a run that never moved)
    assert np.abs(be[~coating] - np.eye(3)).max() > 1e-3


def test_bad_slip_length():
    for b in (-1e-3, float("nan"), "x", 2.0):
        with pytest.raises(ValueError, match="slip length"):
            ForwardModel(slip_length_m=b)


class _FloorOnly(sc.DamBreak):
    """The dam-break block with the floor as the only wall (back and side walls moved far away)."""

    def boxes(self):
        b = super().boxes().copy()
        b[1:] = [[-9.0, -9.0, -9.0], [-8.0, -8.0, -8.0]]
        return b


def _sections(frames, stats, visible0: int) -> list:
    """(x, y) of each visible particle of a plane-strain run per frame, in the scene's order (its frames extrude
    each particle over the depth); the visible set must stay the one it started with."""
    out = []
    for f, n in zip(frames, stats["n_visible"]):
        assert n == visible0 and len(f) % n == 0
        out.append(f[:: len(f) // n, :2])
    return out


@pytest.mark.parametrize("slip_m", [0.0, 4e-3])
def test_layer_under_horizontal_body_force_slides_as_the_navier_law_predicts(mpm_engine, slip_m):
    """A Newtonian layer (n = 1, sigma_y = 0) of height h on the floor, pushed along x by a body force g:
    steady flow u(y) = (g/nu) (h y - y^2/2 + b h), nu = eta/rho, with the Navier slip u(0) = b u'(0).
    After a few diffusion times h^2/nu the particles between frames 4 and 8 (1/6 s) move u(y) * 1/6 s."""
    eta, rho, g, h = 10.0, 1000.0, 0.5, 0.02
    scene = _FloorOnly.build(NS(width_mm=70, height_mm=20), density=rho, cell_mm=1.0, dim=2, ppc=2)
    start, name, _ = solver.runner(2)
    assert name == mpm_engine
    frames, _, stats = start(scene, eta, 1.0, 0.0, False, slip_m=slip_m, body=(g, 0.0, 0.0)).execute()
    x0 = scene.particles()
    x0 = x0[~scene.frozen_and_hidden(x0)[1]]  # the visible ones: all but the floor's coating
    snaps = _sections(frames, stats, len(x0))
    nu = eta / rho
    assert h * h / nu < 0.1  # steady well before frame 4 (t = 1/6 s)
    # the middle third of the layer, away from its free ends; not the frozen floor coating
    mid = (x0[:, 0] > 0.025) & (x0[:, 0] < 0.045) & (x0[:, 1] > 0)
    y = snaps[3][mid, 1]  # frame 4
    moved = snaps[7][mid, 0] - snaps[3][mid, 0]
    expected = g / nu * (h * y - 0.5 * y * y + slip_m * h) / 6.0
    bottom = y < 0.25 * h
    # the mean displacement of the layer, and of its bottom quarter (where the slip matters most)
    # (measured: 6 % and 4 % high without slip, 4 % and 2 % with; the curvature is within 2 % of -g/(2 nu))
    assert moved.mean() == pytest.approx(expected.mean(), rel=0.08)
    assert moved[bottom].mean() == pytest.approx(expected[bottom].mean(), rel=0.06)
    # the slip velocity itself: the profile's value at the wall, fitted through the particles
    coef = np.polyfit(y, moved * 6.0, 2)
    assert coef[0] == pytest.approx(-0.5 * g / nu, rel=0.04)
    slip_fitted = coef[-1] / (g / nu * h)  # u(0) / u'(0): 3.98 mm for b = 4 mm, -0.03 mm for b = 0
    assert slip_fitted == pytest.approx(slip_m, abs=3e-4)
