"""The solver's density correction (mpm.kernels): where particles crowd, their volume ratio follows the spacing.

Plane-strain runs of the runniest shared flow (Worcestershire sauce at Table 1 in its 21 x 40 mm setup), a few
seconds in all.
"""
from types import SimpleNamespace as NS

import numpy as np

from mpm import solver

RUNNY = NS(eta=0.55, n=0.81, sigma_y=1.95)
SETUP = NS(width_mm=21, height_mm=40)


def _front_mm(cell_mm, corrected, ppc=1, material=RUNNY):
    sim = solver.simulate(material, SETUP, density=1200.0, cell_mm=cell_mm, ppc=ppc, dim=2,
                          density_correction=corrected)
    return sim.front_m * 1e3, sim


def test_one_particle_per_cell_converges_with_the_correction(mpm_engine):
    """Without it one particle per cell loses runout under refinement (particles clump where the thin film
    stretches); with it the runout of 1.5 mm and 0.75 mm cells agrees within 4 mm on a ~13 cm flow."""
    fronts = {(c, dc): _front_mm(c, dc)[0] for c in (1.5, 0.75) for dc in (False, True)}
    plain = fronts[(1.5, False)][-1] - fronts[(0.75, False)][-1]
    corrected = abs(fronts[(1.5, True)][-1] - fronts[(0.75, True)][-1])
    assert plain > 8.0
    assert corrected < 4.0
    # ... and it flows further than the uncorrected model at either cell width, towards two particles per axis
    two = _front_mm(0.75, True, ppc=2)[0][-1]
    assert fronts[(0.75, True)][-1] > fronts[(1.5, False)][-1] + 10.0
    assert abs(fronts[(0.75, True)][-1] - two) < 0.1 * two


def test_it_leaves_a_block_at_rest_alone(mpm_engine):
    """A block whose yield stress holds it (sigma_y >> rho g H) is spaced as it started: the correction, which
    only acts where particles crowd beyond what their volume ratio says, changes nothing visible, and mass
    is conserved either way."""
    stiff = NS(eta=10.0, n=1.0, sigma_y=500.0)
    a, sa = _front_mm(3.0, False, material=stiff)
    b, sb = _front_mm(3.0, True, material=stiff)
    assert np.abs(a - b).max() < 0.3  # mm
    assert sb.stats["grid_mass_rel_err"] < 1e-4
    assert np.allclose(sa.stats["mean_J"], sb.stats["mean_J"], atol=2e-3)


def test_it_lowers_the_volume_ratio_by_a_fraction_of_a_percent(mpm_engine):
    """The correction compresses crowded particles and never expands any: at the end of a runny run the moving
    particles' mean J = sqrt(det b_e) is lower with it than without, and both stay within a percent of 1, the
    hydrostatic compression of eq. 12 at kappa = 1e4 Pa (the volume the particles stand for is kept; their spacing
    is what changes)."""
    means = {corrected: _front_mm(1.5, corrected)[1].stats["mean_J"][-1] for corrected in (False, True)}
    assert means[True] < means[False]
    assert all(abs(m - 1.0) < 0.01 for m in means.values())
