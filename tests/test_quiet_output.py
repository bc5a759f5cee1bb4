"""Quiet, honest output: real tiny builds in child processes, their terminal output read back.

Library warnings (numpy, trimesh, the asset readers', Blender's CUDA wrangler, pybullet's banner)
never reach the terminal raw: each becomes one note that says what it means, or is silenced with
the reason in the code. ``--quiet`` and ``--verbose`` change how much is said; a build that writes no
image fails and says why.
"""

from __future__ import annotations

import logging
import os
import re
import subprocess
import sys
import warnings
from pathlib import Path

import pytest

from specsynth import notices

ROOT = Path(__file__).resolve().parents[1]
# A 160 x 120 camera with its intrinsics scaled to match (LM-O's, / 4).
SMALL = ["--set", "intrinsics.width=160", "--set", "intrinsics.height=120", "--set", "intrinsics.fx=143.1",
         "--set", "intrinsics.fy=143.4", "--set", "intrinsics.cx=81.3", "--set", "intrinsics.cy=60.5",
         "--set", "cameras.per_arrangement=2"]
RAW = ("Warning", "WARNING", "RuntimeWarning", "pybullet build time", "CUEW", "Traceback")


def specsynth(*args: str, cache: Path | None = None, timeout: float = 600) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYOPENGL_PLATFORM="egl")
    if cache is not None:
        env["SPECSYNTH_CACHE"] = str(cache)
    return subprocess.run([sys.executable, "-m", "specsynth.cli", *args], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=timeout)


@pytest.fixture()
def fresh_cache(tmp_path) -> Path:
    """A cache with no converted meshes and no unpacked furniture (so every library model is read
    and converted again, with whatever its files lack), that sees the installed asset sets."""
    from specsynth.assets.library.cache import cache_dir

    real = cache_dir()
    c = tmp_path / "cache"
    (c / "library").mkdir(parents=True)
    for name in ("robosuite-textures", "pmndrs", "printed"):
        if (real / "library" / name).exists():
            (c / "library" / name).symlink_to(real / "library" / name)
    (c / "datasets").symlink_to(real / "datasets")
    return c


def raw_lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if any(w in line for w in RAW)]


def test_a_tiny_photo_build_prints_no_raw_library_warning(tmp_path, fresh_cache):
    r = specsynth("build", "specs/demo_bl.yaml", "--out", str(tmp_path / "out"), *SMALL,
                  "--set", "arrangements.count=2", cache=fresh_cache)
    assert r.returncode == 0, r.stderr[-2000:]
    assert raw_lines(r.stderr) == [] and raw_lines(r.stdout) == []
    assert "images written: 4" in r.stdout
    # Whatever is said after the progress bars is a note in a sentence, not a library's line.
    after = r.stderr.rsplit("ETA", 1)[-1].splitlines()[1:]
    assert all(line.startswith("note: ") for line in after if line.strip()), after


def _object_with_a_missing_texture(folder: Path) -> Path:
    """A user's PLY whose header names a texture file that is not there -> a spec dropping it."""
    folder.mkdir(parents=True)
    v = [(x, y, z) for x in (-0.04, 0.04) for y in (-0.03, 0.03) for z in (0.0, 0.05)]
    faces = [(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1), (2, 3, 7), (2, 7, 6),
             (0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3)]
    lines = ["ply", "format ascii 1.0", "comment TextureFile paint.png", f"element vertex {len(v)}",
             "property float x", "property float y", "property float z", f"element face {len(faces)}",
             "property list uchar int vertex_indices", "end_header",
             *(f"{x} {y} {z}" for x, y, z in v), *(f"3 {a} {b} {c}" for a, b, c in faces)]
    (folder / "box.ply").write_text("\n".join(lines) + "\n")
    spec = (ROOT / "specs" / "demo_bl.yaml").read_text().replace(
        "  builtin: [duck, mug, teddy, lego, jenga, torus]",
        f"  builtin: [duck, mug]\n  meshes: [{{path: {folder / 'box.ply'}, unit: m}}]")
    spec = re.sub(r"scenes:\n(?:  .*\n)+", "scenes:\n  - name: room\n", spec)  # the demo's rooms -> one fixed room
    out = folder / "spec.yaml"
    out.write_text(spec)
    return out


def test_a_users_missing_texture_is_said_once_in_a_sentence(tmp_path):
    spec = _object_with_a_missing_texture(tmp_path / "mine")
    r = specsynth("build", str(spec), "--out", str(tmp_path / "out"), *SMALL, "--set", "arrangements.count=2",
                  "--set", "arrangements.distractors.count=[0,0]")
    assert r.returncode == 0, r.stderr[-2000:]
    assert raw_lines(r.stderr) == []
    said = [line for line in r.stderr.splitlines() if "paint.png named in the PLY header is missing" in line]
    assert len(said) == 1 and said[0].startswith("note: ") and "using a plain material" in said[0], r.stderr[-2000:]
    # --verbose: a line per finished job, and the message with its category
    r = specsynth("-v", "build", str(spec), "--out", str(tmp_path / "out2"), *SMALL, "--set", "arrangements.count=1",
                  "--set", "arrangements.distractors.count=[0,0]")
    assert r.returncode == 0, r.stderr[-2000:]
    assert "arrange arr=000000: " in r.stderr and "view arr=000000: " in r.stderr
    assert "render arr=000000/cam=000: " in r.stderr
    assert any(line.startswith("UserWarning: ") and "paint.png named in the PLY header is missing" in line
               for line in r.stderr.splitlines())


def test_quiet_prints_errors_and_the_summary_only(tmp_path):
    r = specsynth("--quiet", "build", "specs/demo_bl.yaml", "--out", str(tmp_path / "out"), *SMALL,
                  "--set", "arrangements.count=1")
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stderr == ""
    assert "images written: 2" in r.stdout
    r = specsynth("--quiet", "validate", "specs/demo_bl.yaml", "--set", "intrinsics.width=160")
    assert r.returncode == 0 and r.stderr == "" and r.stdout.strip() == "specs/demo_bl.yaml: ok"


def test_a_build_that_writes_no_image_fails_and_says_why(tmp_path):
    # width and height changed, the principal point left at (325, 242): every camera looks past its object
    r = specsynth("build", "specs/demo_bl.yaml", "--out", str(tmp_path / "out"), "--set", "intrinsics.width=160",
                  "--set", "intrinsics.height=120", "--set", "arrangements.count=1",
                  "--set", "cameras.per_arrangement=1")
    assert r.returncode == 1
    assert "images written: 0" in r.stdout
    err = [line for line in r.stderr.splitlines() if line.startswith("error: ")]
    assert len(err) == 1 and "the build wrote no image: every camera was rejected" in err[0]
    assert "principal point (cx, cy) = (325.261, 242.049) lies outside the 160 x 120 image" in err[0]
    assert raw_lines(r.stderr) == []
    # validate already says so, as a note
    r = specsynth("validate", "specs/demo_bl.yaml", "--set", "intrinsics.width=160", "--set", "intrinsics.height=120")
    assert r.returncode == 0 and "note: intrinsics: the principal point" in r.stderr


def test_notices_are_collected_and_summarised_by_what_they_mean():
    lib = "/home/u/.cache/specsynth/library/sh3d/Contributions/x/{}.obj"
    with notices.Collector() as c:
        for i in range(3):
            warnings.warn(f"{lib.format(i)}: material 'm': base colour texture t{i}.jpg is missing; using Kd")
        warnings.warn(f"{lib.format(0)}: material 'm': base colour texture t0.jpg is missing; using Kd")  # again
        warnings.warn(f"{lib.format(5)}: material 'w' has textures but its faces have no UVs; using its colours")
        warnings.warn("mine/box.obj: material 'p': base colour texture p.png is missing; using Kd")
        warnings.warn("Mean of empty slice", RuntimeWarning)
        logging.getLogger("trimesh").warning("face_normals didn't match triangles, ignoring!")
    assert len(c.notices) == 8
    assert {n.source for n in c.notices} == {"UserWarning", "RuntimeWarning", "log:trimesh"}
    assert notices.summarise(c.notices) == [
        "3 library furniture textures are missing; their materials use their base colour",
        "1 library furniture material has textures but no texture coordinates; they use their plain colour",
        "1 numerical warning from a library (e.g. a statistic over no values); run with --verbose to see them",
        "mine/box.obj: material 'p': base colour texture p.png is missing; using Kd",
        "1 warning logged by trimesh while reading files; run with --verbose to see them",
    ]
    # outside a collector, warnings and logging are as they were
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        warnings.warn("after", UserWarning)
    assert [str(x.message) for x in w] == ["after"]
    assert logging.getLogger("trimesh").propagate is True
