"""The run context shared by the long commands (``demo``, ``estimate``, ``study``): output folder,
simulation store, executor (local processes or a dask scheduler), progress bars and the counts a
run reports.

``$VIRHEO_SIMULATOR`` (``module:function``) replaces the MPM forward model; the test-suite uses it
to run the commands with a cheap stand-in.  It is not a user setting.
"""
from __future__ import annotations

import argparse
import importlib
import os
import time
from collections.abc import Sequence
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass, field
from pathlib import Path

SIMULATOR_ENV = "VIRHEO_SIMULATOR"


class Names(Sequence):
    """Option ``choices`` read from their home module (``"module:NAME"``) when first needed, so that
    building the parser does not import the estimator or Taichi."""

    def __init__(self, where: str):
        self.where, self._names = where, None

    def _get(self) -> tuple:
        if self._names is None:
            module, _, name = self.where.partition(":")
            self._names = tuple(getattr(importlib.import_module(module), name))
        return self._names

    def __getitem__(self, i):
        return self._get()[i]

    def __len__(self) -> int:
        return len(self._get())

    def __contains__(self, value) -> bool:
        return value in self._get()

    def __iter__(self):
        return iter(self._get())


def real(text: str) -> float:
    """argparse ``type`` for a finite real number, with the project's message."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a number") from None
    if value != value or value in (float("inf"), float("-inf")):
        raise argparse.ArgumentTypeError(f"'{text}' is not a finite number")
    return value


def integer(text: str) -> int:
    """argparse ``type`` for a whole number, with the project's message."""
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}' is not a whole number") from None


def seed(text: str) -> int:
    """argparse ``type`` for a random seed: a whole number in 0..2**32-1 (what numpy, CMA-ES and emcee take)."""
    value = integer(text)
    if not 0 <= value < 2**32:
        raise argparse.ArgumentTypeError(f"{value} is not in 0..2**32-1")
    return value


PRESET_NAMES = Names("similarity.estimate:PRESETS")


def add_command(subparsers, doc: str) -> argparse.ArgumentParser:
    """The parser of the command a module's docstring ``doc`` describes: its first paragraph is
    "``virheo [GROUP] NAME ...``: help", the paragraphs below are the description ``--help`` prints."""
    import re

    first, _, rest = doc.strip().partition("\n\n")
    match = re.match(r"``virheo (?:study |theta )?([a-z][a-z-]*)[^`]*``:\s*(.*)", " ".join(first.split()), re.S)
    if match is None:
        raise ValueError(f"a command's docstring must start with ``virheo NAME``: ...; got {first[:60]!r}")
    name, help = match.groups()
    description = "\n\n".join(" ".join(par.split()) for par in rest.split("\n\n") if par.strip()) or help
    return subparsers.add_parser(name, help=help.replace("%", "%%"), description=description.replace("%", "%%"))


def add_command_group(subparsers, name: str, *, help: str, description: str, dest: str, metavar: str):
    """Register command ``name`` whose actions are sub-commands (returned as their subparsers action);
    given without an action it prints its help and exits 2."""
    p = subparsers.add_parser(name, help=help, description=description)
    p.set_defaults(func=lambda args: (p.print_help(), 2)[1])
    return p.add_subparsers(dest=dest, metavar=metavar)


def add_preset_option(p: argparse.ArgumentParser, default: str) -> None:
    p.add_argument("--preset", default=default, choices=PRESET_NAMES, metavar="NAME",
                   help="accuracy/time trade-off, one of: %(choices)s (default %(default)s; "
                   "costs in the user guide)")


def add_run_options(p: argparse.ArgumentParser, *, default_out: str | None, generations: bool = True) -> None:
    """``--out --store --workers --scheduler [--generations] --quiet`` with their help texts."""
    if default_out is None:
        p.add_argument("--out", required=True, metavar="OUT",
                       help="output folder (result.json, flow_curve.png, overlays/)")
    else:
        p.add_argument("--out", default=default_out, metavar="OUT",
                       help=f"output folder (default {default_out})")
    p.add_argument("--store", default=None, metavar="PATH",
                   help="simulation store folder, shared between runs (default OUT/store)")
    p.add_argument("--workers", type=integer, default=None, metavar="K",
                   help="local worker processes (default: one per CPU core; 0: in this process)")
    p.add_argument("--scheduler", default=None, metavar="ADDR",
                   help="dask.distributed scheduler address, e.g. tcp://host:8786 (instead of --workers)")
    if generations:
        p.add_argument("--generations", type=integer, default=None, metavar="N",
                       help="CMA-ES generations per stage (default: the preset's)")
    p.add_argument("--quiet", action="store_true", help="no progress bars (a damaged store is still reported)")


def add_posterior_options(p: argparse.ArgumentParser) -> None:
    """The options of the posterior of ``similarity.posterior.analyse`` (``virheo report``, ``study calibration``)."""
    from similarity.likelihood import METHODS
    from similarity.posterior import NOISE_COUNT

    p.add_argument("--new-simulations", type=integer, default=24, metavar="N",
                   help="space-filling candidates simulated for the emulator, each in every setup (default 24)")
    p.add_argument("--half-width", type=real, default=0.1, metavar="W",
                   help="half-width of the emulator's box around the estimate, normalised space (default 0.1)")
    p.add_argument("--min-ess", type=real, default=1000.0, metavar="N", help="effective samples to reach (default 1000)")
    p.add_argument("--max-steps", type=integer, default=20000, metavar="N", help="most emcee steps (default 20000)")
    p.add_argument("--noise-count", choices=METHODS, default=NOISE_COUNT,
                   help=f"independent residuals counted per frame: one (frames) or one per residual blob "
                        f"(components) or per correlation area (default {NOISE_COUNT})")


def add_laws_option(p: argparse.ArgumentParser) -> None:
    """``--laws LIST``: the laws whose evidence is computed (``virheo report``, ``virheo laws``)."""
    from similarity.law_evidence import LAW_NAMES

    p.add_argument("--laws", default=",".join(LAW_NAMES), metavar="LIST",
                   help=f"laws whose evidence is computed, comma separated (default all: {', '.join(LAW_NAMES)}; "
                        "herschel-bulkley always)")


def check_posterior_options(args) -> None:
    """ValueError (one line) for posterior options out of range."""
    if args.new_simulations < 0 or args.min_ess <= 0 or args.max_steps < 1 or not 0 < args.half_width <= 0.5:
        raise ValueError("--new-simulations >= 0, --min-ess > 0, --max-steps >= 1 and 0 < --half-width <= 0.5 required")


def check_run_options(args) -> None:
    """The project's own messages for out-of-range numbers and paths of the wrong kind."""
    if getattr(args, "generations", None) is not None and args.generations < 1:
        raise ValueError(f"--generations {args.generations} must be >= 1")
    if getattr(args, "cases", 1) < 1:
        raise ValueError(f"--cases {args.cases} must be >= 1")
    if args.workers is not None and args.workers < 0:
        raise ValueError(f"--workers {args.workers} must be >= 0 (0: simulate in this process)")
    if args.workers is not None and args.scheduler:
        raise ValueError("--workers and --scheduler exclude each other: the scheduler's workers do the work")
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} is a file, not a folder: name a folder")
    store = Path(args.store) if args.store else out / "store"
    if store.exists() and not store.is_dir():
        raise ValueError(f"--store {store} is a file, not a folder: name a folder")


def check_engine() -> str:
    """The engine ``$VIRHEO_ARCH`` chooses (``mpm.runtime.engine_name``): a command that simulates asks first, so
    that an unknown or unavailable engine is one line and exit 2 before any file is written."""
    from mpm import runtime

    return runtime.engine_name()


def simulator() -> str | None:
    """The simulating function ``$VIRHEO_SIMULATOR`` names, or None: the MPM solver."""
    return os.environ.get(SIMULATOR_ENV) or None


@dataclass
class Run:
    """What a long command works with, and what it counts for its report."""

    out: Path
    forward: object  # mpm.forward.Forward: the store and the executor
    progress: object  # callback for the estimator's progress events, or None
    engine: str = ""  # the engine that simulates (mpm.runtime.engine_name): the figures depend on its speed
    simulated: int = 0  # simulations run by this command
    from_store: int = 0  # results served from the store (simulations or cached losses)
    started: float = field(default_factory=time.perf_counter)

    def event(self, ev) -> None:
        from similarity.progress import Simulation

        if isinstance(ev, Simulation):
            if ev.cached:
                self.from_store += 1
            else:
                self.simulated += 1

    @property
    def wall_seconds(self) -> float:
        return time.perf_counter() - self.started

    def counts(self) -> dict:
        """For result.json: the same numbers the progress bar and the printed summary show."""
        return {"simulations_run": self.simulated, "results_from_store": self.from_store,
                "wall_seconds": self.wall_seconds, "engine": self.engine}

    def cost_line(self, total_simulations: int) -> str:
        """'84 simulations (60 run now, 24 from the store) in 95 s', or that all came from the store."""
        if self.simulated == 0:
            return f"{total_simulations} simulations, all served from the store (none run now)"
        rest = max(total_simulations - self.simulated, 0)
        return (f"{total_simulations} simulations ({self.simulated} run now"
                + (f", {rest} from the store" if rest else "") + f") in {self.wall_seconds:.0f} s")

    def report_hint(self) -> str:
        """The line that points from an estimate to what only ``virheo report`` computes."""
        return (f"uncertainty (posterior, credible intervals, yield stress and shear thinning decided by the laws' "
                f"evidence, next setup by information gain, HTML page): virheo report {self.out}")


@contextmanager
def open_run(args):
    """A :class:`Run` for ``args`` (see :func:`add_run_options`); the executor is shut down afterwards."""
    from mpm.forward import Forward
    from studies.report import progress_bars

    engine = check_engine()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with ExitStack() as stack:
        forward = stack.enter_context(Forward(Path(args.store) if args.store else out / "store", workers=args.workers,
                                              scheduler=args.scheduler, simulator=simulator()))
        bars = stack.enter_context(progress_bars(not args.quiet))
        run = Run(out, forward, None, engine)

        def progress(ev: dict) -> None:
            run.event(ev)
            if bars:
                bars(ev)

        run.progress = progress
        yield run


def report_data_losses() -> None:
    """Show every ``StoreWarning`` (a damaged index, simulation file or checkpoint set aside), whatever
    ``-W``, ``PYTHONWARNINGS`` or an earlier warning said: ``--quiet`` silences progress, never a loss of data.
    Call it inside the command's ``warnings.catch_warnings()``."""
    import warnings

    from mpm.store import StoreWarning

    warnings.simplefilter("always", StoreWarning)
