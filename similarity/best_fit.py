"""The best fit the report's simulations found, against the estimate it started from.

The CMA-ES estimate is the optimiser's answer, not necessarily the best simulated fit: a short search can stop in
a flat similarity valley (section 5) short of its floor.  The report simulates hundreds of materials around the
estimate and on the special laws' faces (:mod:`similarity.face_search`); where one of them fits the footage better
than the estimate by at least ``NOTE_NATS`` under eq. (1) of :mod:`similarity.likelihood`, the report says so.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mpm.files import JsonRecord
from mpm.params import Material
from similarity.space import denormalize

NOTE_NATS = 1.0  # a better fit by less than this is within the footage's noise: not worth a line


@dataclass(kw_only=True)
class BestFit(JsonRecord):
    """The lowest simulated loss among the report's simulations, and the estimate's."""

    material: Material
    loss: float  # mean video loss over the run's setups (eq. 3), at the run's final model
    estimate_loss: float
    nats: float  # tau (estimate_loss - loss), eq. (1): how much better it fits than the estimate
    law: str  # the narrowest law whose face it lies on ("herschel-bulkley": on none)

    READERS = {"material": lambda d: Material(**d)}

    @property
    def better(self) -> bool:
        """Whether it fits the footage better than the estimate by at least ``NOTE_NATS``."""
        return self.nats >= NOTE_NATS

    @property
    def text(self) -> str:
        m = self.material
        where = "" if self.law == "herschel-bulkley" else f" (on the {self.law} face)"
        return (f"a better fit than the estimate was simulated: eta {m.eta:.3g} Pa s^n, n {m.n:.3g}, sigma_y "
                f"{m.sigma_y:.3g} Pa{where}, mean loss {self.loss:.5f} against the estimate's {self.estimate_loss:.5f} "
                f"({self.nats:.1f} nats better)")


def best_fit(X, y, estimate_loss: float, precision: float, laws) -> BestFit | None:
    """The best of the simulated normalised materials ``X`` (k, 3) with mean losses ``y`` (NaN: failed), against the
    estimate's loss; ``precision``: tau of eq. (1); ``laws``: :class:`similarity.evidence.Law` values, the narrowest
    whose every fixed coordinate the best material holds names its face.  None where nothing simulated finitely."""
    y = np.asarray(y, float)
    if not np.isfinite(y).any():
        return None
    i = int(np.nanargmin(y))
    x = np.asarray(X, float)[i]
    on = [law for law in laws if law.on_face(x, x)]  # the box of one point reaches the faces it lies on
    law = max(on, key=lambda law: len(law.fixed)).name if on else "herschel-bulkley"
    return BestFit(material=Material.from_array(denormalize(np.clip(x, 0.0, 1.0))), loss=float(y[i]),
                   estimate_loss=float(estimate_loss), nats=float(precision * (estimate_loss - y[i])), law=law)
