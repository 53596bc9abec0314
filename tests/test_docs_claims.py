"""The documentation states claims: no narration of how a figure was measured (load, nice levels, what ran beside,
idle or shared machines, earlier builds: the benches print their conditions), every table of the claim pages stands
in a section that holds the command reproducing it, every claim has a verdict, and every default in decisions.md
names the command that shows why."""
from __future__ import annotations

import re

import pytest

from test_docs_links import DOCS, PAGES, ROOT, _text

CLAIM_PAGES = [DOCS / "validation.md", DOCS / "performance.md", DOCS / "figures.md"]
MAX_VALIDATION_LINES = 350

# How a figure was measured, told in prose; each pattern names what it catches.
NARRATION = {
    "a load average": re.compile(r"\bat load\b|\bload(?: average)? \d", re.I),
    "a nice level": re.compile(r"\bnice(?: -n)? ?\d", re.I),
    "what ran beside": re.compile(
        r"\bbeside (?:a|an|the|one|two|three|other|another)\b[^.;:]{0,80}?"
        r"\b(?:runs?|jobs?|benchmarks?|estimates?|study|studies|process(?:es)?|workers?)\b", re.I),
    "an earlier build": re.compile(r"\b(?:earlier|older|previous) (?:builds?|solvers?|engines?|kernels?|budgets?)\b",
                                   re.I),
    "a figure not recorded": re.compile(r"\bnot recorded\b", re.I),
    "an idle machine": re.compile(r"\bidle (?:machine|core|cpu|2-core)|\bon (?:an? |the )?(?:otherwise )?idle\b"
                                  r"|\botherwise idle\b|\(idle\b|\bnothing else running\b", re.I),
    "a shared machine": re.compile(r"\bshared (?:2-core )?machine\b|\bshared with other work\b", re.I),
    "a build or commit": re.compile(r"\b(?:at|on) commit [0-9a-f]{7,}\b|\bthe (?:same|current) build\b", re.I),
}

# A command a reader can run: a bench script, the test suite, or a virheo command with an argument, in a code
# span or an indented code line (environment variables and a timer may come first).
COMMAND = re.compile(r"(?:^ {4}|`)(?:[A-Z_]+=\S* )*(?:(?:/usr/bin/)?time(?: -v)? )?(?:\.venv/bin/)?"
                     r"(?:python (?:-m pytest \S|bench/bench_\w+\.py)|virheo [a-z][^`\n]*? (?:--?[a-z]|\S*/))",
                     re.M)
VERDICT = re.compile(r"\bVerdict\b\W{0,4}(?:[^\n]{0,200}?)\b(met|missed|open|no target)\b", re.I)
HEADING = re.compile(r"^(#{1,6}) ", re.M)
TABLE_START = re.compile(r"^(?!\|)[^\n]*\n(\|[^\n]*\|)\n\|[-:| ]+\|$", re.M)


def narration(text: str) -> list[str]:
    """'what: the sentence's words' for every narration pattern that matches prose (code is left out)."""
    found = []
    for what, pattern in NARRATION.items():
        for m in pattern.finditer(text):
            found.append(f"{what}: ...{text[max(0, m.start() - 40):m.end() + 20]!r}...")
    return found


def sections(text: str, level: int) -> list[tuple[str, str]]:
    """(heading, body with its subsections) for every heading of ``level``, after ('', the text before the first)."""
    marks = [(m.start(), len(m.group(1))) for m in HEADING.finditer(text)]
    heads = [pos for pos, lv in marks if lv == level]
    out = [("", text[:heads[0] if heads else len(text)])]
    for start in heads:
        end = next((pos for pos, lv in marks if pos > start and lv <= level), len(text))
        out.append((text[start:text.index("\n", start)], text[start:end]))
    return out


def enclosing_section(text: str, pos: int) -> tuple[str, str]:
    """The innermost heading before ``pos`` and its section (to the next heading of its level or above)."""
    marks = [(m.start(), len(m.group(1))) for m in HEADING.finditer(text)]
    before = [(p, lv) for p, lv in marks if p < pos]
    if not before:
        return "(page top)", text[:marks[0][0] if marks else len(text)]
    start, level = before[-1]
    end = next((p for p, lv in marks if p > start and lv <= level), len(text))
    return text[start:text.index("\n", start)], text[start:end]


def test_narration_patterns_catch_narration_and_spare_claims():
    narrated = [
        "for most of the time beside a single-worker convergence benchmark at nice 10",
        "were measured at load 5-8 with an earlier solver that gives the same silhouettes",
        "| lotion | 12.3, 0.305, 2.26 | not recorded | 29 min (idle) |",
        "1372 simulations in 53 s wall on the idle machine",
        "10.9 s (load 4.1)",
        "1030 s with one worker at `nice -n 5` beside other jobs",
        "two workers on an otherwise idle 2-core machine",
        "the agreement and speed figures are of the engine at commit 739c5dc",
    ]
    stated = [
        "Two setups end closer to the truth than one setup in 16 of the 18 runs.",
        "our own Theta map beside the published one",
        "Simulation files written by older versions do not carry their request.",
        "While ours (b) shows nice agreement with the captured footage",
        "The default's 12,180 particles leave the GPU mostly idle (21 M particle-steps/s).",
        "a process that loads the kernels from the cache stays silent",
    ]
    assert all(narration(s) for s in narrated), [s for s in narrated if not narration(s)]
    assert not any(narration(s) for s in stated), [narration(s) for s in stated if narration(s)]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_docs_state_claims_without_narrating_how_they_were_measured(page):
    found = narration(_text(page))
    assert not found, f"{page.relative_to(ROOT)}: measuring conditions belong in the bench's printed header " \
                      f"(bench/measured.py), not in the prose: " + "; ".join(found)


def test_command_pattern_sees_commands_not_mentions():
    assert COMMAND.search("Reproduce: `python bench/bench_forward.py --skip-timing` (20 s).")
    assert COMMAND.search("    VIRHEO_ARCH=taichi-cpu virheo study calibration --cases N --setting both")
    assert COMMAND.search("`/usr/bin/time -v virheo figures --quick\n--out DIR`")
    assert COMMAND.search("`virheo rheometer Chuno_20230114_1458_23C.csv --material ETA,N,SIGMA_Y`")
    assert not COMMAND.search("the `virheo demo` figures are stated once")
    assert not COMMAND.search("bench_estimate.py prints the engine")


@pytest.mark.parametrize("page", CLAIM_PAGES, ids=lambda p: p.name)
def test_every_table_has_its_command(page):
    text = page.read_text(encoding="utf-8")
    missing = []
    for m in TABLE_START.finditer(text):
        heading, body = enclosing_section(text, m.start(1))
        if not COMMAND.search(body):
            missing.append(f"{heading or '(page top)'}: table '{m.group(1)[:60]}'")
    assert not missing, f"{page.name}: tables without a command that reproduces them: " + "; ".join(missing)


@pytest.mark.parametrize("page", CLAIM_PAGES, ids=lambda p: p.name)
def test_every_claim_has_a_command_and_a_verdict(page):
    bad = []
    for heading, body in sections(page.read_text(encoding="utf-8"), 2)[1:]:
        if not COMMAND.search(body):
            bad.append(f"{heading}: no command")
        if not VERDICT.search(body):
            bad.append(f"{heading}: no verdict (met, missed, open or no target)")
    assert not bad, f"{page.name}: " + "; ".join(bad)


def test_every_default_names_the_command_behind_it():
    page = DOCS / "decisions.md"
    found = sections(page.read_text(encoding="utf-8"), 2)[1:]
    names = [heading.lstrip("# ").strip() for heading, _ in found]
    for default in ("Discretisation", "Walls", "Presets", "Likelihood scale", "Density correction", "Engine"):
        assert default in names, f"decisions.md has no section '## {default}'"
    bad = [heading for heading, body in found if not COMMAND.search(body)]
    assert not bad, "decisions.md sections without a command that shows the decision: " + "; ".join(bad)


def test_validation_page_is_short():
    lines = (DOCS / "validation.md").read_text(encoding="utf-8").count("\n")
    assert lines <= MAX_VALIDATION_LINES, f"docs/validation.md has {lines} lines (at most {MAX_VALIDATION_LINES})"
