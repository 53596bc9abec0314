"""Agreement of the native engine with the Taichi reference (taichi-cpu) on the shared experiments.

For each shared experiment at its Table-1 parameters (material, setup, depth and density of the experiment, its
camera, the working image size) the script simulates on ``taichi-cpu`` and on ``native`` in this process (one
thread each, ``VIRHEO_ARCH`` switched between the calls) and prints a markdown table: particles, the per-frame
silhouette IoU of native against taichi (its minimum over the 8 frames and the frame where it occurs), the runout
(``front_m`` at the last frame) of each engine and the largest runout difference over the frames, and whether that
stays within one cell width. Then the verdict against the acceptance: IoU >= 0.99 in every frame of every
experiment and runouts within one cell. Experiments that miss it get their per-frame numbers printed.

    python bench/bench_engine_agreement.py                  # all 14 at the default discretisation (1.5 mm, 1)
    python bench/bench_engine_agreement.py --ppc 2          # two particles per axis, on the subset below
    python bench/bench_engine_agreement.py --experiments ref_Lotion_7.0_7.0_2 --cell-mm 1.26 --ppc 2
"""
from __future__ import annotations

import argparse
import os
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from measured import how_measured, load  # noqa: E402  (bench/ is this script's folder)

ENGINES = ("taichi-cpu", "native")  # reference first
MIN_IOU = 0.99  # acceptance: in every frame of every experiment
# --ppc 2 (or more) without --experiments: the sauce's setup 1 (thin film), lotion's 70 x 70 mm (the largest),
# cabbage pancake sauce's setup 1 (high yield stress, stops early) and carbonara's setup 1 (n = 1, wide)
SUBSET = ("ref_JapaneseThickenedWorcestershireSauce_4.0_2.1_1", "ref_Lotion_7.0_7.0_2",
          "ref_JapaneseCabbagePancakeSauce_3.8_4.2_1", "ref_Carbonara_3.7_6.4_1")


def simulate_on(engine: str, *args, **kwargs):
    """``mpm.simulate`` on ``engine`` ($VIRHEO_ARCH set for the call, restored afterwards)."""
    import mpm

    old = os.environ.get("VIRHEO_ARCH")
    os.environ["VIRHEO_ARCH"] = engine
    try:
        return mpm.simulate(*args, **kwargs)
    finally:
        if old is None:
            os.environ.pop("VIRHEO_ARCH", None)
        else:
            os.environ["VIRHEO_ARCH"] = old


@dataclass
class Agreement:
    """Native (b) against taichi (a): per-frame silhouette IoU and runouts (m), and the cell width (m)."""

    ious: np.ndarray
    front_a: np.ndarray
    front_b: np.ndarray
    cell_m: float
    only_a: np.ndarray  # pixels in a's silhouette only, per frame
    only_b: np.ndarray

    @classmethod
    def of(cls, a, b) -> "Agreement":
        from mpm.loss import iou

        return cls(np.array([iou(x, y) for x, y in zip(a.silhouettes, b.silhouettes)]), np.asarray(a.front_m),
                   np.asarray(b.front_m), a.stats["cell_mm"] * 1e-3,
                   np.array([np.count_nonzero(x & ~y) for x, y in zip(a.silhouettes, b.silhouettes)]),
                   np.array([np.count_nonzero(y & ~x) for x, y in zip(a.silhouettes, b.silhouettes)]))

    @property
    def worst_frame(self) -> int:
        return int(np.argmin(self.ious)) + 1  # frame k at t = k/24 s (config_0k.png)

    @property
    def front_diff_m(self) -> float:
        return float(np.max(np.abs(self.front_b - self.front_a)))

    @property
    def runout_ok(self) -> bool:
        return self.front_diff_m <= self.cell_m

    @property
    def ok(self) -> bool:
        return bool(self.ious.min() >= MIN_IOU) and self.runout_ok


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--experiments", nargs="+", default=None,
                    help="shared experiment folders, or all (default: all; with --ppc >= 2 the subset "
                         f"{', '.join(SUBSET)})")
    ap.add_argument("--cell-mm", type=float, default=None, help="cell width in mm (default: the solver's, 1.5)")
    ap.add_argument("--ppc", type=int, default=None, help="particles per cell per axis (default: the solver's, 1)")
    a = ap.parse_args(argv)
    try:
        return run(a)
    except (ValueError, FileNotFoundError) as exc:
        print(f"bench_engine_agreement: {exc}", file=sys.stderr)
        return 2


def run(a) -> int:
    from mpm import runtime
    from mpm.datasets import manifest, real_world_dir, table1
    from mpm.experiment import load as load_experiment
    from mpm.params import WORKING_SIZE

    rows = {r["folder"]: r for r in manifest()}
    if a.experiments is None:
        folders = list(SUBSET) if a.ppc is not None and a.ppc >= 2 else list(rows)
    elif a.experiments == ["all"]:
        folders = list(rows)
    else:
        folders = [Path(f).name for f in a.experiments]
    unknown = [f for f in folders if f not in rows]
    if unknown:
        raise ValueError(f"--experiments {unknown[0]}: not a shared experiment (one of {', '.join(rows)}, or all)")
    if a.ppc is not None and a.ppc < 1:
        raise ValueError(f"--ppc {a.ppc}: give a whole number >= 1")
    if a.cell_mm is not None and not a.cell_mm > 0:
        raise ValueError(f"--cell-mm {a.cell_mm:g}: give a cell width > 0 mm")
    missing = runtime.native_missing()
    if missing is not None:
        raise ValueError(f"the native engine is not available: {missing}")
    from mpm import solver  # imports Taichi (which prints its banner): only once the input is good

    cell = solver.DEFAULT_CELL_MM if a.cell_mm is None else a.cell_mm
    ppc = solver.PARTICLES_PER_CELL if a.ppc is None else a.ppc
    print(f"# native vs taichi-cpu, each shared experiment at its Table-1 parameters, {cell:g} mm cells, {ppc} "
          f"particle(s) per cell per axis, sticking walls; silhouettes through the experiment's camera at "
          f"{WORKING_SIZE[0]}x{WORKING_SIZE[1]}")
    print(f"# measured: {how_measured()}", flush=True)
    results = {}
    for folder in folders:
        exp = load_experiment(real_world_dir() / folder, frames=False)
        kw = dict(density=exp.density, cell_mm=a.cell_mm, ppc=a.ppc, camera=exp.camera, depth_mm=exp.depth_mm,
                  image_size=WORKING_SIZE)
        sims = {}
        for engine in ENGINES:
            try:
                sims[engine] = simulate_on(engine, table1(rows[folder]), exp, **kw)
            except solver.SimulationError as exc:
                sims[engine] = f"{engine}: {exc}"
        failed = [s for s in sims.values() if isinstance(s, str)]
        if failed:
            results[folder] = "; ".join(failed)
            print(f"# {folder}: failed: {results[folder]}", flush=True)
            continue
        ta, na = sims["taichi-cpu"], sims["native"]
        results[folder] = (ta, na, Agreement.of(ta, na))
        ag = results[folder][2]
        print(f"# {folder}: {ta.stats['n_particles']} particles, taichi {ta.stats['steps']} steps "
              f"{ta.stats['sim_s']:.1f} s, native ({na.stats['isa']}) {na.stats['steps']} steps "
              f"{na.stats['sim_s']:.1f} s; min IoU {ag.ious.min():.4f}, load {load()}", flush=True)

    print(f"\n| experiment | particles | min IoU (frame) | runout taichi mm | runout native mm | "
          f"max \\|Δ front\\| mm | within a cell ({cell:g} mm) |")
    print("|---|---:|---:|---:|---:|---:|---|")
    bad = []
    for folder, res in results.items():
        if isinstance(res, str):
            print(f"| {folder} | | failed: {res} | | | | no |")
            bad.append(folder)
            continue
        ta, na, ag = res
        print(f"| {folder} | {ta.stats['n_particles']:,} | {ag.ious.min():.4f} ({ag.worst_frame}) | "
              f"{ag.front_a[-1] * 1e3:.1f} | {ag.front_b[-1] * 1e3:.1f} | {ag.front_diff_m * 1e3:.3f} | "
              f"{'yes' if ag.runout_ok else 'NO'} |")
        if not ag.ok:
            bad.append(folder)
    ious = np.concatenate([r[2].ious for r in results.values() if not isinstance(r, str)] or [np.ones(0)])
    print(f"\nAcceptance (IoU >= {MIN_IOU} in every frame of every experiment, runouts within one cell): "
          + ("MET" if not bad else f"NOT MET for {len(bad)} of {len(results)}: {', '.join(bad)}")
          + (f"; lowest IoU {ious.min():.4f}, mean {ious.mean():.4f} over {len(ious)} frames" if len(ious) else ""))
    for folder in bad:
        res = results[folder]
        if isinstance(res, str):
            continue
        ta, na, ag = res
        print(f"\n# {folder}, per frame (k at t = k/24 s): IoU, front taichi / native mm, pixels only taichi / "
              f"only native; steps taichi {ta.stats['steps']}, native {na.stats['steps']}")
        for k in range(len(ag.ious)):
            print(f"#   {k + 1}: {ag.ious[k]:.4f}  {ag.front_a[k] * 1e3:6.2f} / {ag.front_b[k] * 1e3:6.2f}  "
                  f"{ag.only_a[k]:6d} / {ag.only_b[k]:6d}")
    print(f"# done: load {load()}")
    return 0 if not bad else 1


if __name__ == "__main__":
    raise SystemExit(main())
