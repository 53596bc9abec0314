"""How far the laws' verdicts can be trusted at a run's model: the shipped rounds of `virheo study laws`.

Each round (``studies/data/law_calibration*/laws.json``) scored the verdicts of `virheo report` on footage of a finer
model than the estimating one, at one preset's model.  :func:`calibration_line` quotes the round that estimated at
the run's preset, for the report's terminal summary and page, and says so where none did.
"""
from __future__ import annotations

from collections import Counter
from pathlib import Path

from mpm.files import read_json
from similarity.evidence import RESOLVED

DATA = Path(__file__).resolve().parent / "data"
NAMES = {"herschel-bulkley": "Herschel-Bulkley", "bingham": "Bingham", "power-law": "power law",
         "newtonian": "Newtonian"}  # the laws in words


def rounds(data=DATA) -> list[dict]:
    """The finished, full (not quick) calibration rounds shipped in ``data``, as their laws.json hold them."""
    out = []
    for path in sorted(Path(data).glob("law_calibration*/laws.json")):
        d = read_json(path)
        if isinstance(d, dict) and not d.get("config", {}).get("quick", True) and d.get("cases"):
            out.append(d)
    return out


def _question(q: dict) -> str:
    n, res = q["cases"], q["resolved"]
    right = f", right in {q['right']}" if res else ""
    return f"{q['question']} resolved in {res} of {n}{right}"


def calibration_line(preset: str | None, data=DATA) -> str:
    """One line: how the verdicts fared at ``preset``'s estimating model on finer-model footage, or that no shipped
    round calibrates it."""
    mine = [d for d in rounds(data) if d["config"].get("preset") == preset]
    if not mine:
        return (f"laws' calibration: none at the {preset} preset's model (no finished round of virheo study laws "
                f"estimated there); read a lean below |ln BF| {RESOLVED:.1f} as no evidence")
    d = mine[-1]
    s, cases = d["summary"], d["cases"]
    best = Counter(max(c["evidence"]["probabilities"], key=c["evidence"]["probabilities"].get) for c in cases)
    law, count = best.most_common(1)[0]
    wrong = sum(q["decisively_wrong"] for q in s["questions"])
    return (f"laws' calibration at the {preset} preset's model (virheo study laws, {len(cases)} materials, footage of "
            f"a finer model): " + "; ".join(_question(q) for q in s["questions"])
            + f"; {'none' if wrong == 0 else wrong} decisively wrong; most probable law: {NAMES[law]} in {count} of "
            f"{len(cases)}, the true one in {s['most_probable_right']}")
