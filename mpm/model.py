"""The forward model as one value (:class:`ForwardModel`): how a material is simulated apart from the experiment,
with the solver's defaults.  Validated once, at construction, with every bound the scene and the CLI enforce;
it travels whole from the caller through the store request (:class:`mpm.store.SimRequest`) to the worker that
simulates it (:func:`mpm.solver.simulate`).  No Taichi here.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace

from mpm import runtime
from mpm.params import check_flow_rule
from mpm.ranges import SLIP_RANGE_M, check_cell_mm, check_modulus, check_ppc, check_within
from mpm.scene import KAPPA_PA, MU_PA

DEFAULT_CELL_MM = 1.5  # with one particle per cell per axis; chosen by measurement: docs/decisions.md#discretisation
PARTICLES_PER_CELL = 1  # per axis (the reference implementation uses 2; see docs/method/forward-model.md)
SLIP_LENGTH_M = 0.0  # Navier slip length of floor and walls (0: sticking); measured: docs/decisions.md#walls


@dataclass(frozen=True)
class ForwardModel:
    """The forward model of a simulation: MPM cell width in mm, particles per cell per axis, the walls' Navier
    slip length in metres, the solver's density correction, the flow rule, the engine and the elastic moduli in Pa.
    None: the solver's default (``DEFAULT_CELL_MM``, ``PARTICLES_PER_CELL``, sticking walls, the paper's kappa =
    1e4 Pa and mu = 1e3 Pa); ``engine`` None: the one ``$VIRHEO_ARCH`` chooses (:func:`mpm.runtime.engine_for`),
    else one of :data:`mpm.runtime.ENGINES`."""

    cell_mm: float | None = None
    ppc: int | None = None
    slip_length_m: float | None = None
    density_correction: bool = False
    flow_rule: str = "paper"
    engine: str | None = None
    kappa_pa: float | None = None
    mu_pa: float | None = None

    def __post_init__(self):
        """Every bound the scene enforces, checked here once, so that a bad model never reaches a worker."""
        if self.cell_mm is not None:
            check_cell_mm(self.cell_mm)
        if self.ppc is not None:
            check_ppc(self.ppc)
        if self.slip_length_m is not None:
            check_within(self.slip_length_m, SLIP_RANGE_M, "m", "slip length")
        for name in ("kappa_pa", "mu_pa"):
            if getattr(self, name) is not None:
                check_modulus(getattr(self, name), name)
        if self.engine is not None and self.engine not in runtime.ENGINES:
            raise ValueError(f"unknown engine {self.engine!r}: expected one of {', '.join(runtime.ENGINES)}")
        check_flow_rule(self.flow_rule)

    def resolved(self) -> "ForwardModel":
        """The same with the solver's discretisation and walls filled in (the moduli and the engine stay as they
        are: None is the paper's moduli, and leaves the engine to ``mpm.runtime`` when a request is made)."""
        return ForwardModel(float(DEFAULT_CELL_MM if self.cell_mm is None else self.cell_mm),
                            int(PARTICLES_PER_CELL if self.ppc is None else self.ppc),
                            float(SLIP_LENGTH_M if self.slip_length_m is None else self.slip_length_m),
                            bool(self.density_correction), self.flow_rule, self.engine, self.kappa_pa, self.mu_pa)

    def keyed(self, precision: str = "f32") -> "ForwardModel":
        """The resolved model as a store request names it: sticking walls and the paper's moduli as None (the keys
        they always had), the engine resolved by ``mpm.runtime`` for ``precision`` where the model leaves it open."""
        r = self.resolved()
        return replace(r, slip_length_m=r.slip_length_m or None, engine=r.engine or runtime.engine_for(precision),
                       kappa_pa=None if r.kappa_pa in (None, KAPPA_PA) else float(r.kappa_pa),
                       mu_pa=None if r.mu_pa in (None, MU_PA) else float(r.mu_pa))

    def to_dict(self) -> dict:
        """The model as a dict; the paper's moduli (None) are left out, as in records written before the model
        carried them."""
        return {k: v for k, v in asdict(self).items() if not (k in ("kappa_pa", "mu_pa") and v is None)}

    @classmethod
    def from_dict(cls, d: dict) -> "ForwardModel":
        """The model of ``to_dict()``; also reads the four-key dicts that result files held before the model had
        a flow rule and an engine.  One-line ValueError for other keys."""
        names = {f.name for f in fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"not a forward model: unknown key(s) {', '.join(sorted(unknown))}")
        return cls(**d)

    @classmethod
    def of_record(cls, record: dict) -> "ForwardModel":
        """The model a result.json or a stage of its history was computed with: its nested ``model``, else the
        ``discretisation`` of result files written before the model was one value, else a stage's loose
        ``cell_mm``/``ppc``/``slip_length_m``/``density_correction`` fields (missing ones: the defaults)."""
        for key in ("model", "discretisation"):
            if isinstance(record.get(key), dict):
                return cls.from_dict(record[key])
        return cls.from_dict({k: record[k] for k in ("cell_mm", "ppc", "slip_length_m", "density_correction")
                              if k in record})


MODEL_FIELDS = tuple(f.name for f in fields(ForwardModel))
