"""The dam-break scene (paper section 3.3) as the reference implementation sets it up: geometry,
particle lattice, walls, moduli and the region the flow can reach. Pure numpy, no Taichi; SI units
inside, setups arrive in millimetres.

Frame: origin at the bottom, back-wall, far-side-wall corner of the specimen; x along the width (the flow
direction, out through the open front at x = W), y up, z towards the camera. The particle block reaches
``OVERLAP_M`` into floor, back wall and side walls; those particles stay frozen (a coating). No gate.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mpm.params import DEFAULT_DEPTH_MM, FPS, N_FRAMES, Setup
from mpm.ranges import check_cell_mm, check_density, check_modulus, check_ppc

KAPPA_PA = 1.0e4  # bulk modulus kappa (section 4.2)
MU_PA = 1.0e3  # shear modulus mu
GRAVITY = 9.81  # m/s^2, along -y
OVERLAP_M = 1.5e-3  # particle block reaches this far into floor, back wall and side walls
SIDE_WALL_M = 3.0e-3  # thickness of the side walls
BACK_WALL_M = 1.0e-2  # thickness of the back wall and the floor
WALL_TOP_M = 0.2  # walls are 20 cm tall
REFERENCE_PARTICLES_PER_CELL = 2  # per axis, as the reference implementation samples; the solver picks its own
MAX_PARTICLES = 8_000_000  # refuse cell widths that need more (0.63 mm, 2 per axis, on 70 x 70 mm: 7.1 M)


def elastic_wave_speed(density: float, kappa: float = KAPPA_PA, mu: float = MU_PA) -> float:
    """P-wave speed sqrt((kappa + 4/3 mu) / rho) in m/s, the speed limit of the explicit time step."""
    return math.sqrt((kappa + 4.0 / 3.0 * mu) / density)


@dataclass(frozen=True)
class DamBreak:
    """Geometry and material constants of one dam-break; lengths in metres, density in kg/m^3."""

    width_m: float
    height_m: float
    depth_m: float
    density: float
    cell_m: float
    dim: int = 3
    ppc: int = REFERENCE_PARTICLES_PER_CELL  # particles per cell per axis
    kappa: float = KAPPA_PA
    mu: float = MU_PA
    gravity: float = GRAVITY

    @classmethod
    def build(cls, setup, *, density: float, cell_mm: float, depth_mm: float = DEFAULT_DEPTH_MM, dim: int = 3,
              ppc: int = REFERENCE_PARTICLES_PER_CELL, kappa_pa: float = KAPPA_PA, mu_pa: float = MU_PA) -> "DamBreak":
        setup = Setup.of(setup).check_in_space()
        w, h = setup.width_mm * 1e-3, setup.height_mm * 1e-3
        density = check_density(density)
        depth_mm = float(depth_mm)
        if not (math.isfinite(depth_mm) and 5.0 <= depth_mm <= 200.0):
            raise ValueError(f"depth must be within 5-200 mm, got {depth_mm!r}")
        cell_mm = check_cell_mm(cell_mm)
        if dim not in (2, 3):
            raise ValueError(f"dim must be 2 or 3, got {dim!r}")
        scene = cls(w, h, depth_mm * 1e-3, density, cell_mm * 1e-3, dim, check_ppc(ppc),
                    check_modulus(kappa_pa, "kappa_pa"), check_modulus(mu_pa, "mu_pa"))
        if scene.n_particles > MAX_PARTICLES:
            raise ValueError(f"cell width {cell_mm:g} mm needs {scene.n_particles} particles (max {MAX_PARTICLES})")
        return scene

    # --- particles ---
    @property
    def spacing_m(self) -> float:
        """Particle lattice spacing: cell / ppc (the reference: 2 particles per cell per axis)."""
        return self.cell_m / self.ppc

    @property
    def half_length_m(self) -> float:
        """uGIMP particle half-length l_p = spacing / 2 (constant)."""
        return 0.5 * self.spacing_m

    @property
    def particle_volume(self) -> float:
        """Initial particle volume (m^3 in 3D, m^2 per unit depth in 2D plane strain)."""
        return self.spacing_m ** self.dim

    @property
    def particle_mass(self) -> float:
        return self.density * self.particle_volume

    @property
    def overlap_m(self) -> float:
        """How far the particle block reaches into the walls: 1.5 mm, at least one spacing so
        that coarse lattices still put a whole particle layer inside every wall."""
        return max(OVERLAP_M, self.spacing_m)

    def block(self) -> tuple[np.ndarray, np.ndarray]:
        """Corners of the particle block: the specimen plus the overlap into floor, back and side walls."""
        o = self.overlap_m
        lo = np.array([-o, -o, -o])
        hi = np.array([self.width_m, self.height_m, self.depth_m + o])
        return lo[: self.dim], hi[: self.dim]

    def lattice_shape(self) -> tuple[int, ...]:
        lo, hi = self.block()
        return tuple(int(math.ceil((b - a) / self.spacing_m - 1e-9)) for a, b in zip(lo, hi))

    @property
    def n_particles(self) -> int:
        return int(np.prod(self.lattice_shape()))

    def particles(self) -> np.ndarray:
        """(N, dim) cell-centred lattice positions, x index fastest, no jitter."""
        lo, _ = self.block()
        axes = [lo[a] + self.spacing_m * (np.arange(m) + 0.5) for a, m in enumerate(self.lattice_shape())]
        grids = np.meshgrid(*axes[::-1], indexing="ij")  # last axis of the mesh = x: x varies fastest
        return np.stack([g.ravel() for g in grids[::-1]], axis=1)

    # --- walls ---
    def boxes(self) -> np.ndarray:
        """(4, 2, 3) static boxes [min, max] in the reference's order: floor, back, far side, near side.

        All are sticking. Side walls are at least one cell thick so that a grid node always lies inside.
        """
        w, d = self.width_m, self.depth_m
        side = max(SIDE_WALL_M, 1.01 * self.cell_m)
        back = max(BACK_WALL_M, 1.01 * self.cell_m)
        big = 10.0
        return np.array([
            [[-big, -back, -big], [big, 0.0, big]],  # B0 floor
            [[-back, 0.0, 0.0], [0.0, WALL_TOP_M, d]],  # B1 back wall
            [[-back, 0.0, -side], [w, WALL_TOP_M, 0.0]],  # B2 far side wall (z = 0)
            [[-back, 0.0, d], [w, WALL_TOP_M, d + side]],  # B3 near side wall (camera side, z = depth)
        ])

    @property
    def plane_z_m(self) -> float:
        """z of the 2D plane-strain section: mid-depth, where only floor and back wall are met."""
        return 0.5 * self.depth_m

    def frozen_and_hidden(self, positions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(frozen, hidden) masks of particles: inside any wall; hidden by the reference's skinning rule.

        The reference tests the boxes in order and lets the *last* box whose x and y ranges contain the
        particle decide: hidden when z is inside that box too. The solver applies the
        same rule every step; this numpy version gives the initial state.
        """
        p = np.asarray(positions, float)
        z = p[:, 2] if p.shape[1] == 3 else np.full(len(p), self.plane_z_m)
        frozen = np.zeros(len(p), bool)
        hidden = np.zeros(len(p), bool)
        for lo, hi in self.boxes():
            in_xy = (p[:, 0] >= lo[0]) & (p[:, 0] <= hi[0]) & (p[:, 1] >= lo[1]) & (p[:, 1] <= hi[1])
            in_z = (z >= lo[2]) & (z <= hi[2])
            frozen |= in_xy & in_z
            hidden = np.where(in_xy, in_z, hidden)
        return frozen, hidden

    def visible_positions(self, positions: np.ndarray, hidden: np.ndarray) -> np.ndarray:
        """(N, 3) positions of the visible particles; in 2D (plane strain) the section is extruded over the 3D
        particle layers in z (the near-wall layer excluded)."""
        p = np.asarray(positions, float)[~np.asarray(hidden, bool)]
        if self.dim == 3:
            return p
        s, o = self.spacing_m, self.overlap_m
        nz = int(math.ceil((self.depth_m + 2 * o) / s - 1e-9))
        zs = -o + s * (np.arange(nz) + 0.5)
        zs = zs[zs <= self.depth_m]
        out = np.empty((len(p) * len(zs), 3))
        out[:, :2] = np.repeat(p, len(zs), axis=0)
        out[:, 2] = np.tile(zs, len(p))
        return out

    # --- time stepping and reach ---
    @property
    def wave_speed(self) -> float:
        return elastic_wave_speed(self.density, self.kappa, self.mu)

    @property
    def speed_limit(self) -> float:
        """A speed no particle of a sane run reaches in 1/3 s: a few times free fall from height H."""
        return 5.0 * math.sqrt(2.0 * self.gravity * self.height_m) + 1.0

    def reach(self) -> tuple[np.ndarray, np.ndarray]:
        """Box (metres) the material cannot leave within 1/3 s unless the simulation blew up.

        A dam-break front moves at most at the inviscid (Ritter) speed 2 sqrt(g H); with a factor 1.5 of
        safety the front travels R = 3 sqrt(g H) T in T = 1/3 s, forward and sideways. Upward, no particle
        rises far above the initial height. The solver's grid follows the particles' bounding box inside
        this region, so its size costs nothing; leaving it raises SimulationError.
        """
        t_end = N_FRAMES / FPS
        r = 3.0 * math.sqrt(self.gravity * self.height_m) * t_end + 10 * self.cell_m
        lo = np.array([-BACK_WALL_M - 2 * self.cell_m, -BACK_WALL_M - 2 * self.cell_m, -r])
        hi = np.array([self.width_m + r, 2.0 * self.height_m + 10 * self.cell_m, self.depth_m + r])
        return lo[: self.dim], hi[: self.dim]
