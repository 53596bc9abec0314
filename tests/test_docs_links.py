"""The documentation's links resolve, and every ``virheo`` command is documented one click from docs/index.md."""
from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
PAGES = sorted(DOCS.rglob("*.md")) + [ROOT / "README.md"]

_FENCE = re.compile(r"^(```|~~~).*?^\1", re.M | re.S)
_CODE_SPAN = re.compile(r"`[^`\n]*`")
_LINK = re.compile(r"!?\[[^\]\n]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
_HEADING = re.compile(r"^#{1,6}\s+(.*?)\s*#*\s*$", re.M)
_HTML_ID = re.compile(r"<a\s+(?:name|id)=\"([^\"]+)\"")


def _text(page: Path) -> str:
    """The page without fenced code blocks and inline code, where brackets are not links."""
    return _CODE_SPAN.sub("", _FENCE.sub("", page.read_text(encoding="utf-8")))


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"`", "", heading).strip().lower()
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(page: Path) -> set[str]:
    text = _FENCE.sub("", page.read_text(encoding="utf-8"))
    found: set[str] = set()
    for heading in _HEADING.findall(text):
        base, k = slug(heading), 0
        name = base
        while name in found:  # repeated headings get -1, -2, ...
            k += 1
            name = f"{base}-{k}"
        found.add(name)
    return found | set(_HTML_ID.findall(text))


def links(page: Path) -> list[str]:
    return [t for t in _LINK.findall(_text(page)) if not re.match(r"^[a-z][a-z0-9+.-]*:", t, re.I)]


def test_slug_follows_github():
    assert slug("`virheo study emulation`") == "virheo-study-emulation"
    assert slug("Presets: cost and accuracy") == "presets-cost-and-accuracy"
    assert slug("Experiment design: loss normals and the next setup (sections 5–6)") == \
        "experiment-design-loss-normals-and-the-next-setup-sections-56"


def test_link_parser_sees_links_and_skips_code():
    page = DOCS / "index.md"
    found = links(page)
    assert "user-guide.md#virheo-estimate" in found
    assert "../DEVELOPERS.md" in found
    assert not any(t.startswith("http") for t in found)


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(page):
    broken = []
    for target in links(page):
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if not dest.exists():
            broken.append(f"{target}: no such file")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            broken.append(f"{target}: no heading '#{anchor}' in {dest.relative_to(ROOT)}")
    assert not broken, f"{page.relative_to(ROOT)}: " + "; ".join(broken)


def _help(argv: list[str]) -> str:
    from studies.cli import main

    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit):
        main(argv + ["--help"])
    return out.getvalue()


def _subcommands(help_text: str) -> list[str]:
    """Sub-command names as argparse lists them: four spaces, the name, then its help or a line break."""
    return re.findall(r"^ {4}([a-z][\w-]*)(?: |$)", help_text, re.M)


def test_every_command_is_one_click_from_the_index():
    commands = []
    for name in _subcommands(_help([])):
        nested = _subcommands(_help([name]))
        commands += [f"{name} {sub}" for sub in nested] or [name]
    assert "estimate" in commands and "study emulation" in commands
    guide = anchors(DOCS / "user-guide.md")
    index_links = set(links(DOCS / "index.md"))
    for command in commands:
        anchor = slug(f"virheo {command}")
        assert anchor in guide, f"docs/user-guide.md has no section '### `virheo {command}`'"
        assert f"user-guide.md#{anchor}" in index_links, f"docs/index.md does not link to virheo {command}"


_CELL_SEP = re.compile(r"(?<!\\)\|")


def _tables(page: Path):
    """Each table of the page as (line number of its header, [cells per row]); a table is a run of lines starting with |."""
    lines = _FENCE.sub(lambda m: "\n" * m.group(0).count("\n"), page.read_text(encoding="utf-8")).split("\n")
    run: list[tuple[int, str]] = []
    for number, line in enumerate(lines + [""], start=1):
        if line.startswith("|"):
            run.append((number, line))
            continue
        if len(run) >= 2:
            yield run[0][0], [len(_CELL_SEP.split(text.strip().strip("|"))) for _, text in run]
        run = []


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_table_row_has_its_headers_cells(page):
    """A row with more or fewer cells than its header shifts its figures under the wrong column."""
    bad = [f"{page.name}:{line} header {cells[0]} cells, rows {sorted(set(cells[1:]) - {cells[0]})}"
           for line, cells in _tables(page) if set(cells) != {cells[0]}]
    assert not bad, bad
