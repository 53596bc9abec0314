"""The ``virheo`` command line: one sub-command per module in :mod:`studies.commands`.

Every user error (bad numbers, malformed folders, missing files) ends as one line on
stderr and exit status 2; nothing below this layer prints tracebacks for them.
"""
from __future__ import annotations

import argparse
import importlib
import re
import sys

# name -> module under studies.commands; each module defines register(subparsers)
COMMANDS = ("demo", "design", "simulate", "check", "estimate", "study", "rheometer", "report")


class UsageError(Exception):
    """A problem with the user's input, reported as one line with exit status 2."""


class _Parser(argparse.ArgumentParser):
    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        # values such as "-1,0.5,3" reach our own validation instead of being taken for an option
        self._negative_number_matcher = re.compile(r"^-\.?\d[\d.,eExX+-]*$")

    def error(self, message):  # argparse prints usage + message; keep it to one line
        sys.stderr.write(f"virheo: error: {message}\n")
        raise SystemExit(2)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="virheo",
        description="Video-based rheometry of Herschel-Bulkley materials. "
        "SI units everywhere (eta in Pa s^n, sigma_y in Pa); setups in millimetres (WxH).",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name in COMMANDS:
        try:
            module = importlib.import_module(f"studies.commands.{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"studies.commands.{name}":
                raise
            continue
        module.register(sub)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        status = args.func(args)
    except KeyboardInterrupt:
        sys.stderr.write("virheo: interrupted (finished simulations are kept in the store)\n")
        return 130
    except (UsageError, ValueError, FileNotFoundError, NotADirectoryError, PermissionError) as exc:
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        sys.stderr.write(f"virheo {args.command}: error: {msg}\n")
        return 2
    return int(status or 0)


if __name__ == "__main__":
    raise SystemExit(main())
