"""The skeleton of a per-case study (calibration, design, emulation): cases run one by one through the forward
model, each kept in ``OUT/cases/.../case.json``, then a summary, a markdown table and figures.

:meth:`Study.run` walks the study's cases in order.  A case whose folder holds a ``case.json`` made with the
same configuration is read back, not recomputed; one made with another configuration stops the study (one
line: use another ``--out``).  The others run through ``forward`` (:class:`mpm.forward.Forward`), whose store
also serves what a case killed midway had simulated.  A case whose run raises a ``ValueError``, ``RuntimeError``
or ``ArithmeticError`` (every simulation of a stage failed, the footage's own simulation failed: what a resume
would meet again) is kept as ``failed.json`` beside where its case.json would be, with its error, and the study
goes on; a resume does not run it again (delete the file to retry).  A broken worker pool is not such a failure: it
stops the study.  :meth:`Study.write` then reads every finished case under ``OUT`` and writes ``OUT/NAME.json``
(configuration, summary, wall time, cases, failed cases), ``OUT/NAME.md`` (the table, and the failed cases under
it) and the figures.

How to add a study
------------------
1. A record: a dataclass with :class:`mpm.files.JsonRecord` (``to_dict`` / ``from_dict``) holding one
   finished case, its ``config`` among its fields.  Its JSON is ``case.json``; once files exist, ``from_dict``
   must keep reading them (add fields with defaults, never rename).
2. A summary: a dataclass with ``to_dict`` (``JsonRecord`` again) computed from the records.
3. A subclass of :class:`Study` naming ``name`` (the stem of the output files), ``record`` (the record class)
   and ``case_files`` (globs under OUT, in the order the cases are listed), with these methods:
   ``cases()`` (the planned cases in order, each with a ``folder``), ``run_case(case, forward=, progress=)``
   (a record), ``summary(records)``, ``table(records, summary)`` (markdown) and ``plots(records, summary)``;
   optionally ``announce(case)`` / ``report(record)`` (progress lines), ``after_cases`` (parts that need every
   case, e.g. the maps of :mod:`studies.design_information`) and ``result`` (the JSON layout).
4. A ``run_study(out, ..., forward, progress)`` in its module checks the options, builds the configuration (what
   a case's result depends on: preset, seeds, budgets, the simulator) and returns
   ``TheStudy(out, config).run(forward=forward, progress=progress)``; its command in ``studies/commands/``
   calls that.  ``TheStudy(out).records()`` reads the finished cases back (benches, figures).

:mod:`studies.design_study` is the shortest complete example.
"""
from __future__ import annotations

import time
from concurrent.futures import BrokenExecutor
from pathlib import Path
from typing import Iterable

from mpm.files import read_json, write_json
from similarity.progress import Message


def finished_cases(out, *patterns: str) -> list[dict]:
    """The ``case.json`` records of a resumable per-case study under ``out`` (glob ``patterns``, in order).

    ValueError when there are none, or when they were made with different configurations.
    """
    found = [read_json(p) for pattern in patterns for p in sorted(Path(out).glob(pattern))]
    if not found:
        raise ValueError(f"{out}: no finished cases")
    if len({str(r["config"]) for r in found}) > 1:
        raise ValueError(f"{out} holds cases made with different settings; use one --out per configuration")
    return found


def finished_case(folder, config: dict) -> dict | None:
    """The record ``folder/case.json`` of a finished case made with ``config``; None when there is none.

    ValueError when it was made with another configuration.
    """
    done = Path(folder) / "case.json"
    if not done.is_file():
        return None
    rec = read_json(done)
    if rec.get("config") != config:
        raise ValueError(f"{done} was made with other settings ({rec.get('config')}); use another --out")
    return rec


def failed_cases(out, *patterns: str) -> list[dict]:
    """The ``failed.json`` records ({"folder", "error", "config"}) beside the ``case.json`` globs ``patterns``."""
    found = []
    for pattern in patterns:
        for p in sorted(Path(out).glob(str(Path(pattern).with_name("failed.json")))):
            found.append(read_json(p) | {"folder": str(p.parent.relative_to(out))})
    return found


def tell(progress, text: str | None) -> None:
    """Hand ``text`` to the ``progress`` callback as a message line (nothing without a callback or a text)."""
    if progress and text:
        progress(Message(text))


class Study:
    """A resumable per-case study: subclasses supply what differs (module docstring)."""

    name: str = ""  # OUT/<name>.json and OUT/<name>.md
    record: type = None  # the record class (JsonRecord dataclass with a ``config`` field)
    case_files: tuple[str, ...] = ("cases/case_*/case.json",)  # globs under OUT, in listing order

    def __init__(self, out, config: dict | None = None):
        self.out, self.config = Path(out), config

    # -- what a study supplies ---------------------------------------------------------------------------------
    def cases(self) -> Iterable:
        """The planned cases in order; each has a ``folder`` (where its case.json goes)."""
        raise NotImplementedError

    def run_case(self, case, *, forward, progress=None):
        """Run one case (its folder exists) and return its record."""
        raise NotImplementedError

    def summary(self, records: list):
        raise NotImplementedError

    def table(self, records: list, summary) -> str:
        raise NotImplementedError

    def plots(self, records: list, summary) -> None:
        raise NotImplementedError

    def after_cases(self, records: list, *, forward, progress=None) -> None:
        """Further parts that need the finished cases (each kept in its own file), run before the outputs."""

    def announce(self, case) -> str | None:
        """Progress line before a case runs (or is read back)."""
        return None

    def report(self, record) -> str | None:
        """Progress line after a case."""
        return None

    def result(self, records: list, summary, wall_seconds: float | None) -> dict:
        """The content of OUT/<name>.json."""
        return {"config": records[0].config, "summary": summary.to_dict(), "wall_seconds": wall_seconds,
                "cases": [r.to_dict() for r in records], "failed": self.failed()}

    # -- the skeleton -----------------------------------------------------------------------------------------
    def records(self) -> list:
        """Every finished case under OUT, in listing order (ValueError when none, or made with different
        configurations)."""
        return [self.record.from_dict(d) for d in finished_cases(self.out, *self.case_files)]

    def failed(self) -> list[dict]:
        """The failed cases under OUT (:func:`failed_cases`), made with this study's configuration."""
        return [f for f in failed_cases(self.out, *self.case_files)
                if self.config is None or f.get("config") == self.config]

    def case(self, case, *, forward, progress=None):
        """The record of one case: read back from its folder when finished with this configuration, else run
        and kept there; None for a failed case (module docstring), kept as its folder's failed.json."""
        folder = Path(case.folder)
        done = finished_case(folder, self.config)
        if done is not None:
            return self.record.from_dict(done)
        failed = folder / "failed.json"
        if failed.is_file() and read_json(failed).get("config") == self.config:
            return None
        folder.mkdir(parents=True, exist_ok=True)
        try:
            rec = self.run_case(case, forward=forward, progress=progress)
        except BrokenExecutor:
            raise
        except (ValueError, RuntimeError, ArithmeticError) as exc:
            write_json(failed, {"config": self.config, "error": str(exc).splitlines()[0] if str(exc) else
                                type(exc).__name__})
            return None
        write_json(folder / "case.json", rec)
        return rec

    def run(self, *, forward, progress=None) -> dict:
        """Run (or resume) every case in order, then :meth:`write`; returns what OUT/<name>.json holds."""
        t0 = time.perf_counter()
        recs = []
        for case in self.cases():
            tell(progress, self.announce(case))
            rec = self.case(case, forward=forward, progress=progress)
            if rec is None:
                tell(progress, f"  failed, left out: {read_json(Path(case.folder) / 'failed.json')['error']}")
                continue
            recs.append(rec)
            tell(progress, self.report(rec))
        self.after_cases(recs, forward=forward, progress=progress)
        return self.write(wall_seconds=time.perf_counter() - t0)

    def write(self, *, wall_seconds: float | None = None) -> dict:
        """OUT/<name>.json, OUT/<name>.md and the figures from every finished case under OUT."""
        recs = self.records()
        summ = self.summary(recs)
        self.plots(recs, summ)
        result = self.result(recs, summ, wall_seconds)
        write_json(self.out / f"{self.name}.json", result)
        table = self.table(recs, summ)
        failed = self.failed()
        if failed:
            table += ("\nFailed cases, left out of the summary (their failed.json; delete it to retry):\n\n"
                      + "".join(f"- {f['folder']}: {f['error']}\n" for f in failed))
        (self.out / f"{self.name}.md").write_text(table)
        return result
