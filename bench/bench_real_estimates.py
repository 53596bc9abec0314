"""ViRheometry on real footage for the four materials with rheometer curves (docs/validation.md).

    python bench/bench_real_estimates.py [--root DIR] [--preset footage] [--slip-mm B | --finish-slip-mm B]
                                         [--density-correction] [--generations G] [--finish-generations G]
                                         [--finish-cell-mm C --finish-ppc P] [--search-cell-mm C --search-ppc P]
                                         [--only lotion milk] [--workers 2] [--score ETA,N,SIGMA_Y ...]

For each material, ``virheo estimate SETUP1 SETUP2 --out ROOT/<slug>`` (slugs: worcestershire, milk,
okonomiyaki, lotion) runs unless ROOT/<slug>/result.json already holds a run finished with the same preset,
seed, walls, solver and finishing budget (then it is only scored; a killed run resumes from its store). Each run is
then scored: our estimate and the paper's (Table 1) under the same forward model as the run's reported loss
(mean eq.-3 loss over the two setups), and both flow curves against the rheometer (RMS of log10 stress over
1-100 1/s; 0.1 is a factor 1.26). Also printed: the stage-1 (one-setup) estimate's RMS, the wall time, the CPU
time of the estimate and its worker processes, and the load average. ``--score`` scores more materials the same
way as the paper's (e.g. the rheometer's own fit). The run's valley: how many of the materials simulated under the
final model (the finishing stage's) lie within 1 % of the best loss, and the range of their n and RMS. Prints a
markdown table and writes ROOT/real_estimates.json.
The default preset, ``footage``, finishes at the paper's discretisation (1.26 mm, two particles per axis);
``--preset footage-1p`` runs the one-particle preset. ``--finish-cell-mm``/``--finish-ppc`` change the finishing
stage's cells, ``--search-cell-mm``/``--search-ppc`` the search stages'.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import time
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402
from measured import how_measured, real_materials  # noqa: E402  (bench/ is this script's folder)

VALLEY = 0.01  # the materials within this fraction of the best loss under the final model are printed as its valley
SLUGS = {"Japanese thickened Worcestershire sauce": "worcestershire", "moisturizing milk": "milk",
         "Japanese cabbage pancake sauce": "okonomiyaki", "lotion": "lotion"}


def _cpu_seconds() -> float:
    """CPU seconds of this process and its finished children (the estimate's worker processes)."""
    me, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def _material(d: dict):
    from mpm.params import Material

    return Material(float(d["eta"]), float(d["n"]), float(d["sigma_y"]))


def _on_cells(record: dict, model) -> bool:
    """Whether ``record`` (a run's result.json or one of its stages, in any layout) names ``model``'s cells,
    particles and density correction (where it does not say the cells or particles: assumed so; no correction)."""
    from mpm.forward import ForwardModel

    said = ForwardModel.of_record(record)
    return ((said.cell_mm is None or np.isclose(said.cell_mm, model.cell_mm))
            and said.ppc in (None, model.ppc) and said.density_correction == model.density_correction)


def _finish_generations(result: dict):
    """Generations of a finished run's finishing stage (0 without one; None if the run does not say)."""
    stages = result.get("stages")
    if not stages:
        return None
    return stages[-1].get("generations") if stages[-1].get("finish") else 0


def parse_materials(parser: argparse.ArgumentParser, specs) -> list:
    """``--score`` materials given as ETA,N,SIGMA_Y (SI); a malformed or unphysical one ends with a usage error."""
    from mpm.params import Material

    fields = [m.split(",") for m in specs]
    if any(len(f) != 3 for f in fields):
        parser.error("--score takes materials as ETA,N,SIGMA_Y (three numbers in SI units)")
    try:
        return [Material(*map(float, f)) for f in fields]
    except ValueError as e:
        parser.error(f"--score: {e}")


def rheometer_curves() -> dict:
    """Material name -> its rheometer flow curve (``surrogate.rheometer.FlowCurve``) from the shared data."""
    from mpm.datasets import require_data_dir
    from surrogate.rheometer import MATERIALS, read_flow_curve

    return {MATERIALS[f.name.split("_")[0]]: read_flow_curve(f)
            for f in sorted((require_data_dir() / "rheometer").glob("*.csv"))}


def score(out: Path, paper, curve, workers: int, others=()) -> dict:
    """Loss of our estimate and the paper's (and of the materials ``others``) under the run's final forward model,
    and their flow-curve RMS."""
    from mpm.forward import Forward
    from mpm.params import Material
    from similarity.posterior import archive, load_run, mean_losses
    from similarity.space import denormalize
    from surrogate.rheometer import log_stress_rms

    with Forward(out / "store", workers=workers) as forward:
        run = load_run(out, forward=forward)
        result = run.result
        model = run.preset.final

        def loss(m):
            return float(np.mean(run.forward.losses([m], run.experiments, model)))

        losses = {"loss_ours": loss(run.estimate), "loss_paper": loss(paper)}
        others_losses = [loss(m) for m in others]
        X = archive(run, np.full(3, 0.5), 0.5)  # every material the store holds in all setups under the final model
        X_losses = mean_losses(run, X)
    near = X_losses <= (1.0 + VALLEY) * np.nanmin(X_losses)
    valley = [{"material": m.to_dict(), "loss": float(v), "rms": log_stress_rms(m, curve)}
              for m, v in zip((Material.from_array(denormalize(x)) for x in X[near]), X_losses[near])]
    stage1 = _material(result["stages"][0]["material"]) if result.get("stages") else None
    return {
        "setups": [f"{e.width_mm:g}x{e.height_mm:g}" for e in run.experiments],
        "estimate": run.estimate.to_dict(), "paper": paper.to_dict(),
        "discretisation": model.resolved().to_dict(), **losses,
        "rms_ours": log_stress_rms(run.estimate, curve), "rms_paper": log_stress_rms(paper, curve),
        "rms_stage1": None if stage1 is None else log_stress_rms(stage1, curve),
        "stage1": None if stage1 is None else stage1.to_dict(),
        "simulations": result.get("simulations_run"), "from_store": result.get("results_from_store"),
        "wall_seconds": result.get("wall_seconds"),
        "others": [{"material": m.to_dict(), "loss": v, "rms": log_stress_rms(m, curve)}
                   for m, v in zip(others, others_losses)],
        "archive_size": int(len(X)), "valley": valley,
    }


def main(argv=None) -> int:
    from mpm import experiment as xp
    from mpm.datasets import table1
    from studies.cli import main as virheo

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--root", default=os.path.expanduser("~/.cache/virheometry/real_estimates"),
                   help="one `virheo estimate` output folder per material is made (or reused) here")
    p.add_argument("--preset", default="footage")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--slip-mm", type=float, default=None, help="passed to virheo estimate: walls slipping by this many mm")
    p.add_argument("--density-correction", action="store_true",
                   help="passed to virheo estimate: the solver's density correction in every stage")
    p.add_argument("--finish-slip-mm", type=float, default=None,
                   help="the preset's finishing stage with walls slipping by this many mm (its search as it is)")
    p.add_argument("--generations", type=int, default=None, help="the preset's generations per search stage")
    p.add_argument("--finish-generations", type=int, default=None,
                   help="the preset's finishing stage with this many CMA-ES generations (its search as it is)")
    p.add_argument("--finish-cell-mm", type=float, default=None, help="the preset's finishing stage on these cells")
    p.add_argument("--finish-ppc", type=int, default=None,
                   help="the preset's finishing stage with this many particles per cell per axis")
    p.add_argument("--search-cell-mm", type=float, default=None, help="the preset's search stages on these cells")
    p.add_argument("--search-ppc", type=int, default=None,
                   help="the preset's search stages with this many particles per cell per axis")
    p.add_argument("--only", nargs="*", default=None, help=f"slugs to run: {', '.join(SLUGS.values())}")
    p.add_argument("--score", nargs="*", default=(), metavar="ETA,N,SIGMA_Y",
                   help="more materials to score like the paper's, under each run's final model (SI units)")
    args = p.parse_args(argv)
    unknown = set(args.only or ()) - set(SLUGS.values())
    if unknown:
        p.error(f"unknown material {', '.join(sorted(unknown))}: choose from {', '.join(SLUGS.values())}")
    if args.slip_mm is not None and args.finish_slip_mm is not None:
        p.error("--slip-mm (every stage) and --finish-slip-mm (the finishing stage) exclude each other")
    others = parse_materials(p, args.score)
    from similarity import presets
    from similarity.run_folder import model_of

    try:
        preset = presets.get_preset(args.preset)
    except ValueError as e:
        p.error(str(e))
    finish = {"slip_length_m": None if args.finish_slip_mm is None else args.finish_slip_mm * 1e-3,
              "cell_mm": args.finish_cell_mm, "ppc": args.finish_ppc}
    if (any(v is not None for v in finish.values()) or args.finish_generations is not None) \
            and not preset.finish_generations:
        p.error(f"--finish-* options need a preset with a finishing stage, not {preset.name}")
    for opt, cells, ppc in (("finish", args.finish_cell_mm, args.finish_ppc),
                            ("search", args.search_cell_mm, args.search_ppc)):
        if cells is not None and not cells > 0:
            p.error(f"--{opt}-cell-mm {cells}: give a cell width > 0 in mm")
        if ppc is not None and ppc < 1:
            p.error(f"--{opt}-ppc {ppc}: give a whole number >= 1")
    preset = replace(preset, finish=replace(preset.finish, **{k: v for k, v in finish.items() if v is not None}))
    search = {"cell_mm": args.search_cell_mm, "ppc": args.search_ppc}
    preset = replace(preset, **{k: v for k, v in search.items() if v is not None})
    if args.generations is not None:
        if args.generations < 1:
            p.error("--generations needs a positive count")
        preset = replace(preset, generations=args.generations)
    if args.finish_generations is not None:
        if args.finish_generations < 1:
            p.error("--finish-generations needs a positive count")
        preset = replace(preset, finish_generations=args.finish_generations)
    presets.PRESETS[preset.name] = preset  # the registered preset, as `virheo estimate` in this process reads it
    if args.slip_mm is not None:
        preset = replace(preset, slip_length_m=args.slip_mm * 1e-3)
    preset = replace(preset, density_correction=args.density_correction)
    final = preset.final.resolved()  # a finished run is reused only if it was estimated with this model
    slip = final.slip_length_m
    root = Path(args.root)
    curves = rheometer_curves()
    summary_path = root / "real_estimates.json"
    results = json.loads(summary_path.read_text()) if summary_path.exists() else {}
    for name, slug, mine, folders in real_materials(SLUGS, args.only):
        out = root / slug
        done = False
        if (out / "result.json").exists():
            result = json.loads((out / "result.json").read_text())
            first = (result.get("stages") or [{}])[0]
            done = (result.get("preset") == args.preset and result.get("seed", 0) == args.seed
                    and np.isclose(model_of(result).slip_length_m or 0.0, slip, rtol=1e-9, atol=0)
                    and _on_cells(result, final)
                    and _on_cells(first, preset.search.resolved())
                    and _finish_generations(result) in (None, preset.finish_generations)
                    and first.get("generations") in (None, preset.generations)
                    and first.get("search_space", "linear") == preset.search_space
                    and ("shape" in result["stages"][-1]) == preset.carry_covariance)
        if not done:
            load, t0, c0 = os.getloadavg()[0], time.perf_counter(), _cpu_seconds()
            code = virheo(["estimate", *folders, "--out", str(out), "--preset", args.preset, "--seed", str(args.seed),
                           "--workers", str(args.workers), "--quiet",
                           *(["--slip-mm", str(args.slip_mm)] if args.slip_mm is not None else []),
                           *(["--density-correction"] if args.density_correction else [])])
            if code:
                return code
            results.setdefault(slug, {})["measured"] = {
                "wall_s": time.perf_counter() - t0, "cpu_s": _cpu_seconds() - c0,
                "load_start": load, "load_end": os.getloadavg()[0]}
        paper = table1(mine[0])
        _ = [xp.load(f) for f in folders]  # fail early on unreadable footage
        results.setdefault(slug, {}).update(material=name, **score(out, paper, curves[name], args.workers, others))
        root.mkdir(parents=True, exist_ok=True)
        summary_path.write_text(json.dumps(results, indent=2))
    print(f"# measured: {how_measured()}", flush=True)
    f = lambda m: f"{m['eta']:.3g}, {m['n']:.3g}, {m['sigma_y']:.3g}"  # noqa: E731
    print("| material | setups | our estimate (eta, n, sigma_y) | paper (Table 1) | loss ours | loss paper | "
          "RMS one setup | RMS ours | RMS paper | simulations | wall |")
    print("|---|---|---|---|---:|---:|---:|---:|---:|---:|---:|")
    for slug, r in results.items():
        if "estimate" not in r:
            continue
        wall = r.get("measured", {}).get("wall_s") or r.get("wall_seconds") or float("nan")
        print(f"| {r['material']} | {' + '.join(r['setups'])} | {f(r['estimate'])} | {f(r['paper'])} | "
              f"{r['loss_ours']:.5f} | {r['loss_paper']:.5f} | {r['rms_stage1']:.3f} | {r['rms_ours']:.3f} | "
              f"{r['rms_paper']:.3f} | {r['simulations']} | {wall / 60:.0f} min |")
    for slug, r in results.items():
        for o in r.get("others", ()):
            print(f"{r['material']}: {f(o['material'])} scores loss {o['loss']:.5f}, RMS {o['rms']:.3f}")
    for slug, r in results.items():
        if r.get("valley"):
            n = [v["material"]["n"] for v in r["valley"]]
            rms = [v["rms"] for v in r["valley"]]
            print(f"{r['material']}: within {100 * VALLEY:g} % of the best loss under the final model, {len(n)} of its "
                  f"{r['archive_size']} simulated materials: n {min(n):.2f}-{max(n):.2f}, RMS {min(rms):.3f}-{max(rms):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
