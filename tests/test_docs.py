"""The documentation's claims against the tests: every test a document names exists (with the
parameters it names), every count docs/reliability.md states is the count the tests carry, and
every limit's value is asserted by the test its row names."""

from __future__ import annotations

import ast
import importlib
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
# The core's tests and each backend's own; a test file's name is unique across them (pytest imports
# each by its name).
TEST_FOLDERS = [ROOT / "tests", *sorted((ROOT / "backends").glob("*/tests"))]
RELIABILITY = ROOT / "docs" / "reliability.md"
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
# `tests/test_x.py`, `backends/b/tests/test_x.py`, `test_x.py::name` or `test_x.py::name[a,b]` in backticks.
REF = re.compile(r"`((?:backends/\w+/)?tests/)?(test_\w+\.py)(?:::(\w+)(?:\[([^\]`]*)\])?)?`")


def _test_file(folder: str | None, file: str) -> Path | None:
    """The file a reference names: in its folder when it names one, else in any tests folder."""
    candidates = [ROOT / folder / file] if folder else [f / file for f in TEST_FOLDERS]
    return next((p for p in candidates if p.is_file()), None)


def _functions(path: Path) -> dict[str, ast.FunctionDef]:
    tree = ast.parse(path.read_text())
    return {n.name: n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name.startswith("test_")}


def _literal_params(fn: ast.FunctionDef) -> set[str]:
    """The string values of a test's literal ``parametrize`` lists (what pytest uses as their ids)."""
    out: set[str] = set()
    for d in fn.decorator_list:
        if isinstance(d, ast.Call) and getattr(d.func, "attr", "") == "parametrize" and len(d.args) >= 2:
            try:
                values = ast.literal_eval(d.args[1])
            except ValueError:
                continue
            out |= {v for v in values if isinstance(v, str)}
    return out


def _refs(doc: Path) -> list[tuple[int, str | None, str, str | None, str | None]]:
    return [(i + 1, *m.groups()) for i, line in enumerate(doc.read_text().splitlines()) for m in REF.finditer(line)]


def _case_count(file: str, name: str) -> int:
    fn = getattr(importlib.import_module(file.removesuffix(".py")), name)
    (mark,) = [m for m in fn.pytestmark if m.name == "parametrize"]
    return len(mark.args[1])


def _pano_repeats() -> int:
    """Read from the photo backend's test file, not imported: the core's tests import no backend."""
    tree = ast.parse(_test_file(None, "test_photo_backend.py").read_text())
    (src,) = [ast.literal_eval(n.value) for n in tree.body
              if isinstance(n, ast.Assign) and [t.id for t in n.targets if isinstance(t, ast.Name)] == ["PANO_REPEAT"]]
    seeds, per_seed = re.findall(r"for \w+ in range\((\d+)\)", src)
    return int(seeds) * int(per_seed)


# Counts docs/reliability.md states, and where the tests keep them.
COUNTS = [
    (r"(\d+) broken specs", lambda: _case_count("test_spec_errors.py", "test_broken_spec_is_located")),
    (r"(\d+) repeated identical background computations", _pano_repeats),
]


@pytest.mark.parametrize("doc", DOCS, ids=[str(d.relative_to(ROOT)) for d in DOCS])
def test_every_named_test_exists(doc):
    missing = []
    for line, folder, file, name, params in _refs(doc):
        path = _test_file(folder, file)
        if path is None:
            missing.append((line, f"{folder or ''}{file}"))
            continue
        if name is None:
            continue
        fns = _functions(path)
        if name not in fns:
            missing.append((line, f"{file}::{name}"))
        elif params is not None:
            missing += [(line, f"{file}::{name}[{p}]") for p in params.split(",") if p.strip() not in _literal_params(fns[name])]
    assert not missing, f"{doc.name} names tests that do not exist: {missing}"


def test_reliability_names_tests_in_every_row():
    """Every row of every table names at least one test, and the fault table names at least ten."""
    rows = [ln for ln in RELIABILITY.read_text().splitlines() if ln.startswith("|") and not ln.startswith("|---")]
    body = [r for r in rows if not r.startswith(("| guarantee", "| limit"))]
    assert len(body) >= 10 and all(REF.search(r.split("|")[-2]) for r in body), [r for r in body if not REF.search(r.split("|")[-2])]


@pytest.mark.parametrize(("claim", "actual"), COUNTS, ids=[c for c, _ in COUNTS])
def test_stated_counts_are_the_tests_counts(claim, actual):
    found = re.findall(claim, RELIABILITY.read_text())
    assert found, f"docs/reliability.md no longer states {claim!r}: update COUNTS"
    assert {int(n) for n in found} == {actual()}, (claim, found, actual())


def test_every_limit_is_asserted_by_its_test():
    """A limit's row: its value (in backticks) appears verbatim in the source of the test it names."""
    text = RELIABILITY.read_text()
    section = text[text.index("## Limits"):].split("\n## ")[0]
    rows = [ln for ln in section.splitlines() if ln.startswith("| ") and not ln.startswith("| limit")]
    assert len(rows) >= 4
    for row in rows:
        cells = [c.strip() for c in row.strip("|").split("|")]
        value = cells[1].strip("`")
        (folder, file, name, _), = [m.groups() for m in REF.finditer(cells[-1])]
        path = _test_file(folder, file)
        fn = _functions(path)[name]
        src = ast.get_source_segment(path.read_text(), fn)
        assert value in src, f"{name} does not assert the limit {value!r} that docs/reliability.md states"
