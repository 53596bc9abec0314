"""Theta fitted to loss-landscape studies (section 5.5) and two maps compared on setup design (section 6).

:func:`fit_theta` re-matches every landscape of one or more finished studies (:mod:`studies.landscapes`)
to its best plane-Poiseuille wall stress, holds whole materials out, fits the reciprocal polynomial of
:mod:`surrogate.theta_fit` and reports, per landscape, the angle between the MPM finite-difference loss
normal and the normals predicted through the fitted and the published maps. :func:`compare_designs`
compares the second setups two maps choose (``virheo theta fit``).
"""
from __future__ import annotations

import json

import numpy as np

from mpm.params import SETUP_RANGE_MM, Material, Setup
from similarity.fd_hessian import angle_deg
from similarity.space import denormalize
from studies.landscapes import match
from studies.sampling import random_setups
from surrogate import theta_fit


# -- fitting Theta to a study (section 5.5) -----------------------------------------------------------
def map_angles(records, theta) -> np.ndarray:
    """Angle (deg) between each record's FD loss normal and the normal predicted through ``theta``
    (Algorithm 2); NaN where the map gives no Poiseuille flow or the FD Hessian is missing."""
    from similarity.normals import loss_normals

    out = np.full(len(records), np.nan)
    for k, r in enumerate(records):
        if r.get("q_max") is None:
            continue
        m = Material(**r["material"])
        q, valid = loss_normals(m, np.array([r["setup"]["width_mm"]]), np.array([r["setup"]["height_mm"]]), theta)
        if bool(valid[0]):
            out[k] = float(angle_deg(r["q_max"], q[0]))
    return out


def split(records, test_fraction: float, seed: int) -> tuple[list[int], list[int]]:
    """Train / test indices, whole materials at a time (a test landscape's material is never fitted)."""
    if not 0 <= test_fraction < 1:
        raise ValueError(f"test fraction {test_fraction} must lie in [0, 1)")
    keys = sorted({json.dumps(r["material"], sort_keys=True) for r in records})
    rng = np.random.default_rng(seed)
    n_test = int(round(test_fraction * len(keys)))
    test_keys = set(rng.permutation(keys)[:n_test].tolist())
    test = [i for i, r in enumerate(records) if json.dumps(r["material"], sort_keys=True) in test_keys]
    train = [i for i in range(len(records)) if i not in set(test)]
    return train, test


def matched_records(studies) -> list[dict]:
    """The matched landscapes of one or more finished studies (``load`` results), which must share
    the landscape block and the FD step so that their matches and normals are comparable."""
    studies = [studies] if isinstance(studies, dict) else list(studies)
    if not studies:
        raise ValueError("no landscape study given")
    keys = ("grid", "half_width", "fd_step")
    first = {k: studies[0]["config"][k] for k in keys}
    for st in studies[1:]:
        other = {k: st["config"][k] for k in keys}
        if other != first:
            raise ValueError(f"landscape studies differ in grid, half-width or FD step ({first} vs {other}); "
                             "fit them separately")
    return [r for st in studies for r in st["pairs"] if r.get("match") is not None]


def input_domain() -> tuple[np.ndarray, np.ndarray]:
    """Bounds of the Theta inputs [eta, n, sigma_y, H, W] (SI, metres): the material space times the setup range."""
    from similarity.space import LOWER, UPPER

    lo, hi = (v * 1e-3 for v in SETUP_RANGE_MM)
    return np.concatenate([LOWER, [lo, lo]]), np.concatenate([UPPER, [hi, hi]])


def fit_theta(studies, *, test_fraction: float = 0.3, seed: int = 0, name: str = "fitted", prior=None):
    """Fit Theta to the matched landscapes of one or more studies; returns (ThetaMap, report dict).

    ``prior`` (a map or what :func:`surrogate.theta.load` accepts): fit the correction to that map, which
    the regularisation shrinks towards zero, instead of a map of our own.

    The report gives the cross-validated error of the fit and, per landscape, the angle between the
    FD loss normal and the normals predicted through the fitted and the published maps, on the
    landscapes used in the fit and on the held-out ones.
    """
    from surrogate.theta import load as load_theta

    studies = [studies] if isinstance(studies, dict) else list(studies)
    records = matched_records(studies)
    if len(records) < 3:
        raise ValueError(f"the studies hold {len(records)} matched landscapes; the fit needs at least 3")
    cfg = studies[0]["config"]
    matches = [match(Material(**r["material"]), r["losses"], cfg["grid"], cfg["half_width"]) for r in records]
    train, test = split(records, test_fraction, seed)
    rows = [records[i] for i in train]
    materials = [json.dumps(r["material"], sort_keys=True) for r in rows]
    if len(set(materials)) < 3:
        raise ValueError(f"only {len(set(materials))} materials left to fit after holding out {test_fraction:g}; "
                         "lower --test-fraction")
    x = theta_fit.inputs([[r["material"][k] for k in ("eta", "n", "sigma_y")] for r in rows],
                         [r["setup"]["width_mm"] for r in rows], [r["setup"]["height_mm"] for r in rows])
    c = np.array([matches[i]["C_Pa"] for i in train])
    prior = None if prior is None else load_theta(prior)
    pipe, summary = theta_fit.fit(x, c, np.unique(materials, return_inverse=True)[1], domain=input_domain(),
                                  prior=prior)
    cfgs = [st["config"] for st in studies]
    seeds = ", ".join(str(k["seed"]) for k in cfgs)
    presets = "/".join(sorted({k["preset"] for k in cfgs}))
    attribution = (f"fitted by virheometry to {len(rows)} MPM landscapes of {summary['materials']} materials "
                   f"(preset {presets}, grid {cfg['grid']}, "
                   f"half-width {cfg['half_width']}, FD step {cfg['fd_step']}, study seeds {seeds})")
    if prior is not None:
        attribution += f" as a correction to the map '{prior.name}' ({prior.attribution})"
    ours = theta_fit.to_theta_map(pipe, name=name, attribution=attribution, prior=prior)
    ref = load_theta("reference")
    report = {"fit": summary, "train": train, "test": test, "landscapes": []}
    a_ours, a_ref = map_angles(records, ours), map_angles(records, ref)
    a_match = [float("nan") if r.get("q_max") is None else float(angle_deg(r["q_max"], mt["q_pp"]))
               for r, mt in zip(records, matches)]
    for k, r in enumerate(records):
        report["landscapes"].append({"material": r["material"], "setup": r["setup"], "used_in_fit": k in set(train),
                                     "C_matched_Pa": matches[k]["C_Pa"], "angle_matched_deg": a_match[k],
                                     "angle_fitted_deg": a_ours[k], "angle_reference_deg": a_ref[k]})
    for label, idx in (("train", train), ("test", test)):
        if idx:
            report[f"median_angle_{label}"] = {
                "landscapes": len(idx),
                "materials": len({json.dumps(records[i]["material"], sort_keys=True) for i in idx}),
                "matched": float(np.nanmedian(np.asarray(a_match)[idx])),
                "fitted": float(np.nanmedian(a_ours[idx])) if np.any(np.isfinite(a_ours[idx])) else None,
                "reference": float(np.nanmedian(a_ref[idx])) if np.any(np.isfinite(a_ref[idx])) else None,
                "invalid_fitted": int(np.sum(~np.isfinite(a_ours[idx]))),
                "invalid_reference": int(np.sum(~np.isfinite(a_ref[idx]))),
            }
    return ours, report


# -- comparing two maps on setup design (section 6) ---------------------------------------------------
def compare_designs(ours, reference, *, count: int = 50, seed: int = 0) -> dict:
    """Second setups chosen through two Theta maps: for the published first-estimate records (when the
    shared data is present) and for ``count`` random materials with random first setups."""
    from similarity.design import next_setup

    def choose(theta, m, s1):
        try:
            return next_setup(m, [s1], theta=theta)
        except ValueError:  # the map gives no Poiseuille flow for the first setup or any candidate
            return None

    records = []
    try:
        from mpm.datasets import first_estimates

        rows = first_estimates()
    except (FileNotFoundError, OSError):
        rows = []
    for row in rows:
        m = Material(float(row["estimate_after_setup1_eta_Pa_s_n"]), float(row["estimate_after_setup1_n"]),
                     float(row["estimate_after_setup1_sigma_y_Pa"]))
        s1 = Setup(round(float(row["setup1_width_cm"]) * 10), round(float(row["setup1_height_cm"]) * 10))
        chosen = Setup(round(float(row["chosen_setup2_width_cm"]) * 10), round(float(row["chosen_setup2_height_cm"]) * 10))
        a, b = choose(ours, m, s1), choose(reference, m, s1)
        records.append({"material": row["material"], "setup1": str(s1), "experimenters": str(chosen),
                        "ours": None if a is None else str(a), "reference": None if b is None else str(b)})
    rng = np.random.default_rng(seed)
    agree = near = both = 0
    for _ in range(count):
        m = Material.from_array(denormalize(rng.uniform(0.05, 0.95, 3)))
        s1 = random_setups(1, rng, replace=False)[0]
        a, b = choose(ours, m, s1), choose(reference, m, s1)
        if a is None or b is None:
            continue
        both += 1
        agree += a == b
        near += np.hypot(a.width_mm - b.width_mm, a.height_mm - b.height_mm) <= 5.0
    return {"records": records,
            "records_reproduced_ours": sum(r["ours"] == r["experimenters"] for r in records),
            "records_reproduced_reference": sum(r["reference"] == r["experimenters"] for r in records),
            "random": {"materials": count, "both_valid": both, "same_setup": int(agree), "within_5mm": int(near)}}
