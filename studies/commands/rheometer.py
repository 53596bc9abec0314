"""``virheo rheometer FILE.csv``: read a rheometer flow curve (instrument CSV export) and fit Herschel-Bulkley
parameters

Read a steady-shear flow curve exported by the rotational rheometer (UTF-16, tab separated, Japanese header rows),
print it in SI (shear rate 1/s, stress Pa, viscosity Pa s) and fit the Herschel-Bulkley curve sigma = sigma_y + eta
* rate^n by least squares in log10 stress over the reliable range (default 1..100 1/s). Optionally score a given
material (e.g. a video estimate) on the same range.
"""
from __future__ import annotations

import json

import numpy as np

from studies.commands.context import add_command, real


def register(subparsers) -> None:
    p = add_command(subparsers, __doc__)
    p.add_argument("file", metavar="FILE.csv", help="instrument CSV export")
    p.add_argument("--lo", type=real, default=1.0, help="lowest shear rate of the fit, 1/s (default 1)")
    p.add_argument("--hi", type=real, default=100.0, help="highest shear rate of the fit, 1/s (default 100)")
    p.add_argument("--material", default=None, metavar="ETA,N,SIGMA_Y",
                   help="also report the RMS log10-stress error of this material (SI: Pa s^n, -, Pa) on the fit range")
    p.add_argument("--json", action="store_true", help="print the curve and fit as JSON")
    p.set_defaults(func=run)


def run(args) -> int:
    from mpm.params import Material
    from mpm.laws import LAWS
    from surrogate.rheometer import fit_herschel_bulkley, log_stress_rms, read_flow_curve

    if not (0 < args.lo < args.hi):
        raise ValueError(f"--lo {args.lo:g} and --hi {args.hi:g} must satisfy 0 < lo < hi (1/s)")
    other = Material.parse(args.material) if args.material else None
    curve = read_flow_curve(args.file)
    fit = fit_herschel_bulkley(curve, args.lo, args.hi)
    laws = [fit] + [fit_herschel_bulkley(curve, args.lo, args.hi, law) for law in LAWS if law != fit.law]
    m = fit.material
    model = m.stress(curve.shear_rate)
    other_rms = log_stress_rms(other, curve, args.lo, args.hi) if other else None
    if args.json:
        print(json.dumps({
            "name": curve.name,
            "material_name": curve.material_name,
            "file": curve.path,
            "shear_rate_per_s": curve.shear_rate.tolist(),
            "shear_stress_pa": curve.shear_stress.tolist(),
            "viscosity_pa_s": curve.viscosity.tolist(),
            "temperature_c": np.round(curve.temperature_c, 3).tolist(),
            "fit": {"range_per_s": [fit.lo, fit.hi], "n_points": fit.n_points, **m.to_dict(), "rms_log10_stress": fit.rms_log10},
            "laws": [{"law": f.law, "parameters": f.parameters, **f.material.to_dict(), "rms_log10_stress": f.rms_log10,
                      "aic": f.aic, "bic": f.bic} for f in laws],
            "material": None if other is None else {**other.to_dict(), "rms_log10_stress": other_rms},
        }, indent=1))
        return 0
    inside = curve.window(args.lo, args.hi)
    print(f"{curve.name} ({curve.material_name}): {len(curve)} points, "
          f"{np.nanmean(curve.temperature_c):.1f} °C")
    print(f"{'point':>5s} {'rate [1/s]':>11s} {'stress [Pa]':>12s} {'viscosity [Pa s]':>17s} {'HB fit [Pa]':>12s}")
    for k in range(len(curve)):
        mark = "*" if inside[k] else " "
        print(f"{curve.point[k]:5d} {curve.shear_rate[k]:11.4g} {curve.shear_stress[k]:12.5g} "
              f"{curve.viscosity[k]:17.5g} {model[k]:12.5g} {mark}")
    print(f"Herschel-Bulkley fit over {fit.lo:g}-{fit.hi:g} 1/s (* rows, {fit.n_points} points): "
          f"eta={m.eta:.4g} Pa s^n, n={m.n:.4g}, sigma_y={m.sigma_y:.4g} Pa; RMS log10 stress error {fit.rms_log10:.4f}")
    best_aic, best_bic = min(f.aic for f in laws), min(f.bic for f in laws)
    print("eq. 1 and its special cases over the same points (AIC, BIC: lower is better; difference to the best):")
    for f in laws:
        print(f"  {f.law:17s} eta={f.material.eta:<10.4g} n={f.material.n:<7.4g} sigma_y={f.material.sigma_y:<8.4g} "
              f"RMS {f.rms_log10:.4f}  AIC {f.aic:8.1f} ({f.aic - best_aic:+6.1f})  BIC {f.bic:8.1f} "
              f"({f.bic - best_bic:+6.1f})")
    if other is not None:
        print(f"given material eta={other.eta:g} Pa s^n, n={other.n:g}, sigma_y={other.sigma_y:g} Pa: "
              f"RMS log10 stress error {other_rms:.4f} over {fit.lo:g}-{fit.hi:g} 1/s")
    return 0
