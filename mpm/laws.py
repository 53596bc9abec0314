"""Eq. 1's special cases: the laws a Herschel-Bulkley material may reduce to, by the parameters each fixes (SI).

Bingham (n = 1), the power law (sigma_y = 0) and Newtonian (both) lie on faces and an edge of the material space
(mpm.params ranges).  Their evidence from footage: similarity/evidence.py; their rheometer fits:
surrogate/rheometer.py.  Not part of the simulator (mpm.batch leaves it out of the code version).
"""
LAWS = {"herschel-bulkley": {}, "bingham": {"n": 1.0}, "power-law": {"sigma_y": 0.0},
        "newtonian": {"n": 1.0, "sigma_y": 0.0}}
