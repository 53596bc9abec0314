"""Does the information criterion's prediction hold on the shared footage?  Predicted against realised gain of the
second setup the experimenters filmed (docs/uncertainty.md, "On the shared footage: predicted and realised gain").

    python bench/bench_design_real.py [--model 5:1] [--workers 2] [--store DIR]

For each shared material with an estimate after setup 1 (``first_estimates.csv``: 6 of the 7; Cobb salad dressing
has none):

* **predicted**: what `virheo design` computes after setup 1: the log det gain of the filmed second setup after
  setup 1, from FD loss Hessians at the setup-1 estimate on footage emulated there (default camera, 1000 kg/m^3),
  :func:`similarity.information.predicted_gains`, with MODEL (default the criterion's own, 5 mm / 1);
* **realised**: the same log det gain from the FD Hessians of the loss on the *real* footage of both setups at
  Table 1's estimate, the loss at the estimate as the stencil's centre (both estimates moved inward by the step, as
  the criterion does).

Prints the table, Spearman's rank correlation between predicted and realised gains, and how it was measured.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from measured import how_measured  # noqa: E402  (bench/ is this script's folder)


def realised_gain(material, experiments, model, forward, step: float) -> tuple[float, list]:
    """log det gain of experiments[1] after experiments[0] from their FD Hessians on the footage at ``material``."""
    from similarity import information as I
    from similarity.emulation import probe_losses
    from similarity.fd_hessian import stencil

    centre = forward.pair_losses([(material, e) for e in experiments], model)
    probes = probe_losses([(material, e) for e in experiments], stencil(step), model, forward)
    h = [I.setup_hessian(row, step, c) for row, c in zip(probes, centre)]
    return float(I.log_det_gain(h[0], h[1][None])[0]), [float(np.trace(x)) for x in h]


def main(argv=None) -> int:
    from mpm.datasets import first_estimates, material_rows, real_world_dir, table1
    from mpm.experiment import load
    from mpm.forward import Forward
    from mpm.params import Material, Setup
    from similarity import information as I
    from similarity.presets import filming
    from studies.design_resolution import model_label, parse_model

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", default="5:1", help="CELL_MM:PPC of the FD Hessians (default 5:1, the criterion's)")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--store", default=str(Path("~/.cache/virheometry/design_real").expanduser()))
    args = p.parse_args(argv)
    model = parse_model(args.model)
    preset = filming("demo", model, f"design-real-{model_label(model)}")
    rows = []
    with Forward(args.store, workers=args.workers) as forward:
        for first in first_estimates():
            name = first["material"]
            manifest = material_rows(name)
            setups = [Setup(float(r["width_cm"]) * 10, float(r["height_cm"]) * 10) for r in manifest]
            stage1 = Material(float(first["estimate_after_setup1_eta_Pa_s_n"]), float(first["estimate_after_setup1_n"]),
                              float(first["estimate_after_setup1_sigma_y_Pa"]))
            predicted = float(I.predicted_gains(stage1, setups[:1], setups[1:], preset=preset, forward=forward)[0])
            experiments = [load(real_world_dir() / r["folder"]) for r in manifest]
            truth = I.interior(table1(manifest[0]))
            realised, traces = realised_gain(truth, experiments, model, forward, I.STEP)
            rows.append((name, setups, predicted, realised, traces))
            print(f"{name}: {setups[0]} then {setups[1]}: predicted {predicted:.3f}, realised {realised:.3f}", flush=True)
    print()
    print(f"| material | setup 1 | setup 2 | predicted gain | realised gain | tr H setup 2 / tr H setup 1 (real) |")
    print("|---|---|---|---:|---:|---:|")
    for name, setups, pr, re, tr in rows:
        print(f"| {name} | {setups[0]} | {setups[1]} | {pr:.3f} | {re:.3f} | {tr[1] / tr[0]:.2f} |")
    rho = I.rank_agreement([r[2] for r in rows], [r[3] for r in rows])
    print(f"\nSpearman (predicted, realised) over {len(rows)} materials: {rho:.2f}; model {model_label(model)}")
    print(f"measured: {how_measured()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
