"""Broken specs: each gives a clean, located error (FILE:LINE:COL: field: message), exit 2, no traceback."""

from __future__ import annotations

import subprocess
import sys

import pytest

from specsynth.spec.yamlio import SpecError, load_spec

BASE = """\
name: t
objects:
  builtin: [duck]
scenes:
  - name: room
backend:
  name: photo
"""

# (id, spec text, expected line or None, expected field path, expected message fragment)
CASES = [
    ("unknown-top-key", BASE + "colour: red\n", 8, "colour", "unknown field"),
    ("unknown-nested-key", BASE + "cameras:\n  distanse: [0.5, 1]\n", 9, "cameras.distanse", "unknown field"),
    ("null-key", BASE + "null: 1\n", 8, "None", "Keys should be strings"),
    ("tilde-key", BASE + "cameras:\n  ~: 1\n", 9, "cameras.None", "Keys should be strings"),
    ("hex-key", BASE + "0x10: 1\n", 8, "16", "Keys should be strings"),
    ("unknown-backend-option", "name: t\nobjects:\n  builtin: [duck]\nscenes:\n  - name: room\nbackend:\n  name: cycles\n  sampels: 4\n", 8, "backend.sampels", "unknown field"),
    ("missing-name", BASE.replace("name: t\n", ""), None, "name", "Field required"),
    ("missing-backend", BASE.replace("backend:\n  name: photo\n", ""), None, "backend", "Field required"),
    ("bad-name-chars", BASE.replace("name: t", "name: 'a b'"), 1, "name", "pattern"),
    ("wrong-type-seed", BASE + "seed: abc\n", 8, "seed", "integer"),
    ("negative-seed", BASE + "seed: -1\n", 8, "seed", "greater than or equal"),
    ("nan-threshold", BASE + "visibility:\n  threshold: .nan\n", 9, "visibility.threshold", "finite"),
    ("inf-distance", BASE + "cameras:\n  distance: [0.5, .inf]\n", 9, "cameras.distance", "finite"),
    ("reversed-range", BASE + "cameras:\n  distance: [2.0, 1.0]\n", 9, "cameras.distance", "min (2.0) must be <= max (1.0)"),
    ("zero-distance", BASE + "cameras:\n  distance: [0, 1.0]\n", 9, "cameras.distance", ">= 0.02"),
    ("elevation-out-of-range", BASE + "cameras:\n  elevation: [10, 95]\n", 9, "cameras.elevation", "<= 90"),
    ("range-wrong-length", BASE + "cameras:\n  azimuth: [0, 90, 180]\n", 9, "cameras.azimuth", "at most 2"),
    ("threshold-above-one", BASE + "visibility:\n  threshold: 1.5\n", 9, "visibility.threshold", "less than or equal to 1"),
    ("bad-quality-level", BASE + "quality:\n  level: ultra\n", 9, "quality.level", "'low', 'medium', 'high', 'paper_low'"),
    ("bad-quality-override", BASE + "quality:\n  presets:\n    high: {aa: 0}\n", 10, "quality.presets.high.aa", "greater than or equal to 1"),
    ("no-objects", BASE.replace("  builtin: [duck]\n", "  instances: [1, 2]\n"), 2, "objects", "no objects"),
    ("ids-without-path", BASE.replace("  builtin: [duck]\n", "  builtin: [duck]\n  ids: [1, 2]\n"), 2, "objects", "set 'path' too"),
    ("empty-scenes", BASE.replace("scenes:\n  - name: room\n", "scenes: []\n"), 4, "scenes", "at least 1"),
    ("scene-two-sources", BASE.replace("  - name: room\n", "  - name: room\n    file: x.yaml\n"), 5, "scenes.0", "exactly one"),
    ("instances-reversed", BASE.replace("  builtin: [duck]\n", "  builtin: [duck]\n  instances: [3, 1]\n"), 4, "objects.instances", "min (3) must be <= max (1)"),
    ("orientation-typo", BASE.replace("  builtin: [duck]\n", "  builtin: [duck]\n  orientation: upright\n"), 4, "objects.orientation", "'canonical' or 'random'"),
    ("material-colour-range", BASE.replace("  builtin: [duck]\n", "  builtin: [duck]\n  materials:\n    duck: {color: [2, 0, 0]}\n"), 5, "objects.materials.duck.color", "[0, 1]"),
    ("image-size-zero", BASE + "intrinsics:\n  width: 0\n", 9, "intrinsics.width", "greater than or equal to 8"),
    ("depth-scale-negative", BASE + "outputs:\n  depth_scale: -1\n", 9, "outputs.depth_scale", "depth_scale"),
    ("image-format", BASE + "outputs:\n  image_format: bmp\n", 9, "outputs.image_format", "'jpg' or 'png'"),
    ("drop-height-negative", BASE + "arrangements:\n  drop_height: [-0.1, 0.5]\n", 9, "arrangements.drop_height", ">= 0"),
    ("arrangements-zero", BASE + "arrangements:\n  count: 0\n", 9, "arrangements.count", "greater than or equal to 1"),
    ("mesh-without-unit", BASE.replace("  builtin: [duck]\n", "  meshes:\n    - path: a.ply\n"), 4, "objects.meshes.0.unit", "Field required"),
    ("version-2", BASE + "version: 2\n", 8, "version", "1"),
    ("bool-as-count", BASE + "cameras:\n  per_arrangement: true\n", 9, "cameras.per_arrangement", "expected a number, got true"),
    ("bool-as-seed", BASE + "seed: false\n", 8, "seed", "expected a number, got false"),
    ("split-too-long", BASE + "split: " + "a" * 300 + "\n", 8, "split", "at most 64"),
    ("distance-inside-object", BASE + "cameras:\n  distance: [0.000001, 1.0]\n", 9, "cameras.distance", ">= 0.02"),
    ("depth-scale-absurd", BASE + "outputs:\n  depth_scale: 1.0e+300\n", 9, "outputs.depth_scale", "[0.001, 1000]"),
    ("photo-lights-reversed", BASE.replace("  name: photo\n", "  name: photo\n  lights: [3, 1]\n"), 8, "backend.lights", "min (3) must be <= max (1)"),
]

DOC_CASES = [
    ("empty-file", "", 1, "", "spec is empty"),
    ("only-comments", "# nothing here\n", 1, "", "spec is empty"),
    ("top-level-list", "- a\n- b\n", 1, "", "top level must be a mapping, got list"),
    ("top-level-scalar", "hello\n", 1, "", "top level must be a mapping, got str"),
    ("yaml-syntax", "name: t\nobjects: [\n", 3, "", "YAML syntax error"),
    ("bad-indent", "name: t\n objects: 1\n", 2, "", "YAML syntax error"),
    ("tab-indent", "name: t\nobjects:\n\tbuiltin: [duck]\n", 3, "", "YAML syntax error"),
    ("duplicate-key", BASE + "name: u\n", 8, "name", "duplicate key 'name'"),
    ("python-tag", BASE + "seed: !!python/object:os.system ls\n", 8, "", "YAML syntax error"),
    (
        "alias-bomb",
        "a: &a [x, x, x, x, x, x, x, x, x, x]\nb: &b [*a, *a, *a, *a, *a, *a, *a, *a, *a, *a]\n"
        "c: &c [*b, *b, *b, *b, *b, *b, *b, *b, *b, *b]\nd: &d [*c, *c, *c, *c, *c, *c, *c, *c, *c, *c]\n"
        "e: &e [*d, *d, *d, *d, *d, *d, *d, *d, *d, *d]\nf: [*e, *e, *e, *e, *e, *e, *e, *e, *e, *e]\n",
        1, "", "alias bomb",
    ),
]


def _problems(tmp_path, text: str, overrides=()):
    f = tmp_path / "spec.yaml"
    f.write_text(text)
    with pytest.raises(SpecError) as ei:
        load_spec(f, overrides)
    return f, ei.value.problems


@pytest.mark.parametrize("case", CASES + DOC_CASES, ids=[c[0] for c in CASES + DOC_CASES])
def test_broken_spec_is_located(tmp_path, case):
    _, text, line, path, fragment = case
    f, problems = _problems(tmp_path, text)
    match = [p for p in problems if (p.path == path or p.path.startswith(path + ".")) and fragment in p.message]
    assert match, f"expected {path!r} ~ {fragment!r}, got {[str(p) for p in problems]}"
    p = match[0]
    assert p.file == str(f)
    if line is not None:
        assert p.line == line, str(p)
        assert p.col is not None and p.col >= 1
    assert str(p).startswith(f"{f}:{p.line}:{p.col}: " if p.line else f"{f}: ")


def test_all_problems_reported_at_once(tmp_path):
    _, problems = _problems(tmp_path, BASE + "seed: x\ncameras:\n  distance: [2, 1]\n  bogus: 1\n")
    assert {p.path for p in problems} >= {"seed", "cameras.distance", "cameras.bogus"}


def test_override_errors_are_located_at_the_override(tmp_path):
    _, problems = _problems(tmp_path, BASE, ["cameras.distance=[3,1]"])
    assert problems[0].file == "--set cameras.distance"
    assert "min (3.0) must be <= max (1.0)" in problems[0].message


def test_override_applies_and_validates(tmp_path):
    f = tmp_path / "spec.yaml"
    f.write_text(BASE)
    loaded = load_spec(f, ["cameras.distance=[0.5, 0.9]", "backend.name=cycles", "scenes.0.name=kiva", "seed=5"])
    assert loaded.spec.cameras.distance == (0.5, 0.9)
    assert loaded.spec.backend.name == "cycles"
    assert loaded.spec.scenes[0].name == "kiva"
    assert loaded.spec.seed == 5


def test_bad_override_syntax(tmp_path):
    _, problems = _problems(tmp_path, BASE, ["cameras.distance"])
    assert "expected dotted.path=value" in problems[0].message


def test_missing_file_is_clean(tmp_path):
    with pytest.raises(SpecError) as ei:
        load_spec(tmp_path / "nope.yaml")
    assert "no such file" in str(ei.value)


@pytest.mark.parametrize("text,fragment", [
    (BASE + "cameras:\n  distance: [2, 1]\n", ":9:"),
    ("- just\n- a list\n", "top level must be a mapping"),
    ("name: [\n", "YAML syntax error"),
])
def test_cli_validate_exit_2_without_traceback(tmp_path, text, fragment):
    f = tmp_path / "bad.yaml"
    f.write_text(text)
    r = subprocess.run([sys.executable, "-m", "specsynth.cli", "validate", str(f)], capture_output=True, text=True)
    assert r.returncode == 2
    assert fragment in r.stderr
    assert "Traceback" not in r.stderr + r.stdout


def test_numeric_material_keys_are_located_and_accepted(tmp_path):
    text = BASE.replace("  builtin: [duck]\n", "  builtin: [duck]\n  materials:\n    default: {roughness: 0.5}\n    5: {roughness: 2.0}\n")
    f, problems = _problems(tmp_path, text)
    assert [(p.line, p.path) for p in problems] == [(6, "objects.materials.5.roughness")]
    f.write_text(text.replace("roughness: 2.0", "roughness: 0.2"))
    assert set(load_spec(f, ["objects.materials.7.roughness=0.3"]).spec.objects.materials) == {"default", "5", "7"}


def test_union_errors_name_the_field_once(tmp_path):
    _, problems = _problems(tmp_path, BASE + "outputs:\n  depth_scale: nope\n")
    assert [(p.line, p.path) for p in problems] == [(9, "outputs.depth_scale")]
    assert "'auto'" in problems[0].message


def test_error_on_the_parent_of_an_override_points_at_the_override(tmp_path):
    _, problems = _problems(tmp_path, BASE + "cameras:\n  distance: [0.5, 1.0]\n", ["cameras.distance.0=2.0"])
    assert problems[0].file == "--set cameras.distance.0" and problems[0].path == "cameras.distance"


def test_validate_refuses_devices_and_huge_files_quickly(tmp_path):
    """`specsynth validate /dev/zero` read forever; a 50 MB list filled memory first."""
    big = tmp_path / "big.yaml"
    big.write_bytes(b"name: t\nobjects: [" + b"1, " * (5 << 20) + b"]\n")
    for path, message in (("/dev/zero", "not a regular file"), (str(big), "over the 4,194,304-byte limit for a spec")):
        with pytest.raises(SpecError) as e:  # (before the fix, /dev/zero never returned)
            load_spec(path)
        assert message in str(e.value.problems[0])
