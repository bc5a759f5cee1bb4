"""The demo pair builds end to end (what `make demo` runs), with identical cameras and poses."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_demo_pair_builds(tmp_path):
    for name in ("demo", "demo_bl"):
        r = subprocess.run([sys.executable, "-m", "specsynth.cli", "build", f"specs/{name}.yaml", "--out",
                            str(tmp_path / name), "--jobs", "2", "--quiet"], cwd=ROOT, capture_output=True, text=True)
        assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    chunk = Path("bop/train_pbr/000000")
    for f in ("scene_gt.json", "scene_camera.json"):
        assert (tmp_path / "demo" / chunk / f).read_bytes() == (tmp_path / "demo_bl" / chunk / f).read_bytes()
    assert len(list((tmp_path / "demo" / chunk / "rgb").glob("*.png"))) >= 12
