"""Guards on huge or wrong input, refused by `validate` before any work (issue: hardening)."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from specsynth.plan.compiler import compile_spec
from specsynth.spec.yamlio import SpecError, load_spec

SPEC = """\
name: g
objects: {builtin: [duck]}
scenes:
  - name: room
backend: {name: photo}
"""


def _problems(tmp_path, text, *overrides):
    f = tmp_path / "s.yaml"
    f.write_text(text)
    with pytest.raises(SpecError) as e:
        compile_spec(load_spec(f, list(overrides)))
    return e.value.problems


def test_huge_image_is_refused_with_its_estimate(tmp_path, monkeypatch):
    (pr,) = _problems(tmp_path, SPEC, "intrinsics={width: 16384, height: 16384, fx: 9000, fy: 9000, cx: 8191.5, cy: 8191.5}")
    assert pr.path == "intrinsics.width" and "needs about 50.0 GiB per worker" in pr.message
    assert "over the limit of 8.0 GiB (set SPECSYNTH_MAX_WORKER_GB" in pr.message
    monkeypatch.setenv("SPECSYNTH_MAX_WORKER_GB", "100")  # overridable
    f = tmp_path / "s.yaml"
    compile_spec(load_spec(f, ["intrinsics={width: 16384, height: 16384, fx: 9000, fy: 9000, cx: 8191.5, cy: 8191.5}"]))


def test_huge_plan_is_refused(tmp_path):
    (pr,) = _problems(tmp_path, SPEC, "arrangements.count=10000000", "cameras.per_arrangement=100")
    assert pr.path == "arrangements.count" and "1,000,000,000 images planned" in pr.message
    assert "over the limit of 100,000,000 (set SPECSYNTH_MAX_IMAGES" in pr.message


def test_password_file_as_scene_mesh_is_refused_without_echo(tmp_path):
    (tmp_path / "scene.yaml").write_text("name: pw\nmeshes:\n  - name: floor\n    source: passwd.ply\n"
                                         "stages:\n  - {name: floor, polygon: [[-1, -1], [1, -1], [1, 1], [-1, 1]], height: 0}\n")
    (tmp_path / "passwd.ply").write_text("root:x:0:0:root:/root:/bin/bash\n")
    (pr,) = _problems(tmp_path, SPEC.replace("  - name: room\n", "  - file: scene.yaml\n"))
    assert "does not start like a PLY file" in pr.message and "root:x" not in pr.message
    (tmp_path / "scene.yaml").write_text((tmp_path / "scene.yaml").read_text().replace("passwd.ply", "/etc/passwd"))
    (pr,) = _problems(tmp_path, SPEC.replace("  - name: room\n", "  - file: scene.yaml\n"))
    assert "not a mesh file by its name" in pr.message and "root:" not in pr.message


def test_missing_or_empty_backgrounds_folder_is_located(tmp_path):
    (tmp_path / "empty").mkdir()
    (pr,) = _problems(tmp_path, SPEC.replace("{name: photo}", "{name: photo, backgrounds: empty}"))
    assert (pr.line, pr.path) == (5, "backend.backgrounds") and "holds no files" in pr.message
    (pr,) = _problems(tmp_path, SPEC.replace("{name: photo}", "{name: photo, backgrounds: nowhere}"))
    assert pr.path == "backend.backgrounds" and "not found" in pr.message
    (tmp_path / "empty" / "README.txt").write_text("no photographs here")  # each render job had failed on it
    (pr,) = _problems(tmp_path, SPEC.replace("{name: photo}", "{name: photo, backgrounds: empty}"))
    assert (pr.line, pr.path) == (5, "backend.backgrounds") and "holds no photographs (jpg/jpeg/png)" in pr.message


def test_a_broken_or_huge_photograph_in_the_backgrounds_folder_is_located_before_any_job(tmp_path):
    """validate reads each photograph's header (not its pixels): a corrupt one, or one claiming too
    many pixels, is named at the spec's line instead of failing the render job that draws it."""
    import struct
    import zlib

    from PIL import Image

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    photos = tmp_path / "photos"
    photos.mkdir()
    Image.new("RGB", (8, 8), (90, 90, 90)).save(photos / "good.jpg")
    (photos / "notes.txt").write_text("not a photo: ignored")
    (photos / "broken.jpg").write_bytes(b"SECRET" * 20)
    spec = SPEC.replace("{name: photo}", "{name: photo, backgrounds: photos}")
    (pr,) = _problems(tmp_path, spec)
    assert (pr.line, pr.path) == (5, "backend.backgrounds") and "broken.jpg" in pr.message and "SECRET" not in pr.message
    (photos / "broken.jpg").unlink()
    ihdr = struct.pack(">IIBBBBB", 60000, 60000, 8, 2, 0, 0, 0)
    (photos / "huge.png").write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr)
                                      + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b""))
    (pr,) = _problems(tmp_path, spec)
    assert pr.path == "backend.backgrounds" and "huge.png" in pr.message and "pixel" in pr.message
    (photos / "huge.png").unlink()
    ihdr = struct.pack(">IIBBBBB", 9000, 9000, 8, 2, 0, 0, 0)  # over a texture's limit, within a photo's
    (photos / "large.png").write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr)
                                       + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b""))
    f = tmp_path / "s.yaml"
    compile_spec(load_spec(f))  # the good photo, the large one and the note pass


def test_collision_hull_of_a_huge_mesh_is_bounded():
    """Not refused: the hull of a huge mesh is computed from 200,000 of its vertices, with a warning."""
    from specsynth.physics import _convex_hull_vertices

    rng = np.random.default_rng(0)
    pts = rng.normal(size=(600_000, 3))
    pts /= np.linalg.norm(pts, axis=1, keepdims=True)  # a sphere: every point is on the hull
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        hull = _convex_hull_vertices(pts)
    assert [str(w.message) for w in caught if "collision hull" in str(w.message)] == [
        "collision hull of 600,000 vertices computed from 200,000 of them"]
    assert len(hull) <= 200_000 + 14
    assert np.allclose(hull.min(0), pts.min(0)) and np.allclose(hull.max(0), pts.max(0))  # extent kept
