"""Cost and accuracy of the estimation presets: emulated two-setup ViRheometry runs (the `virheo demo` job).

    python bench/bench_estimate.py [--preset demo] [--cell 5] [--generations 14] [--sigma0 0.2] [--seeds 0 1] \
        [--material 2,0.6,10] [--setup 40x50] [--workers 2]

Prints, per run: wall time, simulations, time per simulation, E_rel after each stage, the discretisation of
the final loss, setups.  Every run uses a fresh store (no cache), so the times are the real cost (wall-clock
figures belong here, not in the tests).  Record `uptime` with them.
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import tempfile
import time

from mpm import batch
from mpm.store import Store
from similarity import estimate as E
from similarity.space import Material, Setup, e_rel


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cell", type=float, default=None, help="search model's cell width in mm (default: the preset's)")
    p.add_argument("--generations", type=int, default=None, help="generations per stage (default: the preset's)")
    p.add_argument("--sigma0", type=float, default=None, help="stage-1 step size in [0, 1]^3 (default: the preset's)")
    p.add_argument("--seeds", type=int, nargs="+", default=[0])
    p.add_argument("--material", default="2.0,0.6,10.0")
    p.add_argument("--setup", default="40x50")
    p.add_argument("--workers", type=int, default=None)
    p.add_argument("--preset", default="demo", choices=tuple(E.PRESETS))
    p.add_argument("--store", default=None, help="reuse this store (default: a fresh temporary one)")
    p.add_argument("--second", default=None, help="fixed second setup WxH instead of similarity.design")
    args = p.parse_args(argv)
    preset = E.get_preset(args.preset)
    changes = {k: v for k, v in (("cell_mm", args.cell), ("generations", args.generations), ("sigma0", args.sigma0))
               if v is not None}
    preset = dataclasses.replace(preset, **changes)
    truth, first = Material.parse(args.material), Setup.parse(args.setup)
    print(f"# uptime: {os.popen('uptime').read().strip()}")
    print(f"# preset {preset}")
    for seed in args.seeds:
        with tempfile.TemporaryDirectory() as d:
            store = Store(args.store or d)
            t0 = time.perf_counter()
            with batch.local_executor(args.workers) as ex:
                kw = {"propose": (lambda m, done: Setup.parse(args.second))} if args.second else {}
                est, filmed = E.emulate_virheometry(truth, first, preset=preset, seed=seed, store=store, executor=ex, **kw)
            wall = time.perf_counter() - t0
            sims = store.count()
            errs = [e_rel(truth, s.material) for s in est.stages]
            print(f"seed {seed}: wall {wall:.0f} s, {sims} simulations ({wall / max(sims, 1):.2f} s each), "
                  f"E_rel per stage {[round(v, 4) for v in errs]}, loss per stage {[round(s.loss, 5) for s in est.stages]}, "
                  f"final loss at {est.cell_mm:g} mm / {est.ppc} ppc, setups {est.setups}, estimate {est.material}", flush=True)


if __name__ == "__main__":
    main()
