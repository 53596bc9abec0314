"""Emulated video loss along the straight line (in the normalised material space) from a ground truth to
another material: is the valley between them one basin, or two separated by a barrier?

    python bench/bench_loss_line.py [--truth ETA,N,SIGMA_Y] [--other ETA,N,SIGMA_Y] [--setups WxH ...]
                                    [--cell-mm C] [--ppc P] [--t T ...]

Defaults: the demo's material (3, 0.5, 15) and its coarse-model twin (6.79, 0.325, 10.44) on 40x50 and 57x25 mm
at 7 mm cells. Prints a markdown table: t = 0 is the truth, t = 1 the other material.
"""
from __future__ import annotations

import argparse

import numpy as np

from mpm.forward import Forward
from mpm.params import Material, Setup
from similarity.estimate import Preset, emulate
from similarity.space import denormalize, e_rel, normalize


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--truth", default="3,0.5,15")
    p.add_argument("--other", default="6.79,0.325,10.44")
    p.add_argument("--setups", nargs="*", default=["40x50", "57x25"])
    p.add_argument("--cell-mm", type=float, default=7.0)
    p.add_argument("--ppc", type=int, default=None)
    p.add_argument("--t", type=float, nargs="*", default=list(np.round(np.linspace(-0.2, 1.2, 15), 2)),
                   help="positions on the line (0: truth, 1: other)")
    args = p.parse_args(argv)
    preset = Preset("line", generations=1, cell_mm=args.cell_mm, ppc=args.ppc)
    truth, other = Material.parse(args.truth), Material.parse(args.other)
    setups = [Setup.parse(s) for s in args.setups]
    forward = Forward()  # no store, in this process
    footage = emulate(truth, setups, preset=preset, forward=forward)
    a, b = normalize(truth.as_array()), normalize(other.as_array())
    print(f"# truth {args.truth}, other {args.other}, cell {args.cell_mm:g} mm, ppc {args.ppc or 'default'}")
    print("\n| t | E_rel | " + " | ".join(f"loss {s}" for s in args.setups) + " | mean |")
    print("|---:|---:|" + "---:|" * (len(setups) + 1))
    for t in args.t:
        m = Material.from_array(denormalize(a + t * (b - a)))
        losses = forward.losses([m], footage, preset.search)[0]
        print(f"| {t:.2f} | {e_rel(truth, m):.3f} | " + " | ".join(f"{v:.1e}" for v in losses)
              + f" | {losses.mean():.1e} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
