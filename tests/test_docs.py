"""The docs are a reference, not a diary: short lines, no history of work sessions, and
docs/benchmarks.md the latest figures per benchmark (its history is in git)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = sorted((ROOT / "docs").glob("*.md")) + [ROOT / "README.md"]
MAX_LINE = 400
MAX_BENCHMARK_LINES = 600


@pytest.mark.parametrize("path", DOCS, ids=lambda p: p.name)
def test_no_line_over_400_characters(path):
    long = [(n, len(line)) for n, line in enumerate(path.read_text().splitlines(), 1) if len(line) > MAX_LINE]
    assert not long, f"{path.name}: lines over {MAX_LINE} characters (line, length): {long[:10]}"


@pytest.mark.parametrize("path", DOCS, ids=lambda p: p.name)
def test_no_diary_of_sittings(path):
    hits = [n for n, line in enumerate(path.read_text().splitlines(), 1) if re.search(r"sitting", line, re.I)]
    assert not hits, f"{path.name}: 'sitting' on lines {hits[:10]}: the docs say what is, not when it was done"


def test_benchmarks_is_a_reference_of_at_most_600_lines():
    text = (ROOT / "docs" / "benchmarks.md").read_text()
    assert len(text.splitlines()) <= MAX_BENCHMARK_LINES


def test_the_docs_anchors_into_benchmarks_exist():
    """Links to a section of docs/benchmarks.md (from any doc) name a heading it has."""
    text = (ROOT / "docs" / "benchmarks.md").read_text()
    anchors = {re.sub(r"[^a-z0-9 _-]", "", h.strip().lower()).replace(" ", "-")
               for h in re.findall(r"^#+ (.+)$", text, re.M)}
    for path in DOCS:
        for anchor in re.findall(r"benchmarks\.md#([\w-]+)|\]\(#([\w-]+)\)", path.read_text()):
            name = anchor[0] or anchor[1]
            if anchor[1] and path.name != "benchmarks.md":
                continue
            assert name in anchors, f"{path.name}: no heading for #{name} in docs/benchmarks.md"


def test_the_module_table_has_one_short_row_per_module():
    """docs/architecture.md says what each module owns in a line; how it does it is the code's."""
    text = (ROOT / "docs" / "architecture.md").read_text()
    table = text.split("\n## Modules\n", 1)[1].split("\n## ", 1)[0]
    long = [row.split("|")[1].strip() for row in table.splitlines() if row.startswith("| `") and len(row) > 300]
    assert not long, f"module rows over 300 characters: {long}"
