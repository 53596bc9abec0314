"""The ``virheo`` command line: one sub-command per module in :mod:`studies.commands`.

Every user error (bad numbers, malformed folders, missing files, unwritable paths, a damaged store
that cannot be healed) ends as one line on stderr and exit status 2.  Other exceptions are bugs
and keep their traceback.
"""
from __future__ import annotations

import argparse
import errno
import importlib
import os
import pickle
import re
import sqlite3
import sys
import warnings
import zipfile

from studies.commands.context import report_data_losses
from similarity.progress import first_line as _first_line

# modules under studies.commands, in the order of ``virheo --help``; each defines register(subparsers)
COMMANDS = ("demo", "design", "simulate", "check", "estimate", "study", "rheometer", "report", "laws", "theta", "figures")

# a value such as "-1,0.5,3" or "-1e3" after an option is the option's value, not another option
_NEGATIVE_VALUE = re.compile(r"^-\.?\d[\d.,eExX+-]*$")

# what to do about an OSError, by errno
_ADVICE = {
    errno.ENOSPC: "free some disk space and run the same command again (finished simulations are kept)",
    errno.EDQUOT: "free some disk space and run the same command again (finished simulations are kept)",
    errno.EACCES: "check the permissions or choose another path",
    errno.EPERM: "check the permissions or choose another path",
    errno.EROFS: "choose a path on a writable disk",
    errno.EEXIST: "a file is in the way: name a folder, or move the file",
    errno.ENOTDIR: "a file is in the way: name a folder, or move the file",
    errno.EISDIR: "that is a folder: name a file",
    errno.ENOENT: "check the path",
}


class UsageError(Exception):
    """A problem with the user's input, reported as one line with exit status 2."""


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # argparse prints usage + message; keep it to one line
        sys.stderr.write(f"{self.prog}: error: {message}\n")
        raise SystemExit(2)


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("virheometry")
    except PackageNotFoundError:
        return "unknown (not installed)"


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="virheo",
        description="Video-based rheometry of Herschel-Bulkley materials. "
        "SI units everywhere (eta in Pa s^n, sigma_y in Pa); setups in millimetres (WxH).",
    )
    parser.add_argument("--version", action="version", version=f"virheo {_version()}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name in COMMANDS:
        importlib.import_module(f"studies.commands.{name}").register(sub)
    return parser


def _join_negative_values(argv: list[str]) -> list[str]:
    """``--material -1,0.5,3`` -> ``--material=-1,0.5,3`` so that our own validation sees the value."""
    out: list[str] = []
    for token in argv:
        if out and _NEGATIVE_VALUE.match(token) and out[-1].startswith("--") and "=" not in out[-1]:
            out[-1] = f"{out[-1]}={token}"
        else:
            out.append(token)
    return out


def describe_os_error(exc: OSError) -> str:
    """One line naming the path, the problem and what to do."""
    what = exc.strerror or _first_line(exc)
    path = exc.filename if exc.filename is not None else None
    advice = _ADVICE.get(exc.errno or -1)
    if path is None and exc.strerror is None:  # raised by us with a full message
        return _first_line(exc)
    line = f"{path}: {what}" if path is not None else what
    return f"{line}; {advice}" if advice else line


def _quiet_start_up() -> None:
    """Taichi's banner and start-up log lines are not for a CPU user's terminal."""
    os.environ.setdefault("ENABLE_TAICHI_HEADER_PRINT", "0")
    os.environ.setdefault("TI_LOG_LEVEL", "error")


def main(argv=None) -> int:
    _quiet_start_up()
    parser = build_parser()
    args = parser.parse_args(_join_negative_values(list(sys.argv[1:] if argv is None else argv)))
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    prefix = f"virheo {args.command}"

    def show_warning(message, category, filename, lineno, file=None, line=None):
        sys.stderr.write(f"{prefix}: warning: {_first_line(message)}\n")

    try:
        with warnings.catch_warnings():
            warnings.showwarning = show_warning
            report_data_losses()
            status = args.func(args)
    except KeyboardInterrupt:
        sys.stderr.write(f"{prefix}: interrupted (finished simulations are kept in the store; "
                         f"run the same command again to resume)\n")
        return 130
    except (UsageError, ValueError) as exc:
        return _fail(prefix, _first_line(exc))
    except OSError as exc:  # FileNotFoundError, IsADirectoryError, PermissionError, a full disk, ...
        return _fail(prefix, describe_os_error(exc))
    except sqlite3.Error as exc:
        return _fail(prefix, f"the simulation store's index cannot be used ({_first_line(exc)}); "
                     f"if another run uses the same store, wait for it; else pass another --store")
    except (pickle.UnpicklingError, zipfile.BadZipFile, EOFError) as exc:
        return _fail(prefix, f"a stored file is damaged ({_first_line(exc)}); run again, or pass another --store")
    return int(status or 0)


def _fail(prefix: str, message: str) -> int:
    sys.stderr.write(f"{prefix}: error: {message}\n")
    return 2


if __name__ == "__main__":
    raise SystemExit(main())
