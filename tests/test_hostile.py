"""Hostile and careless input (issue #35): special files, huge and broken textures, references out
of a file's folder, broken glTF nodes, files that are not specs, impossible ranges and counts.

Each test gives the tool a real file (a FIFO from os.mkfifo, /dev/zero, a PNG whose header claims
20000 x 20000 pixels, a glTF whose nodes form a cycle, ...) and checks that it is refused before
any expensive work, with the file and the field named, without hanging (every command that could
block runs in a subprocess under a timeout) and without echoing what the file holds."""

from __future__ import annotations

import json
import os
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest

from specsynth.plan.compiler import compile_spec
from specsynth.spec.yamlio import SpecError, load_spec

SPEC = """\
name: hostile
intrinsics: {width: 64, height: 48, fx: 58.0, fy: 58.0, cx: 31.5, cy: 23.5}
objects: {builtin: [duck]}
scenes:
  - file: scene.yaml
arrangements: {count: 1}
cameras: {per_arrangement: 2, distance: [0.35, 0.7]}
backend: {name: photo}
"""

SCENE = """\
name: s
meshes:
  - {name: floor, source: {plane: [2, 2]}}
  - {name: table, source: table.obj}
stages:
  - {name: floor, polygon: [[-1, -1], [1, -1], [1, 1], [-1, 1]], height: 0}
"""

OBJ = """\
mtllib table.mtl
v 0 0 0.1
v 0.5 0 0.1
v 0 0.5 0.1
vt 0 0
vt 1 0
vt 0 1
usemtl wood
f 1/1 2/2 3/3
"""


def cli(*args, timeout: float = 120, cwd: Path | None = None) -> subprocess.CompletedProcess:
    """A real `specsynth` process; a hang fails the test (TimeoutExpired) instead of the suite."""
    return subprocess.run([sys.executable, "-m", "specsynth.cli", *map(str, args)], capture_output=True, text=True,
                          timeout=timeout, cwd=cwd)


def png_header(path: Path, width: int, height: int) -> Path:
    """A PNG that claims ``width`` x ``height`` pixels in a few bytes: its IHDR says so, its one
    IDAT chunk holds a single row. Readers that decode before checking the size allocate
    ``3 * width * height`` bytes."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 64))
                     + chunk(b"IEND", b""))
    return path


def small_png(path: Path, size: int = 8) -> Path:
    from PIL import Image

    Image.fromarray(np.full((size, size, 3), 128, np.uint8)).save(path)
    return path


def obj_scene(folder: Path, mtl: str = "newmtl wood\nKd 0.8 0.8 0.8\nmap_Kd wood.png\n", obj: str = OBJ) -> Path:
    """spec.yaml -> scene.yaml -> table.obj -> table.mtl (-> wood.png) in ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "spec.yaml").write_text(SPEC)
    (folder / "scene.yaml").write_text(SCENE)
    (folder / "table.obj").write_text(obj)
    (folder / "table.mtl").write_text(mtl)
    small_png(folder / "wood.png")
    return folder / "spec.yaml"


def problems(spec: Path, *overrides: str) -> list:
    with pytest.raises(SpecError) as e:
        compile_spec(load_spec(spec, list(overrides)))
    return e.value.problems


def one_message(spec: Path, *overrides: str) -> str:
    return "\n".join(str(p) for p in problems(spec, *overrides))


# --------------------------------------------------------------------------- 2. counts


def test_object_counts_are_bounded_before_any_work(tmp_path):
    spec = obj_scene(tmp_path)
    (pr,) = problems(spec, "objects.instances=[1000000,1000000]")
    assert pr.path == "objects.instances" and "1000" in pr.message
    (pr,) = problems(spec, "objects.instances=[0,300]", "arrangements.distractors={count: [300, 300]}")
    assert pr.path == "objects.instances" and "objects per arrangement" in pr.message
    assert "SPECSYNTH_MAX_OBJECTS" in pr.message


# --------------------------------------------------------------------------- 11. what a scene file is


@pytest.mark.parametrize("kind, says", [("folder", "a folder"), ("fifo", "FIFO"), ("loop", "symbolic link loop")])
def test_a_scene_file_that_is_not_a_file_says_what_it_is(tmp_path, kind, says):
    spec = obj_scene(tmp_path)
    target = tmp_path / "other.yaml"
    if kind == "folder":
        target.mkdir()
    elif kind == "fifo":
        os.mkfifo(target)
    else:
        target.symlink_to(tmp_path / "loop.yaml")
        (tmp_path / "loop.yaml").symlink_to(target)
    r = cli("validate", spec, "--set", "scenes=[{file: other.yaml}]", timeout=60)
    assert r.returncode == 2 and says in r.stderr and "not found" not in r.stderr
