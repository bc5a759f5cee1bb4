"""The scene users bring (``examples/byo_scene``: a glTF room with a checker floor, an OBJ table
with a wood top), built with Mitsuba: both textures show in their colours."""

from __future__ import annotations

import importlib.util
import warnings
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from specsynth.cli import main

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[3]  # the repository: examples/ is not part of a package


@pytest.fixture()
def byo(tmp_path) -> Path:
    spec = importlib.util.spec_from_file_location("make_scene", ROOT / "examples" / "byo_scene" / "make_scene.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    mod.write_all(tmp_path / "byo")
    return tmp_path / "byo"


def test_both_textures_show_in_a_real_render(byo, tmp_path):
    out = tmp_path / "mitsuba"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rc = main(["build", str(byo / "spec.yaml"), "--out", str(out), "--quiet", "--set", "backend={name: mitsuba, samples: 16}",
                   "--set", "arrangements.count=1", "--set", "cameras.per_arrangement=2"])
    assert rc == 0
    pixels = np.concatenate([np.asarray(Image.open(p).convert("RGB")).reshape(-1, 3)
                             for p in sorted((out / "bop/train_pbr/000000/rgb").iterdir())]).astype(int)
    r, g, b = pixels.T
    blue_tiles = (b > r + 30) & (b > g + 10)  # the checker's dark tiles (70, 95, 140)
    wood = (r > b + 60) & (r > g + 20)  # the table top (150-210, 90-130, 45-65)
    assert blue_tiles.mean() > 0.02 and wood.mean() > 0.02, (blue_tiles.mean(), wood.mean())
