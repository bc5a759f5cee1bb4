"""Hostile and careless input (issue #35): special files, huge and broken textures, references out
of a file's folder, broken glTF nodes, files that are not specs, impossible ranges and counts.

Each test gives the tool a real file (a FIFO from os.mkfifo, /dev/zero, a PNG whose header claims
20000 x 20000 pixels, a glTF whose nodes form a cycle, ...) and checks that it is refused before
any expensive work, with the file and the field named, without hanging (every command that could
block runs in a subprocess under a timeout) and without echoing what the file holds."""

from __future__ import annotations

import json
import os
import re
import shutil
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


# --------------------------------------------------------------------------- 2. special files


@pytest.fixture()
def fifo(tmp_path) -> Path:
    p = tmp_path / "pipe.png"
    os.mkfifo(p)
    return p


@pytest.mark.parametrize("special, kind", [("fifo", "FIFO"), ("/dev/zero", "character device"),
                                           ("folder", "a folder")])
def test_a_special_file_as_a_texture_is_refused_without_opening_it(tmp_path, fifo, special, kind):
    spec = obj_scene(tmp_path / "s")
    path = {"fifo": fifo, "folder": tmp_path}.get(special, special)
    r = cli("validate", spec, "--set", f"objects.materials.duck.texture={path}", timeout=60)
    assert r.returncode == 2
    assert "objects.materials.duck.texture" in r.stderr and kind in r.stderr and str(path) in r.stderr


def test_a_fifo_as_an_object_mesh_or_a_scene_file_is_refused(tmp_path):
    spec = obj_scene(tmp_path / "s")
    os.mkfifo(tmp_path / "s" / "pipe.obj")
    r = cli("validate", spec, "--set", "objects.meshes=[{path: pipe.obj, unit: m}]", timeout=60)
    assert r.returncode == 2 and "pipe.obj" in r.stderr and "FIFO" in r.stderr
    os.mkfifo(tmp_path / "s" / "pipe.yaml")
    r = cli("validate", spec, "--set", "scenes=[{file: pipe.yaml}]", timeout=60)
    assert r.returncode == 2 and "scenes.0.file" in r.stderr and "FIFO" in r.stderr


GLTF_FIFO_BUFFER = {"asset": {"version": "2.0"}, "buffers": [{"uri": "pipe.bin", "byteLength": 36}],
                    "bufferViews": [{"buffer": 0, "byteLength": 36}],
                    "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                                   "min": [0, 0, 0], "max": [1, 1, 0]}],
                    "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}], "nodes": [{"mesh": 0}],
                    "scenes": [{"nodes": [0]}], "scene": 0}


@pytest.mark.parametrize("names", ["mtllib", "map_Kd", "glTF buffer"])
@pytest.mark.parametrize("command", ["validate", "build"])
def test_an_object_mesh_naming_a_fifo_is_refused_at_its_spec_line(tmp_path, names, command):
    """A spec's own mesh is checked as a scene file's is: what it names must be a regular file in
    its folder. Unchecked, trimesh opened the FIFO and the build hung."""
    spec = obj_scene(tmp_path / "s")
    folder = spec.parent
    if names == "glTF buffer":
        (folder / "mine.gltf").write_text(json.dumps(GLTF_FIFO_BUFFER))
        os.mkfifo(folder / "pipe.bin")
        mesh = "mine.gltf"
    else:
        mtl = "newmtl m\nKd 0.8 0.8 0.8\nmap_Kd pipe.png\n"
        (folder / "mine.obj").write_text(OBJ.replace("table.mtl", "pipe.mtl" if names == "mtllib" else "mine.mtl")
                                         .replace("usemtl wood", "usemtl m"))
        (folder / "mine.mtl").write_text(mtl)
        os.mkfifo(folder / ("pipe.mtl" if names == "mtllib" else "pipe.png"))
        mesh = "mine.obj"
    extra = ("--out", tmp_path / "out", "--quiet") if command == "build" else ()
    r = cli(command, spec, *extra, "--set", f"objects.meshes=[{{path: {mesh}, unit: m}}]", timeout=90)
    assert r.returncode == 2, r.stderr
    assert "objects.meshes.0.path" in r.stderr and "FIFO" in r.stderr and "pipe." in r.stderr
    assert "Traceback" not in r.stderr


def test_an_object_mesh_that_is_not_a_mesh_is_refused_at_its_spec_line(tmp_path):
    spec = obj_scene(tmp_path / "s")
    (spec.parent / "notes.ply").write_text("SECRET_TOKEN: a text file named like a mesh\n")
    msg = one_message(spec, "objects.meshes=[{path: notes.ply, unit: m}]")
    assert "objects.meshes.0.path" in msg and "does not start like a PLY file" in msg and "SECRET_TOKEN" not in msg


def test_a_corrupt_object_mesh_is_named_without_quoting_its_bytes(tmp_path):
    spec = obj_scene(tmp_path / "s")
    (spec.parent / "bad.ply").write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\n"
                                         "property float y\nproperty float z\nelement face 1\n"
                                         "property list uchar int vertex_indices\nend_header\n"
                                         "0 0 0\nSECRET_TOKEN 1 0\n0 1 0\n3 0 1 2\n")
    r = cli("build", spec, "--out", tmp_path / "out", "--quiet", "--set", "objects.meshes=[{path: bad.ply, unit: m}]",
            timeout=120)
    assert r.returncode != 0 and "bad.ply" in r.stderr and "corrupt PLY" in r.stderr
    assert "SECRET_TOKEN" not in r.stderr + r.stdout and "Traceback" not in r.stderr


@pytest.mark.parametrize("target", ["fifo", "/dev/full", "folder"])
@pytest.mark.parametrize("command", ["schema", "compile"])
def test_a_file_to_write_that_is_not_a_regular_file_is_refused(tmp_path, target, command):
    """`schema --out /dev/full` read the device to compare it with the schema until memory ran
    out, and a FIFO as `--out` or `--jobs-out` blocked the writer."""
    spec = obj_scene(tmp_path / "s")
    path = {"fifo": tmp_path / "pipe.json", "folder": tmp_path}.get(target, Path(target))
    if target == "fifo":
        os.mkfifo(path)
    args = ("schema", "--out", path) if command == "schema" else ("compile", spec, "--jobs-out", path)
    r = cli(*args, timeout=60)
    said = "a folder, not a file" if target == "folder" else "not a regular file"
    assert r.returncode == 2 and str(path) in r.stderr and said in r.stderr, r.stderr
    assert "Traceback" not in r.stderr


def test_schema_and_jobs_files_are_written_and_a_link_there_is_replaced_not_followed(tmp_path):
    spec = obj_scene(tmp_path / "s")
    outside = tmp_path / "outside.json"
    outside.write_text("keep")
    (tmp_path / "jobs.jsonl").symlink_to(outside)
    r = cli("compile", spec, "--jobs-out", tmp_path / "jobs.jsonl", timeout=60)
    assert r.returncode == 0, r.stderr
    assert outside.read_text() == "keep" and not (tmp_path / "jobs.jsonl").is_symlink()
    jobs = [json.loads(line) for line in (tmp_path / "jobs.jsonl").read_text().splitlines()]
    assert jobs and {"stage", "id", "key", "seed", "upstream"} <= set(jobs[0])
    r = cli("schema", "--out", tmp_path / "schema.json", timeout=60)
    assert r.returncode == 0 and json.loads((tmp_path / "schema.json").read_text())["title"]


@pytest.mark.parametrize("target, says", [("file", "a file, not a folder"), ("/dev/null", "a character device, not a folder"),
                                          ("/", "the root of the file system")])
def test_an_out_that_is_not_a_folder_is_refused_before_any_work(tmp_path, target, says):
    spec = obj_scene(tmp_path / "s")
    path = tmp_path / "afile" if target == "file" else Path(target)
    if target == "file":
        path.write_text("mine")
    r = cli("build", spec, "--out", path, "--quiet", timeout=60)
    assert r.returncode == 2 and f"--out {path}: {says}" in r.stderr, r.stderr
    assert target != "file" or path.read_text() == "mine"


def _validate_with_last_line(tmp_path, last_line: str):
    spec = obj_scene(tmp_path)
    spec.write_text(SPEC.replace("name: hostile\n", "") + last_line + "\n")
    r = cli("validate", spec, timeout=60)
    assert r.returncode == 2 and "Traceback" not in r.stderr and "Error" not in r.stderr, r.stderr
    assert f"{spec}:{len(spec.read_text().splitlines())}:" in r.stderr, r.stderr  # the line that holds it
    return r.stderr


def test_a_spec_nested_too_deep_is_a_located_error(tmp_path):
    """600 nested brackets (1.5 KB) raised RecursionError, naming no line."""
    assert "nested deeper than 64 levels" in _validate_with_last_line(tmp_path, "name: " + "[" * 600 + "]" * 600)


def test_a_spec_integer_of_endless_digits_is_a_located_error(tmp_path):
    """A 5000-digit seed raised Python's ValueError (its limit of 4300 digits), naming no line."""
    err = _validate_with_last_line(tmp_path, "seed: " + "9" * 5000)
    assert "an integer of 5,000 characters (at most 4,000 digits)" in err


def test_a_nul_byte_in_a_spec_is_placed_by_line_and_column(tmp_path):
    spec = obj_scene(tmp_path)
    spec.write_bytes(SPEC.encode() + b"seed: 1\x00\n")
    r = cli("validate", spec, timeout=60)
    line = len(SPEC.splitlines()) + 1
    assert r.returncode == 2 and f"{spec}:{line}:8: YAML syntax error: character U+0000" in r.stderr, r.stderr


def test_a_scene_file_or_a_set_value_nested_too_deep_is_refused(tmp_path):
    spec = obj_scene(tmp_path)
    (tmp_path / "deep.yaml").write_text("name: s\nmeshes: " + "[" * 600 + "]" * 600 + "\n")
    r = cli("validate", spec, "--set", "scenes=[{file: deep.yaml}]", timeout=60)
    assert r.returncode == 2 and f"{tmp_path / 'deep.yaml'}:2:" in r.stderr, r.stderr
    assert "nested deeper than 64 levels" in r.stderr
    r = cli("validate", spec, "--set", "name=" + "[" * 600 + "]" * 600, timeout=60)
    assert r.returncode == 2 and "--set name" in r.stderr and "nested deeper" in r.stderr, r.stderr


@pytest.mark.parametrize("args, says", [
    (("build", "{spec}", "--out", "{tmp}/out", "--jobs", "0"), "argument --jobs: '0': at least 1"),
    (("build", "{spec}", "--out", "{tmp}/out", "--threads", "-1"), "argument --threads: '-1': at least 1"),
    (("scenes", "show", "room2", "--clearance", "nan"), "argument --clearance: 'nan': a finite distance"),
    (("bench", "{spec}", "--scale", "0"), "argument --scale: '0': a scale over 0"),
    (("bench", "{spec}", "--out", "o", "--ref-crop", "0"), "argument --ref-crop: '0': a fraction over 0"),
    (("bench", "{spec}", "--out", "o", "--ref-crop", "1.5"), "argument --ref-crop: '1.5': a fraction over 0"),
    (("scenes", "show", "room2", "--out", "{tmp}"), "a folder, not a file"),
    (("schema", "--backends", "cycles,bogus", "--stdout"), "--backends: bogus not installed"),
    (("scenes", "show", "room2", "--out", "{tmp}/top.txt"), "an image file name ending in .png or .jpg"),
])
def test_impossible_arguments_are_refused_before_any_work(tmp_path, args, says):
    spec = obj_scene(tmp_path / "s")
    r = cli(*(a.format(spec=spec, tmp=tmp_path) for a in args), timeout=60)
    assert r.returncode == 2 and says in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert not (tmp_path / "out").exists()


def test_plan_refuses_a_link_out_of_its_folder_as_build_does(tmp_path):
    spec = obj_scene(tmp_path / "s")
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / ".specsynth").symlink_to(tmp_path / "elsewhere")
    for command in ("plan", "build"):
        r = cli(command, spec, "--out", tmp_path / "out", timeout=60)
        assert r.returncode == 2 and "a symbolic link out of the output folder" in r.stderr, (command, r.stderr)
    assert list((tmp_path / "elsewhere").iterdir()) == []


@pytest.mark.parametrize("statement", ["mtllib", "map_Kd", "map_Pr", "map_Bump"])
@pytest.mark.parametrize("command", ["validate", "build", "show"])
def test_an_obj_naming_a_fifo_is_refused_by_every_command(tmp_path, statement, command):
    mtl = "newmtl wood\nKd 0.8 0.8 0.8\nmap_Kd wood.png\n"
    obj = OBJ
    if statement == "mtllib":
        obj = OBJ.replace("mtllib table.mtl", "mtllib pipe.mtl")
        os.mkfifo(tmp_path / "pipe.mtl")
    else:
        mtl += f"{statement} pipe.png\n"
        os.mkfifo(tmp_path / "pipe.png")
    spec = obj_scene(tmp_path, mtl=mtl, obj=obj)
    args = {"validate": ("validate", spec), "build": ("build", spec, "--out", tmp_path / "out", "--quiet"),
            "show": ("scenes", "show", tmp_path / "scene.yaml", "--out", tmp_path / "top.png")}[command]
    r = cli(*args, timeout=90)
    assert r.returncode == 2, r.stderr
    assert "FIFO" in r.stderr and "pipe." in r.stderr and "Traceback" not in r.stderr


@pytest.mark.parametrize("value", ["1e-300", "0", "-1", "1e9"])
def test_a_depth_scale_no_uint16_depth_can_hold_is_refused_at_its_field(tmp_path, value):
    (pr,) = problems(obj_scene(tmp_path), f"outputs.depth_scale={value}")
    assert pr.path == "outputs.depth_scale" and "[0.001, 1000] mm per unit" in pr.message


def test_object_counts_are_bounded_before_any_work(tmp_path):
    spec = obj_scene(tmp_path)
    (pr,) = problems(spec, "objects.instances=[1000000,1000000]")
    assert pr.path == "objects.instances" and "at most 1000 instances" in pr.message
    (pr,) = problems(spec, "objects.instances=[0,300]", "arrangements.distractors={count: [300, 300]}")
    assert pr.path == "objects.instances" and "objects per arrangement" in pr.message
    assert "SPECSYNTH_MAX_OBJECTS" in pr.message and "over the limit of 500" in pr.message
    (pr,) = problems(spec, "objects.instances=[0,0]")  # the build had run physics and cameras, then found no object
    assert pr.path == "objects.instances" and "no instance of any model would be dropped" in pr.message


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


# --------------------------------------------------------------------------- 7. huge and broken textures


def test_a_huge_obj_texture_is_refused_in_validate(tmp_path):
    spec = obj_scene(tmp_path)
    png_header(tmp_path / "wood.png", 20000, 20000)
    msg = one_message(spec)
    assert "wood.png" in msg and "pixel limit" in msg and "8192 x 8192" in msg


def test_a_huge_roughness_map_is_a_located_error(tmp_path):
    spec = obj_scene(tmp_path, mtl="newmtl wood\nKd 0.8 0.8 0.8\nmap_Pr rough.png\n")
    png_header(tmp_path / "rough.png", 20000, 20000)
    msg = one_message(spec)
    assert "rough.png" in msg and "table.mtl:3" in msg and "pixel limit" in msg
    assert "DecompressionBomb" not in msg


def test_a_huge_spec_texture_is_refused(tmp_path):
    spec = obj_scene(tmp_path)
    png_header(tmp_path / "big.png", 12000, 12000)
    (pr,) = problems(spec, "objects.materials.duck.texture=big.png")
    assert pr.path == "objects.materials.duck.texture" and "12000 x 12000" in pr.message


def test_a_text_file_as_an_obj_texture_is_refused(tmp_path):
    spec = obj_scene(tmp_path)
    (tmp_path / "wood.png").write_text("root:x:0:0:secret-token\n")
    msg = one_message(spec)
    assert "wood.png" in msg and "not an image" in msg and "secret-token" not in msg


# --------------------------------------------------------------------------- 8. references out of a file's folder


def test_an_obj_texture_outside_its_folder_is_refused(tmp_path):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    small_png(elsewhere / "private_photo.png")
    spec = obj_scene(tmp_path / "a" / "b", mtl="newmtl wood\nKd 0.8 0.8 0.8\nmap_Kd ../../elsewhere/private_photo.png\n")
    msg = one_message(spec)
    assert "private_photo.png" in msg and "outside" in msg and "table.mtl:3" in msg
    if Path("/etc/passwd").is_file():
        (spec.parent / "table.mtl").write_text("newmtl wood\nmap_Kd ../../../../../../../../etc/passwd\n")
        assert "outside" in one_message(spec)


def test_a_link_out_of_the_folder_is_refused_and_a_subfolder_is_fine(tmp_path):
    outside = small_png(tmp_path / "private.png")
    spec = obj_scene(tmp_path / "scene", mtl="newmtl wood\nKd 0.8 0.8 0.8\nmap_Kd textures/wood.png\n")
    (spec.parent / "textures").mkdir()
    small_png(spec.parent / "textures" / "wood.png")
    compile_spec(load_spec(spec))  # a texture in a subfolder is inside
    (spec.parent / "textures" / "wood.png").unlink()
    (spec.parent / "textures" / "wood.png").symlink_to(outside)
    assert "outside" in one_message(spec)


def test_an_mtllib_outside_its_folder_is_refused(tmp_path):
    (tmp_path / "lib.mtl").write_text("newmtl wood\nKd 0.1 0.2 0.3\n")
    spec = obj_scene(tmp_path / "s", obj=OBJ.replace("mtllib table.mtl", "mtllib ../lib.mtl"))
    msg = one_message(spec)
    assert "lib.mtl" in msg and "outside" in msg and "table.obj:1" in msg


def _gltf(folder: Path, **change) -> Path:
    """A one-triangle glTF (external buffer tri.bin) named room.gltf, with ``change`` applied to its JSON."""
    folder.mkdir(parents=True, exist_ok=True)
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 0, -1]], np.float32)
    (folder / "tri.bin").write_bytes(pos.tobytes() + np.array([0, 1, 2], np.uint16).tobytes() + b"\0\0")
    doc = {
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
        "nodes": [{"name": "floor", "mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "buffers": [{"uri": "tri.bin", "byteLength": 44}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 36}, {"buffer": 0, "byteOffset": 36, "byteLength": 6}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                       "min": [0, 0, -1], "max": [1, 0, 0]},
                      {"bufferView": 1, "componentType": 5123, "count": 3, "type": "SCALAR"}],
    }
    for key, value in change.items():
        doc[key] = value(doc) if callable(value) else value
    path = folder / "room.gltf"
    path.write_text(json.dumps(doc))
    return path


def _gltf_spec(folder: Path) -> Path:
    spec = folder / "spec.yaml"
    spec.write_text(SPEC.replace("file: scene.yaml", "file: room.gltf"))
    return spec


def test_a_gltf_buffer_outside_its_folder_is_refused(tmp_path):
    secret = tmp_path / "secret.bin"
    secret.write_bytes(b"\x01" * 44)
    _gltf(tmp_path / "s", buffers=[{"uri": "../secret.bin", "byteLength": 44}])
    msg = one_message(_gltf_spec(tmp_path / "s"))
    assert "secret.bin" in msg and "outside" in msg and "buffers[0]" in msg
    _gltf(tmp_path / "s", buffers=[{"uri": str(secret), "byteLength": 44}])
    assert "outside" in one_message(_gltf_spec(tmp_path / "s"))


def _with_image(uri: str):
    def change(doc):
        doc["images"] = [{"uri": uri}]
        doc["textures"] = [{"source": 0}]
        doc["materials"] = [{"name": "m", "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}]
        doc["meshes"][0]["primitives"][0]["material"] = 0
        return doc["meshes"]
    return change


@pytest.mark.parametrize("image, says", [("notes.png", "not an image"), ("../out.png", "outside"),
                                         ("big.png", "12000 x 12000")])
def test_a_gltf_image_that_cannot_be_used_is_an_error(tmp_path, image, says):
    folder = tmp_path / "s"
    _gltf(folder, meshes=_with_image(image))
    (folder / "notes.png").write_text("not a picture at all\n")
    small_png(tmp_path / "out.png")
    png_header(folder / "big.png", 12000, 12000)
    msg = one_message(_gltf_spec(folder))
    assert says in msg and "images[0]" in msg and "room.gltf" in msg


def test_a_urdf_mesh_outside_its_folder_is_refused(tmp_path):
    (tmp_path / "part.obj").write_text("v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nf 1 2 3\n")
    folder = tmp_path / "s"
    spec = obj_scene(folder)
    (folder / "thing.urdf").write_text('<robot name="t"><link name="l"><visual><geometry>'
                                       '<mesh filename="../part.obj"/></geometry></visual></link></robot>\n')
    (folder / "scene.yaml").write_text(SCENE.replace("source: table.obj", "source: thing.urdf"))
    msg = one_message(spec)
    assert "part.obj" in msg and "outside" in msg and "thing.urdf" in msg


def test_a_ply_texture_outside_its_folder_is_refused(tmp_path):
    small_png(tmp_path / "private.png")
    folder = tmp_path / "s"
    spec = obj_scene(folder)
    (folder / "part.ply").write_text("ply\nformat ascii 1.0\ncomment TextureFile ../private.png\nelement vertex 3\n"
                                     "property float x\nproperty float y\nproperty float z\nproperty float s\n"
                                     "property float t\nelement face 1\nproperty list uchar int vertex_indices\n"
                                     "end_header\n0 0 0 0 0\n0.1 0 0 1 0\n0 0.1 0 0 1\n3 0 1 2\n")
    msg = one_message(spec, "objects.meshes=[{path: part.ply, unit: m}]")
    assert "private.png" in msg and "outside" in msg


# --------------------------------------------------------------------------- 9. broken glTF nodes and lights


def _nodes(*nodes):
    def change(doc):
        doc["scenes"] = [{"nodes": [0]}]
        return list(nodes)
    return change


def _lit(light: dict):
    def change(doc):
        doc["extensions"] = {"KHR_lights_punctual": {"lights": [light]}}
        doc["extensionsUsed"] = ["KHR_lights_punctual"]
        return [{"name": "floor", "mesh": 0, "children": [1]},
                {"name": "lamp", "translation": [0, 2, 0], "extensions": {"KHR_lights_punctual": {"light": 0}}}]
    return change


@pytest.mark.parametrize("nodes, says", [
    (_nodes({"name": "a", "mesh": 0, "children": [1]}, {"name": "b", "children": [0]}), "reached twice"),
    (_nodes({"name": "far", "mesh": 0, "translation": [1e30, 0, 0]}), "beyond the 10,000 m"),
    (_nodes({"name": "flat", "mesh": 0, "scale": [0, 1, 1]}), "flattens"),
    (_nodes({"name": "huge", "mesh": 0, "scale": [1e20, 1e20, 1e20]}), "from the origin"),
    (_nodes({"name": "nan", "mesh": 0, "matrix": [float("nan")] * 16}), "NaN"),
    (_lit({"type": "point", "intensity": 1e308}), "intensity must be a number in [0, 1e+07]"),
    (_lit({"type": "point", "color": [float("nan"), 1, 1]}), "color"),
])
def test_a_broken_gltf_node_or_light_is_refused_by_validate_naming_it(tmp_path, nodes, says):
    folder = tmp_path / "s"
    _gltf(folder, nodes=nodes)
    r = cli("validate", _gltf_spec(folder), timeout=60)
    assert r.returncode == 2, r.stderr
    assert "room.gltf" in r.stderr and says in r.stderr and "Traceback" not in r.stderr
    assert "nodes[" in r.stderr or "lights[" in r.stderr


# --------------------------------------------------------------------------- 6. a file's contents are never echoed

SHADOW = "root:$6$SECRETHASH:19000:0:99999:7:::\ndaemon:*:19000:0:99999:7:::\nalice:$6$ALICEHASH:19000::::\n"


def test_validate_of_a_file_that_is_not_a_spec_does_not_quote_it(tmp_path):
    shadow = tmp_path / "shadow"
    shadow.write_text(SHADOW)
    r = cli("validate", shadow, timeout=60)
    assert r.returncode == 2 and "not a dataset spec" in r.stderr and str(shadow) in r.stderr
    assert not any(word in r.stderr + r.stdout for word in ("SECRETHASH", "daemon", "alice", "19000"))


def test_a_scene_file_that_is_not_a_scene_is_not_quoted(tmp_path):
    spec = obj_scene(tmp_path)
    (tmp_path / "shadow").write_text(SHADOW)
    r = cli("validate", spec, "--set", "scenes=[{file: shadow}]", timeout=60)
    assert r.returncode == 2 and "not a scene file" in r.stderr
    assert not any(word in r.stderr + r.stdout for word in ("SECRETHASH", "daemon", "alice", "19000"))


def test_a_gltf_light_index_that_is_not_a_number_is_not_quoted(tmp_path):
    folder = tmp_path / "s"

    def change(doc):
        _lit({"type": "point"})(doc)
        return [{"name": "floor", "mesh": 0, "children": [1]},
                {"name": "lamp", "extensions": {"KHR_lights_punctual": {"light": "SECRET"}}}]

    _gltf(folder, nodes=change, extensions={"KHR_lights_punctual": {"lights": [{"type": "point"}]}})
    r = cli("validate", _gltf_spec(folder), timeout=60)
    assert r.returncode == 2 and "nodes[1].extensions.KHR_lights_punctual.light" in r.stderr
    assert "SECRET" not in r.stderr and "Traceback" not in r.stderr


# --------------------------------------------------------------------------- 1, 5. export yolo


def bop_dataset(out: Path, arrangements: int = 2, views: int = 2, stereo: bool = False) -> Path:
    """A small BOP dataset as `build` writes it: one chunk per eye, ``views`` images per
    arrangement, one visible object each, and the Parquet images table mapping images to
    arrangements (``images_right.parquet`` for a stereo build's right eye)."""
    import pyarrow as pa
    import pyarrow.parquet as pq
    from PIL import Image

    (out / "parquet").mkdir(parents=True)
    for split, table in [("train_pbr", "images")] + ([("train_pbr_right", "images_right")] if stereo else []):
        chunk = out / "bop" / split / "000000"
        (chunk / "rgb").mkdir(parents=True)
        gt, info, cams, rows = {}, {}, {}, {"rgb": [], "arr": []}
        for im in range(arrangements * views):
            Image.fromarray(np.full((24, 32, 3), 90, np.uint8)).save(chunk / "rgb" / f"{im:06d}.jpg")
            gt[str(im)] = [{"obj_id": 1, "cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [0, 0, 500]}]
            info[str(im)] = [{"bbox_visib": [4, 4, 10, 8], "px_count_visib": 80, "visib_fract": 0.9}]
            cams[str(im)] = {"cam_K": [30, 0, 16, 0, 30, 12, 0, 0, 1], "depth_scale": 1.0}
            rows["rgb"].append(f"bop/{split}/000000/rgb/{im:06d}.jpg")
            rows["arr"].append(im // views)
        for name, doc in (("scene_gt", gt), ("scene_gt_info", info), ("scene_camera", cams)):
            (chunk / f"{name}.json").write_text(json.dumps(doc))
        pq.write_table(pa.table({"rgb": rows["rgb"], "arr": pa.array(rows["arr"], pa.int32())}),
                       out / "parquet" / f"{table}.parquet")
    return out


def export(*args) -> tuple[int, str]:
    from specsynth.cli import main

    import contextlib
    import io

    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        try:
            rc = main(["export", "yolo", *map(str, args)])
        except SystemExit as e:  # an argument the parser refuses: exit status 2, as from a shell
            rc = e.code
    return rc, err.getvalue()


def _tree(folder: Path) -> dict[str, bytes]:
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("link", ["images", "images/train_pbr", "labels/train_pbr/train_pbr_000000_000001.txt"])
def test_export_writes_and_deletes_nothing_through_a_link_out_of_dest(tmp_path, link):
    out = bop_dataset(tmp_path / "out")
    dest = tmp_path / "dest"
    assert export(out, dest) == (0, "")
    elsewhere = tmp_path / "users_files"
    elsewhere.mkdir()
    (elsewhere / "train_pbr_000000_000099.jpg").write_bytes(b"the user's photo")  # a name export would delete
    (elsewhere / "train_pbr").mkdir()
    before = _tree(elsewhere)
    target = dest / link
    if target.is_dir():
        import shutil

        shutil.rmtree(target)
    else:
        target.unlink()
    target.symlink_to(elsewhere / ("train_pbr" if link.count("/") == 1 else "train_pbr_000000_000099.jpg")
                      if "/" in link else elsewhere)
    rc, err = export(out, dest)
    assert rc == 2 and "symbolic link out of the output folder" in err and link.split("/")[-1] in err
    assert _tree(elsewhere) == before


def test_export_keeps_both_eyes_of_an_arrangement_in_one_split(tmp_path):
    out = bop_dataset(tmp_path / "out", arrangements=4, views=2, stereo=True)
    assert export(out, tmp_path / "dest", "--val-fraction", "0.5")[0] == 0
    split_of_arr: dict[int, set[str]] = {}
    for p in (tmp_path / "dest" / "labels").rglob("*.txt"):
        split_of_arr.setdefault(int(p.stem[-6:]) // 2, set()).add("val" if p.parent.name == "val" else "train")
    assert len(split_of_arr) == 4 and all(len(s) == 1 for s in split_of_arr.values())
    assert sum(s == {"val"} for s in split_of_arr.values()) == 2
    assert len(list((tmp_path / "dest" / "labels" / "val").iterdir())) == 8  # 2 arrangements x 2 views x 2 eyes


@pytest.mark.parametrize("arrangements, option", [(2, ("--val-fraction", "0.9")), (1, ("--val-fraction", "0.2")),
                                                   (2, ("--val", "train_pbr"))])
def test_export_that_leaves_nothing_to_train_on_is_refused_before_writing(tmp_path, arrangements, option):
    out = bop_dataset(tmp_path / "out", arrangements=arrangements)
    dest = tmp_path / "dest"
    rc, err = export(out, dest, *option)
    assert rc == 2 and "nothing is left to train on" in err
    assert not dest.exists()
    assert export(out, dest)[0] == 0


@pytest.mark.parametrize("value", ["-1", "2", "nan", "inf"])
def test_export_min_visib_must_be_a_fraction(tmp_path, value):
    rc, err = export(bop_dataset(tmp_path / "out"), tmp_path / "dest", f"--min-visib={value}")
    assert rc == 2 and "--min-visib" in err and not (tmp_path / "dest").exists()


def test_export_names_a_missing_rgb_file(tmp_path):
    out = bop_dataset(tmp_path / "out")
    (out / "bop" / "train_pbr" / "000000" / "rgb" / "000002.jpg").unlink()
    rc, err = export(out, tmp_path / "dest")
    assert rc == 2 and "000002" in err and "no RGB file" in err


def test_export_into_a_file_is_refused(tmp_path):
    (tmp_path / "dest").write_text("mine")
    rc, err = export(bop_dataset(tmp_path / "out"), tmp_path / "dest")
    assert rc == 2 and "is a file, not a folder" in err and (tmp_path / "dest").read_text() == "mine"


def test_export_does_not_quote_an_obj_id(tmp_path):
    out = bop_dataset(tmp_path / "out")
    gt = out / "bop" / "train_pbr" / "000000" / "scene_gt.json"
    gt.write_text(gt.read_text().replace('"obj_id": 1', '"obj_id": "SECRET"', 1))
    rc, err = export(out, tmp_path / "dest")
    assert rc == 2 and "obj_id must be a positive integer" in err and "SECRET" not in err


def test_an_export_that_stopped_half_way_can_be_redone(tmp_path):
    """An unreadable image stops an export before it writes anything; one interrupted after its
    first files (no data.yaml yet) is recognised as ours by its marker and done again."""
    out, dest = bop_dataset(tmp_path / "out"), tmp_path / "dest"
    bad = out / "bop" / "train_pbr" / "000000" / "rgb" / "000003.jpg"
    good = bad.read_bytes()
    bad.write_bytes(b"not a jpeg")
    rc, err = export(out, dest)
    assert rc == 2 and "000003.jpg" in err and not dest.exists()
    bad.write_bytes(good)
    assert export(out, dest) == (0, "")
    (dest / "data.yaml").unlink()  # as an export interrupted before its last file
    assert export(out, dest) == (0, "") and (dest / "data.yaml").is_file()


# --------------------------------------------------------------------------- 4. a failed rebuild


def _digest(out: Path) -> dict[str, bytes]:
    return {k: v for k, v in _tree(out).items() if not k.startswith(".specsynth/")}


def test_a_failed_rebuild_leaves_the_last_good_dataset(tmp_path):
    """The second build's scene file is gone by the time its arrangements run: every arrange job
    fails. The dataset of the first build stays byte for byte; a fixed rebuild then replaces it."""
    from specsynth.cli import main
    from specsynth.run.build import build

    spec = obj_scene(tmp_path)
    out = tmp_path / "out"
    assert main(["build", str(spec), "--out", str(out), "--quiet"]) == 0
    good = _digest(out)
    assert any(k.startswith("bop/") and k.endswith(".jpg") for k in good)
    (tmp_path / "scene2.yaml").write_text(SCENE.replace("name: s", "name: s2"))
    spec.write_text(SPEC.replace("file: scene.yaml", "file: scene2.yaml"))
    graph = compile_spec(load_spec(spec))
    (tmp_path / "scene2.yaml").rename(tmp_path / "gone.yaml")
    s = build(graph, out, jobs=1)
    assert s.failures and {f["stage"] for f in s.failures} == {"arrange"} and s.kept_previous
    assert _digest(out) == good
    assert json.loads((out / ".specsynth" / "failures.json").read_text()) == s.failures
    (tmp_path / "gone.yaml").rename(tmp_path / "scene2.yaml")
    again = build(compile_spec(load_spec(spec)), out, jobs=1)
    assert not again.failures and not again.kept_previous and _digest(out) != good
    assert not (out / ".specsynth" / "failures.json").exists()


# --------------------------------------------------------------------------- 10. useless specs


@pytest.mark.parametrize("override, field, says", [
    ("intrinsics.fx=1e-300", "intrinsics.fx", "it must lie in [0.5, 170]"),
    ("intrinsics.fy=1e9", "intrinsics.fy", "field of view"),
    ("intrinsics.distortion=[1e6, 0, 0, 0, 0]", "intrinsics.distortion", "squeezes"),
    ("sensor={depth: {axial_noise: [1e300, 1e300]}}", "sensor.depth.axial_noise", "above 1 (metres"),
])
def test_a_spec_that_would_build_nothing_useful_is_refused_in_validate(tmp_path, override, field, says):
    (pr,) = problems(obj_scene(tmp_path), override)
    assert pr.path == field and says in pr.message


def test_an_unknown_room_category_is_refused_in_validate(tmp_path):
    from specsynth.assets.library.furniture import LibraryError, catalogue

    try:
        catalogue()
    except LibraryError:
        pytest.skip("no furniture catalogue installed")
    (pr,) = problems(obj_scene(tmp_path), "scenes=[{name: random_room, room: {categories: [Kitchen, NoSuchCategory]}}]")
    assert pr.path == "scenes.0.room.categories.1" and "NoSuchCategory" in pr.message and "Kitchen" in pr.message


def test_a_build_that_writes_no_image_fails_and_keeps_the_last_good_dataset(tmp_path):
    """Cameras 30-40 m from a 2 m floor see nothing: every view is dropped."""
    from specsynth.cli import main

    spec = obj_scene(tmp_path)
    out = tmp_path / "out"
    assert main(["build", str(spec), "--out", str(out), "--quiet"]) == 0
    good = _digest(out)
    r = cli("build", spec, "--out", out, "--quiet", "--set", "cameras.distance=[30, 40]", timeout=300)
    assert r.returncode == 1 and "the build wrote no image" in r.stderr and "left as it was" in r.stderr, r.stderr
    assert _digest(out) == good
    r = cli("build", spec, "--out", tmp_path / "new", "--quiet", "--set", "cameras.distance=[30, 40]", timeout=300)
    assert r.returncode == 1 and "the build wrote no image" in r.stderr and "left as it was" not in r.stderr


# --------------------------------------------------------------------------- 11. small ones


def test_diff_skips_the_right_eyes_timings_too(tmp_path):
    from specsynth.run.verify import compare, write_index

    for side, seconds in (("a", b"1.25"), ("b", b"3.5")):
        (tmp_path / side / "parquet").mkdir(parents=True)
        (tmp_path / side / "parquet" / "images.parquet").write_bytes(b"same rows")
        for name in ("timings.parquet", "timings_right.parquet"):
            (tmp_path / side / "parquet" / name).write_bytes(b"seconds " + seconds)
        write_index(tmp_path / side)
    d = compare(tmp_path / "a", tmp_path / "b")
    assert d["differ"] == [] and d["only_in_a"] == d["only_in_b"] == [] and d["recorded"]


def _children(pid: int) -> list[str]:
    try:
        return Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    except OSError:
        return []


def _as_a_terminal_starts_it() -> None:
    """SIGINT at its default and unblocked in the child, as an interactive shell starts a command.
    In the full default suite (not in this file alone, nor in tests/ up to it) the build ran to
    its end with SIGINT sent at 0.8 s, three runs of three: the child had inherited SIGINT ignored
    or blocked from the test process; what left it so is not found yet (an in-process build
    restores both)."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})


@pytest.mark.skipif(not Path("/proc/self/task").is_dir(), reason="needs /proc to see the workers start")
def test_ctrl_c_of_a_build_with_workers_prints_no_traceback(tmp_path):
    """SIGINT to the whole process group, as a terminal's Ctrl-C sends it, while the pool's
    workers are still importing (where an interrupted worker printed its traceback)."""
    import signal
    import time

    spec = obj_scene(tmp_path)
    spec.write_text(SPEC.replace("count: 1", "count: 40"))
    p = subprocess.Popen([sys.executable, "-m", "specsynth.cli", "build", str(spec), "--out", str(tmp_path / "out"),
                          "--quiet", "--jobs", "2"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                         start_new_session=True, preexec_fn=_as_a_terminal_starts_it)
    t0 = time.monotonic()
    try:
        deadline = t0 + 120
        while len(_children(p.pid)) < 2 and time.monotonic() < deadline and p.poll() is None:
            time.sleep(0.05)
        seen = (_children(p.pid), round(time.monotonic() - t0, 2), p.poll())  # what the signal met
        time.sleep(0.3)
        os.killpg(p.pid, signal.SIGINT)
        _, err = p.communicate(timeout=120)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()
    assert p.returncode == 130 and "interrupted" in err, (p.returncode, seen, round(time.monotonic() - t0, 2), err[-400:])
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err


# --------------------------------------------------------------------------- the limits, at their edges


def test_gltf_geometry_may_reach_10_km_from_the_origin_and_no_further(tmp_path):
    _gltf(tmp_path / "s", nodes=_nodes({"name": "far", "mesh": 0, "translation": [9990, 0, 0]}))
    compile_spec(load_spec(_gltf_spec(tmp_path / "s")))
    _gltf(tmp_path / "s", nodes=_nodes({"name": "far", "mesh": 0, "translation": [10010, 0, 0]}))
    msg = one_message(_gltf_spec(tmp_path / "s"))
    assert "room.gltf: nodes[0] 'far'" in msg and "beyond the 10,000 m" in msg


def test_a_gltf_light_may_be_as_bright_as_1e7_and_no_brighter(tmp_path):
    _gltf(tmp_path / "s", nodes=_lit({"type": "spot", "intensity": 1e7}))
    compile_spec(load_spec(_gltf_spec(tmp_path / "s")))
    _gltf(tmp_path / "s", nodes=_lit({"type": "spot", "intensity": 1.01e7}))
    msg = one_message(_gltf_spec(tmp_path / "s"))
    assert "KHR_lights_punctual.lights[0]" in msg and "intensity must be a number in [0, 1e+07]" in msg


def test_a_cameras_field_of_view_lies_in_half_a_degree_to_170_degrees(tmp_path):
    import math

    spec = obj_scene(tmp_path)
    fx = lambda degrees: 64 / (2 * math.tan(math.radians(degrees) / 2))  # noqa: E731  (width 64)
    compile_spec(load_spec(spec, [f"intrinsics.fx={fx(169.9)}", f"intrinsics.fy={fx(90)}"]))
    compile_spec(load_spec(spec, [f"intrinsics.fx={fx(0.51)}"]))
    for degrees in (170.1, 0.49):
        (pr,) = problems(spec, f"intrinsics.fx={fx(degrees)}")
        assert pr.path == "intrinsics.fx" and "it must lie in [0.5, 170]" in pr.message


def test_depth_noise_coefficients_are_at_most_1(tmp_path):
    spec = obj_scene(tmp_path)
    compile_spec(load_spec(spec, ["sensor={depth: {axial_noise: [1.0, 1.0]}}"]))
    (pr,) = problems(spec, "sensor={depth: {axial_noise: [0.001, 1.5]}}")
    assert pr.path == "sensor.depth.axial_noise" and "above 1 (metres" in pr.message


# --------------------------------------------------------------------------- 12. the build's own index


# The merge writes into a staging folder three levels under the output folder (.specsynth/staging/new):
# five '..' after yolo/ reach the folder beside it; forty reach the root, whence any path.
@pytest.mark.parametrize("rel", ["yolo/../../../../../victim/precious.txt", "yolo/" + "../" * 40 + "{victim_abs}",
                                 "yolo/..//../../../../victim/precious.txt"])
def test_a_rebuild_deletes_nothing_an_edited_index_names_outside_its_folder(tmp_path, rel):
    """The index of a build's files (.specsynth/outputs.json) lives in the folder and travels with
    it: a path there that leads out of the folder (a '..', an absolute path) is data, never a file to
    delete as stale (a rebuild had deleted it, and the folder it emptied)."""
    from specsynth.cli import main

    spec = obj_scene(tmp_path)
    out = tmp_path / "out"
    assert main(["build", str(spec), "--out", str(out), "--quiet"]) == 0
    victim = tmp_path / "victim"
    victim.mkdir()
    (victim / "precious.txt").write_text("the user's")
    (out / "yolo").mkdir()  # a writer owns yolo/ and is off: its files in the index are stale
    index = out / ".specsynth" / "outputs.json"
    doc = json.loads(index.read_text())
    doc[rel.format(victim_abs=str(victim / "precious.txt").lstrip("/"))] = [1, 1, "0" * 64]
    index.write_text(json.dumps(doc))
    assert main(["build", str(spec), "--out", str(out), "--quiet"]) == 0
    assert (victim / "precious.txt").read_text() == "the user's"


@pytest.mark.parametrize("text", ["null", "[1, 2]", '{"bop/x.png": 5}', "[" * 100_000 + "]" * 100_000])
def test_a_damaged_index_is_read_as_none_and_the_rebuild_succeeds(tmp_path, text):
    """A build's index that is not the shape it writes (edited, damaged) is left out, as an index
    that cannot be read is: the rebuild hashes its files again (it had failed after all the work
    with "TypeError: 'NoneType' object is not iterable")."""
    from specsynth.cli import main
    from specsynth.run.verify import read_index

    spec = obj_scene(tmp_path)
    out = tmp_path / "out"
    assert main(["build", str(spec), "--out", str(out), "--quiet"]) == 0
    (out / ".specsynth" / "outputs.json").write_text(text)
    assert read_index(out) == {}
    r = cli("build", spec, "--out", out, "--quiet", "--set", "seed=3", timeout=300)
    assert r.returncode == 0, r.stderr
    assert read_index(out) and all(not rel.startswith("..") for rel in read_index(out))


# --------------------------------------------------------------------------- 13. stats and view write in their place


@pytest.fixture()
def built(tmp_path) -> Path:
    from specsynth.cli import main

    out = tmp_path / "out"
    assert main(["build", str(obj_scene(tmp_path)), "--out", str(out), "--quiet"]) == 0
    return out


def test_stats_writes_nothing_through_a_link_out_of_its_folder(built, tmp_path):
    victim = tmp_path / "victim.json"
    victim.write_text("the user's")
    dest = tmp_path / "st"
    dest.mkdir()
    (dest / "stats.json").symlink_to(victim)
    r = cli("stats", built, "--out", dest)
    assert r.returncode == 2 and "stats.json: a symbolic link out of the output folder" in r.stderr, r.stderr
    assert victim.read_text() == "the user's"
    (dest / "stats.json").unlink()
    r = cli("stats", built, "--out", dest)
    assert r.returncode == 0 and (dest / "stats.png").is_file() and json.loads((dest / "stats.json").read_text())["images"]
    for target, says in ((tmp_path / "st" / "stats.json", "a file, not a folder"), ("/dev/null", "character device")):
        r = cli("stats", built, "--out", target)
        assert r.returncode == 2 and says in r.stderr and "Traceback" not in r.stderr, r.stderr


def test_view_replaces_a_link_at_its_out_and_names_a_file_it_cannot_write(built, tmp_path):
    victim = tmp_path / "photo.png"
    victim.write_bytes(b"the user's photo")
    link = tmp_path / "sheet.png"
    link.symlink_to(victim)
    r = cli("view", built, "--out", link)
    assert r.returncode == 0, r.stderr
    assert victim.read_bytes() == b"the user's photo" and not link.is_symlink()
    assert link.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    os.mkfifo(tmp_path / "pipe.png")
    for target, says in (("sheet.txt", "give a file name ending in .png"), ("pipe.png", "FIFO"),
                         ("/dev/zero", "character device")):
        r = cli("view", built, "--out", tmp_path / target if "/" not in target else target)
        assert r.returncode == 2 and says in r.stderr and "Traceback" not in r.stderr, r.stderr


@pytest.mark.parametrize("what", ["link", "fifo"])
def test_export_copies_no_image_from_outside_the_dataset(tmp_path, what):
    """An image of the dataset that is a link out of it is refused before anything is written:
    export had copied the outside file into the export. A FIFO there is no image file."""
    out = bop_dataset(tmp_path / "out", arrangements=1, views=1)
    rgb = out / "bop" / "train_pbr" / "000000" / "rgb" / "000000.jpg"
    private = tmp_path / "private.jpg"
    private.write_bytes(rgb.read_bytes())
    rgb.unlink()
    rgb.symlink_to(private) if what == "link" else os.mkfifo(rgb)
    rc, err = export(out, tmp_path / "dest")
    assert rc == 2 and "000000.jpg" in err and ("a link out of the dataset folder" if what == "link" else "no RGB file") in err
    assert not (tmp_path / "dest").exists()


DEEP = "[" * 100_000 + "]" * 100_000  # past the JSON decoder's recursion limit


@pytest.mark.parametrize("file, command", [
    ("bop/train_pbr/000000/scene_gt.json", ("view", "{out}", "--out", "{tmp}/v.png")),
    ("bop/train_pbr/000000/scene_gt.json", ("export", "yolo", "{out}", "{tmp}/y")),
    ("bop/train_pbr/000000/scene_gt.json", ("compare", "{out}", "{out}", "--out", "{tmp}/c")),
    (".specsynth/manifest.json", ("diff", "{out}", "{out}")),
])
def test_a_dataset_json_nested_too_deep_is_named(built, tmp_path, file, command):
    """Every command reading a built dataset's JSON names the file it cannot read (a bare
    'RecursionError: maximum recursion depth exceeded' had named none)."""
    (built / file).write_text(DEEP)
    r = cli(*(c.format(out=built, tmp=tmp_path) for c in command))
    assert r.returncode in (1, 2) and file.split("/")[-1] in r.stderr and "Traceback" not in r.stderr, r.stderr


def test_a_models_info_nested_too_deep_is_located(tmp_path, lm_models):
    import shutil

    models = tmp_path / "models"
    shutil.copytree(lm_models, models)
    (models / "models_info.json").write_text(DEEP)
    (pr,) = problems(obj_scene(tmp_path / "s"), f"objects={{path: {models}}}")
    assert pr.path.startswith("objects") and "models_info.json" in pr.message


# --------------------------------------------------------------------------- 14. an object in the wrong unit


def test_an_object_in_the_wrong_unit_is_located_by_validate(tmp_path):
    """Its size says so before any work: a BOP folder whose models are in metres (its diameter,
    0.139 'mm', from models_info.json) and mesh files whose declared unit makes them 50 m or 0.14 mm
    across (the build had stopped in its arrange jobs, naming no field)."""
    import trimesh

    spec = obj_scene(tmp_path)
    bop = tmp_path / "models_m"
    bop.mkdir()
    trimesh.creation.box((0.08, 0.08, 0.08)).export(bop / "obj_000001.ply")  # metres, where BOP means mm
    (pr,) = problems(spec, "objects={path: models_m}")
    assert pr.path == "objects.path" and "obj_000001" in pr.message and "millimetres" in pr.message
    trimesh.creation.icosphere(radius=25.0).export(tmp_path / "ball_mm.stl")
    trimesh.creation.box((0.08, 0.08, 0.08)).export(tmp_path / "box_m.stl")
    (big, small) = problems(spec, "objects={meshes: [{path: ball_mm.stl, unit: m}, {path: box_m.stl, unit: mm}]}")
    assert big.path == "objects.meshes.0.unit" and "at least 50 m across with unit 'm'" in big.message
    assert small.path == "objects.meshes.1.unit" and "at most 0.0001386 m across with unit 'mm'" in small.message
    compile_spec(load_spec(spec, ["objects={meshes: [{path: ball_mm.stl, unit: mm}, {path: box_m.stl, unit: m}]}"]))


def test_objects_without_an_id_take_the_lowest_free_ids_in_order(tmp_path):
    """[can, block, ball (obj_id: 7)] is 1, 2, 7, as a BOP user numbers models (it had been 8, 9, 7)."""
    import trimesh

    from specsynth.assets.resolve import object_fingerprints, _sources
    from specsynth.spec.models import Objects

    for name in ("can", "block", "ball"):
        trimesh.creation.box((0.05, 0.05, 0.05)).export(tmp_path / f"{name}.stl")
    objects = Objects(meshes=[{"path": "can.stl", "unit": "m"}, {"path": "block.stl", "unit": "m"},
                              {"path": "ball.stl", "unit": "m", "obj_id": 7}])
    assert {s.path.name: s.obj_id for s in _sources(objects, tmp_path)} == {"can.stl": 1, "block.stl": 2, "ball.stl": 7}
    assert len(object_fingerprints(objects, tmp_path)) == 3
    objects = Objects(builtin=["duck", {"name": "mug", "obj_id": 1}], meshes=[{"path": "can.stl", "unit": "m"}])
    assert {s.name: s.obj_id for s in _sources(objects, tmp_path)} == {"duck": 2, "mug": 1, "obj_000003": 3}


# --------------------------------------------------------------------------- 15. scene files the arrange jobs could not use


FLOOR = "{name: floor, source: {box: [2, 2, 0.1]}, transform: {translation: [0, 0, -0.05]}}"
STAGE = "[{name: st, polygon: [[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]], height: 0.0}]"


@pytest.mark.parametrize("body, field, says", [
    (f"meshes: [{FLOOR}]\nstages: {STAGE}\nfocus: [{{polygon: [[0, 0], [0, 0], [0, 0]], height: 0}}]",
     "focus.0.polygon", "polygon has zero area"),
    (f"meshes: [{FLOOR}, {{name: c, source: {{tube: {{points: [[0, 0, 1], [0, 0, 1]], radius: 0.01}}}}}}]\nstages: {STAGE}",
     "meshes.1.source.tube.points", "two distinct points"),
    (f"meshes: [{FLOOR}, {{name: c, source: {{box: [1e300, 1e300, 0.1]}}}}]\nstages: {STAGE}",
     "meshes.1.source.box", "beyond 10000 m"),
    (f"meshes: [{FLOOR}]\nstages: {STAGE.replace('height: 0.0', 'height: 1e300')}", "stages.0.height", "10000"),
    (f"meshes: [{FLOOR}, {{name: c, source: {{box: [1, 1, 1]}}, transform: {{translation: [1e300, 0, 0]}}}}]\nstages: {STAGE}",
     "meshes.1.transform.translation", "beyond 10000 m"),
    ("stages: auto", "(top)", "this scene has none"),
])
def test_a_scene_file_the_arrange_jobs_could_not_use_is_located_by_validate(tmp_path, body, field, says):
    """Each had passed validate and failed every arrange job, some with a raw pydantic dump that
    quoted the file's values and named neither file nor line."""
    spec = obj_scene(tmp_path)
    (tmp_path / "scene.yaml").write_text(f"name: s\n{body}\n")
    (pr,) = problems(spec)
    lines = [line for line in pr.message.splitlines() if f": {field}: " in line]
    assert lines and "scene.yaml:" in lines[0] and says in lines[0], pr.message
    assert field == "(top)" or re.search(r"scene\.yaml:\d+:\d+: ", lines[0]), lines[0]


def _gltf_triangle(path: Path, indices: tuple[int, int, int]) -> Path:
    import base64

    data = struct.pack("<9f", 0, 0, 0, 0.05, 0, 0, 0, 0.05, 0) + struct.pack("<3I", *indices)
    path.write_text(json.dumps({
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [0.05, 0.05, 0]},
                      {"bufferView": 1, "componentType": 5125, "count": 3, "type": "SCALAR"}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}, {"buffer": 0, "byteOffset": 36, "byteLength": 12}],
        "buffers": [{"byteLength": 48, "uri": "data:application/octet-stream;base64," + base64.b64encode(data).decode()}]}))
    return path


def test_a_gltf_index_past_its_vertices_is_named(tmp_path):
    """A triangle's index 7 of 3 vertices: validate locates the object's mesh and `scenes show`
    names the file (both had failed with a bare 'IndexError: index 7 is out of bounds')."""
    bad = _gltf_triangle(tmp_path / "bad.gltf", (0, 1, 7))
    (pr,) = problems(obj_scene(tmp_path / "s"), f"objects={{meshes: [{{path: {bad}, unit: m}}]}}")
    assert pr.path == "objects.meshes.0.path" and "bad.gltf: face indices out of range (0..2" in pr.message
    r = cli("scenes", "show", bad, "--out", tmp_path / "top.png")
    assert r.returncode == 2 and "bad.gltf: face indices out of range" in r.stderr and "Traceback" not in r.stderr, r.stderr
    good = _gltf_triangle(tmp_path / "good.gltf", (0, 1, 2))
    compile_spec(load_spec(obj_scene(tmp_path / "s"), [f"objects={{meshes: [{{path: {good}, unit: m}}]}}"]))


def test_an_out_path_too_long_for_the_file_system_is_refused_before_any_work(tmp_path):
    """A folder name over 255 bytes, or a path leaving the build too little of the system's 4096
    bytes for its own files: named at once (the build had failed in its arrange jobs with 'File
    name too long')."""
    spec = obj_scene(tmp_path)
    r = cli("build", spec, "--out", tmp_path / ("x" * 300), "--quiet")
    assert r.returncode == 2 and "a folder name of 300 bytes, over the file system's 255" in r.stderr, r.stderr
    deep = tmp_path.joinpath(*["d" * 200] * 19)  # about 3.8 kB
    r = cli("build", spec, "--out", deep, "--quiet")
    assert r.returncode == 2 and "the files written under it need up to 512 more" in r.stderr, r.stderr
    assert not (tmp_path / ("d" * 200)).exists()


def test_a_bop_model_of_obj_id_0_is_located(tmp_path, lm_models):
    import shutil

    models = tmp_path / "models"
    shutil.copytree(lm_models, models)
    (models / "models_info.json").unlink()
    shutil.copy(models / "obj_000001.ply", models / "obj_000000.ply")
    (pr,) = problems(obj_scene(tmp_path / "s"), f"objects={{path: {models}}}")
    assert pr.path == "objects.path" and "obj_id 0 (obj_000000)" in pr.message and "start at 1" in pr.message


def test_verify_follows_no_link_out_of_the_dataset(built, tmp_path):
    """A dataset file swapped for a link to a copy outside: not read through the link (it had been
    hashed there and called unchanged), but reported as gone."""
    from specsynth.run.verify import verify

    rgb = next(built.rglob("rgb/*.jpg"))
    outside = tmp_path / "copy.jpg"
    outside.write_bytes(rgb.read_bytes())
    rgb.unlink()
    rgb.symlink_to(outside)
    rel = rgb.relative_to(built).as_posix()
    assert rel in verify(built)["missing"]


SECRET = "SECRET_VALUE_7f3a"
CHUNK = "bop/train_pbr/000000"


def _edit_json(path: Path, change) -> None:
    path.write_text(json.dumps(change(json.loads(path.read_text()))))


@pytest.mark.parametrize("damage, says", [
    (lambda c: _edit_json(c / "scene_gt.json", lambda d: {**d, SECRET: d["0"]}), "a key that is not an image id"),
    (lambda c: _edit_json(c / "scene_gt.json", lambda d: [SECRET]), "expected an object keyed by image id"),
    (lambda c: _edit_json(c / "scene_gt.json", lambda d: {**d, "00": d["0"]}), "a key that is not an image id"),
    (lambda c: (c / "scene_gt.json").write_text('{"0": [], "0": [{"obj_id": 1}]}'), "names one key twice"),
    (lambda c: _edit_json(c / "scene_gt_info.json", lambda d: {**d, "0": [{**d["0"][0], "bbox_visib": SECRET}]}),
     "bbox_visib must be a list of 4 numbers"),
    (lambda c: _edit_json(c / "scene_gt_info.json", lambda d: {**d, "0": [{**d["0"][0], "bbox_visib": [1, 2]}]}),
     "bbox_visib must be a list of 4 numbers"),
    (lambda c: (c / "scene_gt_info.json").write_text('{"0": [{"bbox_visib": [NaN, 1, 2, 3]}]}'), "bbox_visib"),
    (lambda c: _edit_json(c / "scene_gt_info.json", lambda d: {**d, "0": [{**d["0"][0], "visib_fract": SECRET}]}),
     "visib_fract: expected a number in [0, 1]"),
    (lambda c: _edit_json(c / "scene_gt_info.json", lambda d: {**d, "0": [{"visib_fract": 0.5}]}),
     "bbox_visib must be a list of 4 numbers"),
    (lambda c: _edit_json(c / "scene_camera.json", lambda d: {**d, "0": SECRET}), "every image's entry must be an object"),
    (lambda c: (c / "scene_camera.json").unlink() or os.mkfifo(c / "scene_camera.json"), "not a regular file"),
    (lambda c: (c / "scene_gt_info.json").unlink() or os.mkfifo(c / "scene_gt_info.json"), "not a regular file"),
    (lambda c: shutil.copytree(c, c.parent / "abc"), "a chunk folder is named by its number"),
    (lambda c: shutil.copytree(c, c.parent / "0"), "the same chunk number"),
])
@pytest.mark.parametrize("command", ["view", "export"])
def test_a_damaged_bop_table_is_named_by_view_and_export_before_any_work(tmp_path, damage, says, command):
    """view and export read a dataset's BOP tables as compare does: a FIFO does not hang them, a
    damaged entry is named by file and place (never quoted), before anything is drawn or copied."""
    out = bop_dataset(tmp_path / "out", arrangements=1, views=2)
    damage(out / CHUNK)
    dest = tmp_path / ("v.png" if command == "view" else "y")
    args = ("view", out, "--out", dest) if command == "view" else ("export", "yolo", out, dest)
    r = cli(*args, timeout=60)
    assert r.returncode == 2 and says in r.stderr and SECRET not in r.stderr and "Traceback" not in r.stderr, r.stderr
    assert not dest.exists()


def test_export_refuses_a_box_outside_its_image_before_writing(tmp_path):
    out = bop_dataset(tmp_path / "out", arrangements=1, views=2)
    _edit_json(out / CHUNK / "scene_gt_info.json", lambda d: {**d, "1": [{**d["1"][0], "bbox_visib": [0, 0, 10**6, 10**6]}]})
    rc, err = export(out, tmp_path / "y")
    assert rc == 2 and "image 1, annotation 0: bbox_visib lies outside its 32 x 24 image" in err, err
    assert not (tmp_path / "y").exists()


@pytest.mark.parametrize("categories", [[SECRET], [{"id": SECRET, "name": "x"}], [{"name": "x"}], SECRET])
def test_export_names_coco_categories_it_cannot_use(tmp_path, categories):
    out = bop_dataset(tmp_path / "out", arrangements=1, views=1)
    (out / "coco").mkdir()
    (out / "coco" / "train_pbr.json").write_text(json.dumps({"categories": categories}))
    rc, err = export(out, tmp_path / "y")
    assert rc == 2 and "train_pbr.json: categories must be a list" in err and SECRET not in err, err


def test_view_refuses_images_and_masks_from_outside_the_dataset(tmp_path):
    out = bop_dataset(tmp_path / "out", arrangements=1, views=1)
    outside = tmp_path / "outside"
    shutil.move(out / CHUNK / "rgb", outside)
    (out / CHUNK / "rgb").symlink_to(outside)
    r = cli("view", out, "--out", tmp_path / "v.png", timeout=60)
    assert r.returncode == 2 and "a link out of the dataset folder" in r.stderr and not (tmp_path / "v.png").exists()


def test_stats_and_diff_name_tables_they_cannot_use(built, tmp_path):
    import pyarrow as pa
    import pyarrow.parquet as pq

    images = built / "parquet" / "images.parquet"
    table = pq.read_table(images)
    pq.write_table(table.drop(["R_w2c"]), images)
    r = cli("stats", built, "--out", tmp_path / "s1", timeout=60)
    assert r.returncode == 2 and "images.parquet: no column 'R_w2c'" in r.stderr, r.stderr
    pq.write_table(table.slice(0, 0), images)
    r = cli("stats", built, "--out", tmp_path / "s2", timeout=60)
    assert r.returncode == 2 and "no images to plot" in r.stderr, r.stderr
    pq.write_table(table.set_column(table.schema.get_field_index("R_w2c"), "R_w2c",
                                    pa.array([[1.0, 2.0]] * len(table))), images)
    r = cli("stats", built, "--out", tmp_path / "s3", timeout=60)
    assert r.returncode == 2 and "column 'R_w2c': expected lists of 9 numbers" in r.stderr, r.stderr
    manifest = built / ".specsynth" / "manifest.json"
    for bad in (["x"], {"x": 1}, {"stage_inputs": [], "jobs": {}}, {"stage_inputs": {}, "jobs": SECRET}):
        manifest.write_text(json.dumps(bad))
        r = cli("diff", built, built, timeout=60)
        assert r.returncode == 2 and "not a manifest specsynth wrote" in r.stderr and SECRET not in r.stderr, r.stderr


def test_compare_and_fit_refuse_an_output_under_a_file_before_measuring(tmp_path):
    (tmp_path / "afile").write_text("x")
    spec = Path(__file__).resolve().parents[1] / "specs" / "lmo_bl.yaml"
    for args in (("compare", "dataset:lmo/test", "dataset:lmo/test", "--out", tmp_path / "afile" / "sub"),
                 ("fit", "dataset:lmo/test", spec, "-o", tmp_path / "afile" / "x.yaml", "--probe-images", "0")):
        r = cli(*args, timeout=60)
        assert r.returncode == 2 and "is a file, not a folder" in r.stderr and "computing" not in r.stderr, r.stderr
