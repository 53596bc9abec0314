"""The per-case study skeleton (studies/study.py): a case that fails the same way on every resume is kept as
failed.json and left out, the study goes on, a resume does not run it again, and a broken worker pool stops it."""
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path

import pytest

from mpm.files import JsonRecord, read_json
from studies.study import Study


@dataclass
class Rec(JsonRecord):
    config: dict
    value: int


@dataclass(frozen=True)
class Case:
    index: int
    folder: Path


class Toy(Study):
    name = "toy"
    record = Rec

    def __init__(self, out, config, fail=(), broken=()):
        super().__init__(out, config)
        self.fail, self.broken, self.ran = set(fail), set(broken), []

    def cases(self):
        return [Case(i, self.out / "cases" / f"case_{i}") for i in range(4)]

    def run_case(self, case, *, forward, progress=None):
        self.ran.append(case.index)
        if case.index in self.broken:
            raise BrokenProcessPool("a worker died")
        if case.index in self.fail:
            raise RuntimeError(f"every simulation failed in stage 1 (case {case.index})\nsecond line")
        return Rec(self.config, 10 * case.index)

    def summary(self, records):
        return Rec(self.config, sum(r.value for r in records))

    def table(self, records, summary):
        return f"sum {summary.value}\n"

    def plots(self, records, summary):
        return None


def test_a_failing_case_is_kept_as_failed_and_left_out(tmp_path):
    lines = []
    study = Toy(tmp_path, {"a": 1}, fail={1})
    res = study.run(forward=None, progress=lambda m: lines.append(m.text))
    assert study.ran == [0, 1, 2, 3]
    assert [c["value"] for c in res["cases"]] == [0, 20, 30] and res["summary"]["value"] == 50
    assert res["failed"] == [{"config": {"a": 1}, "error": "every simulation failed in stage 1 (case 1)",
                              "folder": "cases/case_1"}]
    assert read_json(tmp_path / "cases" / "case_1" / "failed.json")["error"].startswith("every simulation failed")
    assert any("failed, left out: every simulation failed" in line for line in lines)
    table = (tmp_path / "toy.md").read_text()
    assert "- cases/case_1: every simulation failed in stage 1 (case 1)" in table
    again = Toy(tmp_path, {"a": 1})  # a resume runs nothing: three finished, one failed
    assert again.run(forward=None)["failed"] == res["failed"] and again.ran == []
    (tmp_path / "cases" / "case_1" / "failed.json").unlink()  # deleted: retried
    third = Toy(tmp_path, {"a": 1})
    assert third.run(forward=None)["failed"] == [] and third.ran == [1]


def test_a_failure_under_another_configuration_is_not_this_ones(tmp_path):
    Toy(tmp_path / "x", {"a": 1}, fail={2}).run(forward=None)
    other = Toy(tmp_path / "x", {"a": 2})
    with pytest.raises(ValueError, match="other settings"):  # its finished cases stop it, as before
        other.run(forward=None)


def test_a_broken_worker_pool_stops_the_study_and_marks_nothing(tmp_path):
    study = Toy(tmp_path, {"a": 1}, broken={1})
    with pytest.raises(BrokenProcessPool):
        study.run(forward=None)
    assert not (tmp_path / "cases" / "case_1" / "failed.json").exists()
    assert (tmp_path / "cases" / "case_0" / "case.json").is_file()
