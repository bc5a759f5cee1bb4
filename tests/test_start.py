"""The first commands a user runs: ``specsynth init``, ``specsynth doctor``, ``specsynth --version``.

Real commands on real files: the starter spec is written and validated by the same command line a
user types; doctor runs in a child process on this machine's real installation.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from importlib import metadata
from pathlib import Path

import pytest
import yaml

from specsynth.cli import main

ROOT = Path(__file__).resolve().parents[1]


def cli(*args: str, cwd: Path = ROOT, env: dict | None = None, timeout: float = 600) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "specsynth.cli", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=timeout, env=dict(os.environ, PYOPENGL_PLATFORM="egl", **(env or {})))


# --------------------------------------------------------------------------- init


def test_init_writes_a_commented_starter_spec_that_validates(tmp_path, capsys):
    folder = tmp_path / "first"
    assert main(["init", str(folder)]) == 0
    spec = folder / "spec.yaml"
    assert f"wrote {spec}" in capsys.readouterr().out
    text = spec.read_text()
    comments = [line for line in text.splitlines() if "#" in line]
    assert len(comments) >= 20  # every block says what it does
    data = yaml.safe_load(text)
    assert data["name"] == "first" and data["objects"]["builtin"] and data["scenes"] == [{"name": "random_room"}]
    assert data["backend"]["name"] in ("cycles", "mitsuba", "photo")
    assert main(["validate", str(spec)]) == 0
    assert capsys.readouterr().out.strip() == f"{spec}: ok"


def test_init_never_overwrites_a_file(tmp_path, capsys):
    spec = tmp_path / "spec.yaml"
    spec.write_text("my own spec\n")
    assert main(["init", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert f"error: {spec} exists" in err and "never overwrites" in err
    assert spec.read_text() == "my own spec\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["spec.yaml"]  # no temporary file left


def test_init_with_a_bop_models_folder_and_a_scene_file(tmp_path, lm_models, capsys):
    # The user's files, named relative to the folder the command runs in; the spec names them
    # relative to itself, as specs do.
    work = tmp_path / "work"
    shutil.copytree(lm_models, work / "bop" / "models")
    r = subprocess.run([sys.executable, str(ROOT / "examples" / "byo_scene" / "make_scene.py"), str(work / "byo")],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    r = cli("init", "dataset", "--models", "bop/models", "--scene", "byo/scene.glb", "--backend", "photo", cwd=work)
    assert r.returncode == 0, r.stderr
    spec = work / "dataset" / "spec.yaml"
    data = yaml.safe_load(spec.read_text())
    assert data["objects"]["path"] == "../bop/models" and "builtin" not in data["objects"]
    assert data["scenes"] == [{"file": "../byo/scene.glb"}] and data["backend"] == {"name": "photo"}
    r = cli("validate", str(spec))
    assert r.returncode == 0 and r.stdout.strip() == f"{spec}: ok", r.stderr
    # and it builds: one arrangement, one camera, at a quarter of the size
    r = cli("-q", "build", str(spec), "--out", str(tmp_path / "out"), "--set", "arrangements.count=1",
            "--set", "cameras.per_arrangement=1", "--set", "intrinsics.width=160", "--set", "intrinsics.height=120",
            "--set", "intrinsics.fx=143.1", "--set", "intrinsics.fy=143.4", "--set", "intrinsics.cx=81.3",
            "--set", "intrinsics.cy=60.5", "--set", "visibility.threshold=0.05")
    assert r.returncode == 0, r.stderr[-2000:]
    assert "images written: 1" in r.stdout


def test_init_with_the_installed_lmo_models(tmp_path, capsys):
    assert main(["init", str(tmp_path / "lmo"), "--models", "dataset:lmo/models"]) == 0
    spec = tmp_path / "lmo" / "spec.yaml"
    assert yaml.safe_load(spec.read_text())["objects"]["path"] == "dataset:lmo/models"
    capsys.readouterr()
    assert main(["-q", "validate", str(spec)]) == 0
    assert capsys.readouterr().out.strip() == f"{spec}: ok"


def test_init_with_a_missing_models_folder_writes_nothing_and_says_where(tmp_path, capsys):
    assert main(["init", str(tmp_path / "a" / "b"), "--models", str(tmp_path / "nowhere")]) == 2
    err = capsys.readouterr().err
    assert f"{tmp_path / 'a' / 'b' / 'spec.yaml'} (not written): objects.path: " in err
    assert f"{tmp_path / 'nowhere'} does not exist" in err
    assert not (tmp_path / "a").exists()  # the folders it made are gone again


# --------------------------------------------------------------------------- doctor


COMPONENTS = ("python", "specsynth core", "OpenGL (PYOPENGL_PLATFORM=egl)", "furniture library",
              "assets robosuite-textures", "assets dataset:lmo", "assets pmndrs", "backends")


def test_doctor_passes_on_this_machine_and_names_each_component():
    r = cli("doctor")
    assert r.returncode == 0, r.stdout + r.stderr
    lines = r.stdout.splitlines()
    rows = {line[8:].split("  ")[0].strip(): line for line in lines[:-1] if not line.startswith(" ")}
    for name in COMPONENTS:
        assert name in rows, (name, r.stdout)
        assert rows[name].startswith("ok "), rows[name]
    assert lines[-1].startswith("everything specsynth needs works")
    assert f"{sys.version_info.major}.{sys.version_info.minor}" in rows["python"]
    assert "headless context, renderer " in rows["OpenGL (PYOPENGL_PLATFORM=egl)"]
    backends = metadata.entry_points(group="specsynth.backends")
    installed = {ep.name for ep in backends}
    if "cycles" in installed:
        assert rows["cycles (bpy)"].startswith("ok ") and f"bpy {metadata.version('bpy')}" in rows["cycles (bpy)"]
        assert rows["GPU devices"].startswith("info ")  # none here is fine: it is never a problem
    if "mitsuba" in installed:
        assert rows["mitsuba"].startswith("ok ") and "llvm_ad_rgb" in rows["mitsuba"]
        assert "mitsuba llvm_ad_rgb" in rows
    if "photo" in installed:
        assert rows["photo backgrounds"].startswith("ok ")
    assert "CUEW" not in r.stdout + r.stderr and r.stderr == ""


def test_doctor_names_the_fix_for_a_missing_or_damaged_asset_set(tmp_path, monkeypatch):
    from specsynth import doctor
    from specsynth.assets.library import textures
    from specsynth.assets.library.cache import cache_dir

    real = textures.folder(cache_dir())
    cache = tmp_path / "cache"
    shutil.copytree(real, textures.folder(cache))
    damaged = sorted(textures.folder(cache).glob("*.png"))[0]
    damaged.write_bytes(damaged.read_bytes()[:-1])
    monkeypatch.setenv("SPECSYNTH_CACHE", str(cache))
    checks = {c.component: c for c in doctor.asset_checks()}
    tex = checks["assets robosuite-textures"]
    assert tex.ok is False and tex.detail == f"1 file(s) differ from the manifest, e.g. {damaged.name}"
    assert tex.fix == "specsynth assets install --force"
    lmo = checks["assets dataset:lmo"]
    assert lmo.ok is False and lmo.detail == f"not installed in {cache}" and lmo.fix == "specsynth assets install"
    said: list[str] = []
    assert doctor.report(list(checks.values()), write=said.append) == 1
    assert "fix: specsynth assets install --force" in "\n".join(said)
    assert said[-1] == "3 problem(s): fix them and run `specsynth doctor` again"


# --------------------------------------------------------------------------- --version


def test_version_names_specsynth_and_each_backend_plugin():
    r = cli("--version")
    assert r.returncode == 0 and r.stderr == ""
    lines = r.stdout.splitlines()
    assert lines[0] == f"specsynth {metadata.version('specsynth')} (Python {sys.version.split()[0]})"
    for ep in metadata.entry_points(group="specsynth.backends"):
        line = next(line for line in lines if line.strip().startswith(f"backend {ep.name}: "))
        assert f"{ep.dist.name} {ep.dist.version}" in line
    if "cycles" in {ep.name for ep in metadata.entry_points(group="specsynth.backends")}:
        assert any(f"bpy {metadata.version('bpy')}" in line for line in lines)


def test_version_is_printed_by_main_too(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.startswith(f"specsynth {metadata.version('specsynth')} ")


def test_the_starter_spec_asks_each_backend_for_what_makes_its_images_photographs(tmp_path, capsys):
    """A path tracer's starter denoises and meters (its `low` is one sample: speckle, and lamps
    burn a desk out, without them); the photo baseline draws over exposed photographs."""
    from specsynth.plugins import installed_backend_plugins

    for plugin in installed_backend_plugins():
        folder = tmp_path / plugin.name
        assert main(["init", str(folder), "--backend", plugin.name]) == 0
        data = yaml.safe_load((folder / "spec.yaml").read_text())
        assert data["backend"].get("denoise", False) == plugin.capabilities.denoise, plugin.name
        sensor = data.get("sensor", {})
        assert (sensor.get("auto_exposure"), sensor.get("auto_white_balance")) == \
            ((True, True) if plugin.capabilities.draws_scene else (None, None)), plugin.name
        assert main(["validate", str(folder / "spec.yaml")]) == 0


@pytest.mark.slow
def test_the_starter_spec_builds_images_that_look_like_photographs(tmp_path, capsys):
    """The starter as written, built small: no image is speckle or burnt out (the starter of one
    undenoised, unmetered sample gave a median |Laplacian| of 262-319 levels, tests/photolike.py)."""
    from photolike import photo_faults

    assert main(["init", str(tmp_path / "first"), "--backend", "cycles"]) == 0
    small = ["--set", "intrinsics={width: 160, height: 120, fx: 143.1, fy: 143.4, cx: 80.0, cy: 60.0}",
             "--set", "arrangements.count=1", "--set", "cameras.per_arrangement=2"]
    r = cli("build", str(tmp_path / "first" / "spec.yaml"), "--out", str(tmp_path / "out"), "--jobs", "2", *small)
    assert r.returncode == 0, r.stderr[-2000:]
    images = sorted((tmp_path / "out").rglob("rgb/*.jpg"))
    assert len(images) >= 2
    assert not [f for p in images for f in photo_faults(p)]
