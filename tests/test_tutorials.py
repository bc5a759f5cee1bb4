"""Every tutorial runs: its files are written, its ```bash commands run in order in a fresh folder
holding the repository's specs/ and examples/, each exiting 0.

What is run: fenced ```yaml / ```python blocks with a ``title="FILE"`` are written to FILE; every
line of a ```bash block is a command (```sh blocks are illustrations, never run). ``specsynth`` and
``python`` run in this interpreter. A ``specsynth build`` runs at tiny size (the TINY overrides
appended: 160 x 120 pixels, two arrangements of two cameras), so a tutorial takes seconds; the
commands are otherwise the tutorial's own.
"""

from __future__ import annotations

import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from photolike import photo_faults

ROOT = Path(__file__).resolve().parents[1]
TUTORIALS = ROOT / "docs" / "tutorials"
TINY = ["--set", "intrinsics={width: 160, height: 120, fx: 143.1, fy: 143.4, cx: 80.0, cy: 60.0}",
        "--set", "arrangements.count=2", "--set", "cameras.per_arrangement=2"]
FENCE = re.compile(r"^```(\w+)([^\n]*)\n(.*?)^```", re.M | re.S)
# Tutorials that render with a PBR backend run with the slow tests.
PBR = {"bop-objects.md", "own-scene.md", "swap-renderer.md", "real-images.md"}


def steps(text: str) -> list[tuple[str, str]]:
    """("file", "name\\0content") and ("run", command line) in the order the tutorial gives them."""
    out = []
    for lang, info, body in FENCE.findall(text):
        title = re.search(r'title="([^"]+)"', info)
        if title and lang in ("yaml", "python"):
            out.append(("file", f"{title.group(1)}\0{body}"))
        elif lang == "bash":
            out += [("run", line) for line in body.splitlines() if line.strip() and not line.lstrip().startswith("#")]
    return out


def command(line: str) -> list[str]:
    words = shlex.split(line, comments=True)
    if words[0] == "specsynth":
        words = [sys.executable, "-m", "specsynth.cli", *words[1:]] + (TINY if words[1] == "build" else [])
    elif words[0] == "python":
        words = [sys.executable, *words[1:]]
    return words


def test_every_tutorial_is_in_the_site_and_has_commands():
    nav = (ROOT / "mkdocs.yml").read_text()
    for md in TUTORIALS.glob("*.md"):
        assert f"tutorials/{md.name}" in nav, md.name
        assert any(kind == "run" for kind, _ in steps(md.read_text())), md.name


@pytest.mark.parametrize("name", [pytest.param(p.name, marks=pytest.mark.slow) if p.name in PBR else p.name
                                  for p in sorted(TUTORIALS.glob("*.md"))])
def test_a_tutorial_runs(name, tmp_path):
    for folder in ("specs", "examples"):
        shutil.copytree(ROOT / folder, tmp_path / folder)
    shutil.copytree(ROOT / "schemas", tmp_path / "schemas")
    for kind, what in steps((TUTORIALS / name).read_text()):
        if kind == "file":
            file, body = what.split("\0", 1)
            (tmp_path / file).parent.mkdir(parents=True, exist_ok=True)
            (tmp_path / file).write_text(body)
            continue
        r = subprocess.run(command(what), cwd=tmp_path, capture_output=True, text=True, timeout=1800)
        assert r.returncode == 0, f"{name}: `{what}` exited {r.returncode}:\n{r.stderr[-2000:]}"
    if name in PBR:  # what a tutorial renders with a path tracer looks like a photograph
        images = [p for p in tmp_path.rglob("rgb/*") if p.suffix in (".png", ".jpg") and "bop" in p.parts]
        assert images, f"{name}: no image rendered"
        assert not [f for p in images for f in photo_faults(p)], [f for p in images for f in photo_faults(p)]
