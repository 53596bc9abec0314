"""How does the matched wall stress C = P L of shallow boxes (H = 20 mm) change with the box's width, and with the
cell width of the forward model?

For each material, setups W x 20 mm (``--widths``) are emulated at each cell width; the MPM loss landscape (eq. 3) on the
3^3 block of half-width 0.05 around the material is matched to the plane-Poiseuille loss normals (eq. 43), as in
`virheo study landscapes`, and the best C is printed per width. The published Theta map's C along this edge has a
shallow minimum at W = 25-32 mm, which sets the second setups of `first_estimates.csv`; this script shows what our
simulator's landscapes say there.

    python bench/bench_theta_width_trend.py [--cells 5,2.5] [--ppc 1] [--widths 20,45,70] [--only pancake]
        [--store PATH] [--workers 2]
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from mpm.forward import Forward  # noqa: E402
from mpm.params import DEFAULT_DENSITY_KG_M3, Material, Setup  # noqa: E402
from similarity.emulation import emulate, probe_losses  # noqa: E402
from similarity.presets import Preset  # noqa: E402
from studies.landscapes import grid_offsets, match  # noqa: E402
from surrogate.theta import load as load_theta  # noqa: E402
from measured import how_measured  # noqa: E402  (bench/ is this script's folder)

# materials inside the region landscapes can sample: two Table-1-like sauces' first estimates and a mid-space one
MATERIALS = {"pancake sauce (first estimate)": (3.45, 0.738, 6.26),
             "carbonara (first estimate)": (9.82, 0.705, 12.9),
             "mid-space": (10.0, 0.6, 10.0)}
HEIGHT_MM, GRID, HALF_WIDTH = 20.0, 3, 0.05


def numbers(text: str) -> list[float]:
    return [float(v) for v in text.split(",") if v]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cells", type=numbers, default=[5.0, 2.5], help="cell widths in mm (default 5,2.5)")
    ap.add_argument("--widths", type=numbers, default=[20.0, 45.0, 70.0], help="box widths in mm (default 20,45,70)")
    ap.add_argument("--ppc", type=int, default=1, help="particles per cell per axis (default 1; the paper's: 2)")
    ap.add_argument("--only", default="", help="only the materials whose name contains this text")
    ap.add_argument("--store", default="bench-theta-width-store", help="simulation store folder")
    ap.add_argument("--workers", type=int, default=2)
    a = ap.parse_args(argv)
    forward = Forward(a.store, workers=a.workers)
    block = grid_offsets(GRID, HALF_WIDTH)
    reference = load_theta("reference")
    setups = [Setup(w, HEIGHT_MM) for w in a.widths]
    print(f"# measured: {how_measured()}", flush=True)
    print(f"matched C [Pa] at H = {HEIGHT_MM:g} mm, W = {' / '.join(f'{w:g}' for w in a.widths)} mm")
    try:
        for name, mat in MATERIALS.items():
            if a.only not in name:
                continue
            m = Material(*mat)
            ref_c = reference.wall_stress(*mat, np.array(a.widths), np.full(len(a.widths), HEIGHT_MM))
            print(f"{name} {mat}: published map {' / '.join(f'{c:5.1f}' for c in ref_c)}")
            for cell in a.cells:
                t0 = time.perf_counter()
                preset = Preset("bench", generations=1, cell_mm=cell, ppc=a.ppc)
                shots = emulate(m, setups, density=DEFAULT_DENSITY_KG_M3, preset=preset, forward=forward)
                losses = probe_losses([(m, shot) for shot in shots], block, preset.search, forward)
                cs = [match(m, row, GRID, HALF_WIDTH)["C_Pa"] for row in losses]
                print(f"  MPM, {cell:g} mm cells, {a.ppc} per axis: {' / '.join(f'{c:5.1f}' for c in cs)}"
                      f"   ({time.perf_counter() - t0:.0f} s)", flush=True)
    finally:
        forward.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
