"""``virheo laws RUN``: does the material have a yield stress, is it shear thinning: the laws' evidence of a reported
run

For a folder `virheo report` has written: the evidence of Herschel-Bulkley and of its special cases Bingham (n = 1),
power law (sigma_y = 0) and Newtonian, on the report's likelihood and emulator, their log Bayes factors with Monte
Carlo errors and the verdicts in words (Jeffreys' scale; resolved from |ln BF| = ln 10). Simulates nothing; `virheo
report` computes the same and grows its box to every law's face.
"""
from __future__ import annotations

import argparse
import json

from studies.commands.context import add_command


def register(subparsers) -> None:
    from studies.commands.context import add_laws_option

    p = add_command(subparsers, __doc__)
    p.add_argument("run", metavar="RUN", help="run folder holding posterior.json and the posterior's samples")
    add_laws_option(p)
    p.add_argument("--json", action="store_true", help="print the evidence as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from similarity.evidence import parse_laws
    from similarity.law_evidence import evidence_of_report
    from similarity.run_folder import read_result
    from studies.commands.report import print_verdicts

    laws = [law.name for law in parse_laws(args.laws)]  # an unknown law stops here
    evidence = evidence_of_report(args.run, laws)
    if args.json:
        print(json.dumps(evidence.to_dict(), indent=1))
    else:
        result, _ = read_result(args.run)
        print_verdicts(evidence, result.get("preset", "demo"))
    return 0
