"""ViRheometry on real footage for the four materials with rheometer curves (docs/validation.md).

    python bench/bench_real_estimates.py [--cell-mm 3] [--generations 12] [--workers 2] [--store PATH]

For each material: Algorithm 1 on its two shared setups (stage 1 from the centre on setup 1, stage 2 on
both), at a reduced fidelity (cell width and generations given); then our estimate and the paper's (Table 1)
are both scored with the default forward model (mean loss over the two setups, eq. 3), and both flow curves
against the rheometer (RMS of log10 stress over 1-100 1/s). Prints a markdown table; resumable via the store.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time
from pathlib import Path

import numpy as np

from mpm import batch
from mpm import experiment as xp
from mpm.datasets import manifest, real_world_dir, require_data_dir
from mpm.store import Store
from similarity import estimate as E
from similarity.space import Material
from surrogate.rheometer import MATERIALS, log_stress_rms, read_flow_curve


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cell-mm", type=float, default=3.0)
    p.add_argument("--generations", type=int, default=12)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--store", default=os.path.expanduser("~/.cache/virheometry/bench_real_estimates"))
    p.add_argument("--out", default="real_estimates.json")
    p.add_argument("--only", nargs="*", default=None, help="material names (manifest spelling) to run")
    args = p.parse_args(argv)
    preset = dataclasses.replace(E.get_preset("demo"), name=f"real-{args.cell_mm}mm", cell_mm=args.cell_mm,
                                 generations=args.generations)
    store = Store(args.store)
    curves = {MATERIALS[f.name.split("_")[0]]: read_flow_curve(f)
              for f in sorted((require_data_dir() / "rheometer").glob("*.csv"))}
    rows = manifest()
    results = json.loads(Path(args.out).read_text()) if Path(args.out).exists() else {}
    print(f"# uptime: {os.popen('uptime').read().strip()}; preset {preset}")
    with batch.local_executor(args.workers) as ex:
        for name, curve in curves.items():
            if name in results or (args.only and name not in args.only):
                continue
            mine = sorted((r for r in rows if r["material"].lower() == name.lower()), key=lambda r: r["setup_index"])
            exps = [xp.load(Path(real_world_dir()) / r["folder"]) for r in mine]
            r0 = mine[0]
            paper = Material(float(r0["paper_eta_Pa_s_n"]), float(r0["paper_n"]), float(r0["paper_sigma_y_Pa"]))
            t0 = time.perf_counter()
            est = E.estimate(exps, preset=preset, seed=args.seed, executor=ex, store=store)
            wall = time.perf_counter() - t0
            scores = {}
            for label, m in (("ours", est.material), ("paper", paper)):
                jobs = [(batch.request_for(m, e, density=e.density, depth_mm=e.depth_mm, camera=e.camera),
                         batch.experiment_id(e.frames, e.name), e.frames) for e in exps]
                scores[label] = float(np.mean(batch.evaluate_losses(jobs, store=store, executor=ex)))
            results[name] = {
                "setups": [f"{e.width_mm:g}x{e.height_mm:g}" for e in exps], "estimate": est.material.to_dict(),
                "paper": paper.to_dict(), "loss_ours": scores["ours"], "loss_paper": scores["paper"],
                "rms_ours": log_stress_rms(est.material, curve), "rms_paper": log_stress_rms(paper, curve),
                "simulations": est.simulations, "wall_seconds": wall,
            }
            Path(args.out).write_text(json.dumps(results, indent=2))
            print(name, json.dumps(results[name]), flush=True)
    print("\n| material | setups | our estimate (eta, n, sigma_y) | paper | loss ours | loss paper | RMS ours | RMS paper |")
    print("|---|---|---|---|---|---|---|---|")
    for name, r in results.items():
        f = lambda m: f"{m['eta']:.3g}, {m['n']:.3g}, {m['sigma_y']:.3g}"  # noqa: E731
        print(f"| {name} | {' + '.join(r['setups'])} | {f(r['estimate'])} | {f(r['paper'])} | {r['loss_ours']:.4f} | "
              f"{r['loss_paper']:.4f} | {r['rms_ours']:.3f} | {r['rms_paper']:.3f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
