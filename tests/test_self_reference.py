"""The project speaks of itself: no work-session numbers, dates of work, paths of one machine or
files outside the repository in anything it ships (code, comments, docs, tests, specs)."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# Built from pieces so that this file does not match itself.
FORBIDDEN = [
    ("a work session", re.compile(r"\b(this|last|previous|next) " + "session\\b|\\bsession " + r"\d+", re.I)),
    ("a round of work", re.compile(r"\b(this|last|previous|next) " + r"round\b|\bround" + r"'s (work|rooms)", re.I)),
    ("a folder outside the repository", re.compile(r"\.\./" + "shared")),
    ("a path of one machine", re.compile("/" + r"work/(main|wt-)")),
    ("a day of work", re.compile(r"(measured|re-run|slow|VM)( on)? (day|" + r"20\d\d-\d\d-\d\d)", re.I)),
    ("a day of work", re.compile(r"\bVM" + r" day\b|\bslow" + r" day\b", re.I)),
]
SKIP = ("schemas/", "docs/images/", "tests/data/")


def shipped_text_files() -> list[Path]:
    names = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
    out = []
    for name in names:
        p = ROOT / name
        if name.startswith(SKIP) or not p.is_file() or p.stat().st_size > 2_000_000:
            continue
        try:
            p.read_text()
        except UnicodeDecodeError:
            continue
        out.append(p)
    return out


def test_nothing_shipped_names_a_session_a_machine_or_a_folder_outside_the_repository():
    found = []
    for p in shipped_text_files():
        for n, line in enumerate(p.read_text().splitlines(), 1):
            for what, pattern in FORBIDDEN:
                if pattern.search(line):
                    found.append(f"{p.relative_to(ROOT)}:{n}: {what}: {line.strip()[:100]}")
    assert not found, "\n".join(found)


def test_the_check_finds_what_it_forbids():
    lines = ["as measured in " + "sess" + "ion 9", "see ../" + "shared/x.md", "cd /" + "work/main",
             "Measured 2026-" + "11-21 on the VM", "on a slow VM " + "day", "goals of this " + "round"]
    for line in lines:
        assert any(p.search(line) for _, p in FORBIDDEN), line
    assert not any(p.search("metadata.date_created=2026-11-23") for _, p in FORBIDDEN)
