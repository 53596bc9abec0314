"""Real footage at the paper's Table-1 parameters versus the material-space centre and one-at-a-time
perturbations, plus every shared experiment's loss at Table 1.

    python bench/bench_real_footage.py [--cell-mm X] [--ppc P] [--workers K] [--store PATH] [--materials NAME ...]
                                       [--columns LABEL ...]

For each material of manifest.csv: loss summed over its two setups at Table 1, at the centre of the material
space, and with eta x3, x1/3, sigma_y x2, x1/2 (+-5 Pa where sigma_y < 5 Pa). Prints markdown tables
(docs/validation.md records them). Results go to a simulation store, so a killed run resumes.
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from mpm import batch
from mpm import experiment as xp
from mpm.datasets import manifest, real_world_dir, table1
from mpm.model import ForwardModel
from mpm.params import Material
from mpm.store import Store
from similarity.space import center
from measured import how_measured  # noqa: E402  (bench/ is this script's folder)


def perturbations(m: Material) -> dict[str, Material]:
    s_up = m.sigma_y * 2 if m.sigma_y >= 5 else m.sigma_y + 5
    s_dn = m.sigma_y / 2 if m.sigma_y >= 5 else max(m.sigma_y - 5, 0.0)
    return {
        "Table 1": m, "centre": center(),
        "eta x3": Material(m.eta * 3, m.n, m.sigma_y), "eta /3": Material(m.eta / 3, m.n, m.sigma_y),
        "sigma_y up": Material(m.eta, m.n, s_up), "sigma_y down": Material(m.eta, m.n, s_dn),
    }


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cell-mm", type=float, default=None)
    p.add_argument("--ppc", type=int, default=None, help="particles per cell per axis (paper: --cell-mm 1.26 --ppc 2)")
    p.add_argument("--columns", nargs="*", default=None, choices=list(perturbations(center())),
                   help="only these columns, e.g. 'Table 1' 'sigma_y down' (default: all)")
    p.add_argument("--workers", type=int, default=0)
    p.add_argument("--store", default=os.path.expanduser("~/.cache/virheometry/bench_real_footage"))
    p.add_argument("--materials", nargs="*", default=None)
    args = p.parse_args(argv)
    rows = manifest()
    by_material: dict[str, list[dict]] = {}
    for r in rows:
        by_material.setdefault(r["material"], []).append(r)
    names = args.materials or list(by_material)
    store = Store(args.store)
    print(f"# measured: {how_measured()}", flush=True)
    print(f"# uptime: {os.popen('uptime').read().strip()}; cell_mm={args.cell_mm or 'default'}, "
          f"ppc={args.ppc or 'default'}")
    t0 = time.perf_counter()
    jobs, keys = [], []
    exps = {}
    for name in names:
        for r in by_material[name]:
            e = xp.load(Path(real_world_dir()) / r["folder"])
            exps[r["folder"]] = e
            for label, m in perturbations(table1(r)).items():
                if args.columns is not None and label not in args.columns:
                    continue
                req = batch.request_for(m, e, density=e.density, depth_mm=e.depth_mm, camera=e.camera,
                                        model=ForwardModel(args.cell_mm, args.ppc))
                jobs.append((req, batch.experiment_id(e.frames, e.name), e.frames))
                keys.append((name, r["folder"], label))
    with (batch.local_executor(args.workers) if args.workers else batch.local_executor(0)) as ex:
        losses = batch.evaluate_losses(jobs, store=store, executor=ex)
    wall = time.perf_counter() - t0
    table: dict[str, dict[str, float]] = {}
    per_exp: dict[str, float] = {}
    for (name, folder, label), loss in zip(keys, losses):
        table.setdefault(name, {}).setdefault(label, 0.0)
        table[name][label] += loss
        if label == "Table 1":
            per_exp[folder] = loss
    labels = [lab for lab in perturbations(center()) if args.columns is None or lab in args.columns]
    verdict = len(labels) > 1 and labels[0] == "Table 1"
    print("\n| material | " + " | ".join(labels) + (" | Table 1 lowest |" if verdict else " |"))
    print("|---" * (len(labels) + 1 + verdict) + "|")
    ok_all = True
    for name in names:
        vals = [table[name][lab] for lab in labels]
        ok = all(vals[0] < v for v in vals[1:])
        ok_all &= ok
        print(f"| {name} | " + " | ".join(f"{v:.4f}" for v in vals) + (f" | {'yes' if ok else 'NO'} |" if verdict else " |"))
    print("\n| experiment | loss at Table 1 |\n|---|---|")
    for folder, loss in per_exp.items():
        print(f"| {folder} | {loss:.4f} |")
    print(f"\n# {len(jobs)} evaluations in {wall:.0f} s" + (f"; Table 1 lowest for every material: {ok_all}" if verdict else ""))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
