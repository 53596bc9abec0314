"""Were a calibration case's special laws integrated on an emulator that knew their faces?  (docs/uncertainty.md)

    python bench/bench_law_faces.py OUT/cases/case_06 [more case folders] --store OUT/store [--search]

For each case folder of `virheo study laws` (its posterior.json, posterior_training.npz and case.json):

1. the emulator the report fitted (refitted from its training set) against the simulations the laws' check made on
   each special law's face (store simulations on the face that are not training losses): the mean and the draws of
   tau (L_simulated - L_emulated) in nats, per face (negative: the emulator pessimistic there, the law's evidence
   understated);
2. the mean video loss at the estimating model of the truth, the CMA-ES estimate and each law's best fit on the
   emulator (simulated here, nothing stored);
3. with ``--search``, the face search of similarity/face_search.py on each special law's face, simulated here: its
   best fit per law and loss, to set beside 2.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import numpy as np  # noqa: E402

from measured import how_measured  # noqa: E402


def _material(m) -> str:
    return f"eta {m.eta:.3g} Pa s^n, n {m.n:.3g}, sigma_y {m.sigma_y:.3g} Pa"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("cases", nargs="+", help="case folders of `virheo study laws`")
    ap.add_argument("--store", required=True, help="the study's simulation store (OUT/store)")
    ap.add_argument("--search", action="store_true", help="also run the face search on each special law's face")
    args = ap.parse_args(argv)

    from mpm.forward import Forward
    from mpm.params import Material
    from similarity.evidence import LAWS
    from similarity.face_search import face_search
    from similarity.posterior import archive, mean_losses, not_among
    from similarity.run_folder import load_run
    from similarity.space import denormalize, normalize
    from surrogate.emulator import LossEmulator

    print(f"# measured: {how_measured()}")
    stored, fresh = Forward(args.store, workers=0), Forward(None, workers=0)
    special = [law for law in LAWS.values() if law.fixed]
    for folder in map(Path, args.cases):
        case = json.loads((folder / "case.json").read_text())
        post = json.loads((folder / "posterior.json").read_text())
        run = load_run(folder, forward=stored)
        with np.load(folder / "posterior_training.npz") as t:
            X, y = t["X"], t["y"]
            emu = LossEmulator(seed=int(t["seed"])).fit(X, y, theta=t["theta"])
        nz = post["noise"]
        tau = nz["n_eff"] / (2.0 * (nz["loss_at_optimum"] + nz["discretisation"]))  # eq. (1) without e_emul
        print(f"\n## case {case['case']} ({case['law']}): truth {_material(Material(**case['truth']))}, setups "
              f"{' + '.join(case['setups'])}")
        new = archive(run, np.full(3, 0.5), 0.5)
        new = new[not_among(new, X, 1e-9)]
        for law in special:
            on = np.all([np.abs(new[:, i] - v) < 1e-9 for i, v in law.fixed], axis=0)
            others = [o for o in special if o is not law and len(o.fixed) > len(law.fixed)]
            for o in others:  # a draw on a narrower law's edge belongs to that law's check
                on &= ~np.all([np.abs(new[:, i] - v) < 1e-9 for i, v in o.fixed], axis=0)
            if not on.any():
                print(f"{law.name:10s} face: no checked draws")
                continue
            d = tau * (mean_losses(run, new[on]) - emu.predict(new[on]))
            print(f"{law.name:10s} face: emulator offset {d.mean():+.1f} nats (draws {np.round(d, 1).tolist()})")
        fresh_run = load_run(folder, forward=fresh)
        points = {"truth": Material(**case["truth"]), "estimate": Material(**case["estimate"])}
        points |= {f"{e['law']} best (emulator)": Material(**e["best"]) for e in post["evidence"]["laws"]}
        losses = fresh_run.forward.losses(list(points.values()), fresh_run.experiments, fresh_run.preset.final)
        for (name, m), row in zip(points.items(), losses):
            print(f"{name:32s} {_material(m)}: mean loss {np.mean(row):.5f} at the estimating model")
        if args.search:
            x_hat = normalize(fresh_run.estimate.as_array())
            for law in special:
                Xs, ys = face_search(lambda Z: mean_losses(fresh_run, Z), law, x_hat, seed=int(case["config"]["seed"])
                                     + int(case["case"]))
                i = int(np.nanargmin(ys))
                best = _material(Material.from_array(denormalize(Xs[i])))
                print(f"{law.name + ' best (face search)':32s} {best}: mean loss {ys[i]:.5f} ({len(ys)} simulated)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
