"""Cost and accuracy of the estimation presets: emulated two-setup ViRheometry runs (the `virheo demo` job).

    python bench/bench_estimate.py [--preset demo] [--cell 5] [--generations 14] [--sigma0 0.2] [--seeds 0 1 2 3] \
        [--material 3,0.5,15] [--setup 40x50] [--workers 2]

The defaults are `virheo demo`'s job (its material, first setup and preset; one worker per core).  Prints, per
run: wall time, simulations, time per simulation, E_rel after each stage, the discretisation of the final loss,
setups and the engine that simulated (``stats["arch"]`` of the stored simulations), then a table of seed, E_rel
and wall time.  Every run uses a fresh store (no cache), so the times are the real cost (wall-clock figures
belong here, not in the tests); they depend on the engine's speed.  Record `uptime` with them.
"""
from __future__ import annotations

import argparse
import dataclasses
import os
import tempfile
import time

from mpm.forward import Forward
from mpm.params import Material, Setup
from mpm.store import Store
from similarity import estimate as E
from similarity.space import e_rel
from studies.commands.demo import DEFAULT_FIRST_SETUP, DEFAULT_TRUTH
from measured import how_measured  # noqa: E402  (bench/ is this script's folder)


def engines_of(store: Store) -> str:
    """The engines that ran the store's simulations, as ``stats["arch"]`` names them (with the native engine's
    instruction set)."""
    names = set()
    for req in {r.model.engine: r for r in store.requests()}.values():  # one stored simulation per engine
        res = store.get(req)
        stats = res.stats if res is not None else {}
        names.add(stats.get("arch", req.model.engine or "?") + (f" ({stats['isa']})" if stats.get("isa") else ""))
    return ", ".join(sorted(names))


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cell", type=float, default=None, help="search model's cell width in mm (default: the preset's)")
    p.add_argument("--generations", type=int, default=None, help="generations per stage (default: the preset's)")
    p.add_argument("--sigma0", type=float, default=None, help="stage-1 step size in [0, 1]^3 (default: the preset's)")
    p.add_argument("--seeds", type=int, nargs="+", default=[0])
    p.add_argument("--material", default=DEFAULT_TRUTH, help=f"ground truth ETA,N,SIGMA_Y (default {DEFAULT_TRUTH})")
    p.add_argument("--setup", default=DEFAULT_FIRST_SETUP, help=f"first setup WxH (default {DEFAULT_FIRST_SETUP})")
    p.add_argument("--workers", type=int, default=None, help="local worker processes (default: one per CPU core)")
    p.add_argument("--preset", default="demo", choices=tuple(E.PRESETS))
    p.add_argument("--store", default=None, help="reuse this store (default: a fresh temporary one)")
    p.add_argument("--second", default=None, help="fixed second setup WxH instead of similarity.design")
    args = p.parse_args(argv)
    preset = E.get_preset(args.preset)
    changes = {k: v for k, v in (("cell_mm", args.cell), ("generations", args.generations), ("sigma0", args.sigma0))
               if v is not None}
    preset = dataclasses.replace(preset, **changes)
    truth, first = Material.parse(args.material), Setup.parse(args.setup)
    print(f"# measured: {how_measured()}", flush=True)
    print(f"# uptime: {os.popen('uptime').read().strip()}")
    print(f"# preset {preset}")
    rows = []
    for seed in args.seeds:
        with tempfile.TemporaryDirectory() as d:
            store = Store(args.store or d)
            t0 = time.perf_counter()
            with Forward(store, workers=args.workers) as forward:
                kw = {"propose": (lambda m, done: Setup.parse(args.second))} if args.second else {}
                est, filmed = E.emulate_virheometry(truth, first, preset=preset, seed=seed, forward=forward, **kw)
            wall = time.perf_counter() - t0
            sims = store.count()
            errs = [e_rel(truth, s.material) for s in est.stages]
            engine = engines_of(store)
            print(f"seed {seed}: wall {wall:.0f} s, {sims} simulations ({wall / max(sims, 1):.2f} s each), "
                  f"E_rel per stage {[round(v, 4) for v in errs]}, loss per stage {[round(s.loss, 5) for s in est.stages]}, "
                  f"final loss at {est.model.cell_mm:g} mm / {est.model.ppc} ppc, setups {est.setups}, estimate {est.material}, "
                  f"engine {engine}", flush=True)
            rows.append((seed, errs[-1], wall, sims, engine))
    print("\n| seed | E_rel | wall s | simulations | engine |\n|---:|---:|---:|---:|---|")
    for seed, err, wall, sims, engine in rows:
        print(f"| {seed} | {err:.3f} | {wall:.0f} | {sims} | {engine} |")
    print(f"E_rel <= 0.1 for {sum(err <= 0.1 for _, err, *_ in rows)} of {len(rows)} seeds")


if __name__ == "__main__":
    main()
