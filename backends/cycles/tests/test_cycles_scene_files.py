"""The scene users bring (``examples/byo_scene``: a glTF room with a checker floor, an OBJ table
with a wood top), built with Cycles: both textures show, and the labels agree with Cycles' own
instance ids of each view."""

from __future__ import annotations

import importlib.util
import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from specsynth.cli import main
from specsynth.model.ir import CameraIR, as_tuple
from specsynth.model.records import ArrangementRecord, ViewRecord
from specsynth.plan.compiler import compile_spec
from specsynth.run.store import Store
from specsynth.run.worker import World
from specsynth.spec.yamlio import load_spec

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[3]  # the repository: examples/ is not part of a package
SMALL = ["arrangements.count=1", "cameras.per_arrangement=2"]


@pytest.fixture()
def byo(tmp_path) -> Path:
    spec = importlib.util.spec_from_file_location("make_scene", ROOT / "examples" / "byo_scene" / "make_scene.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    mod.write_all(tmp_path / "byo")
    return tmp_path / "byo"


def test_both_textures_show_and_the_masks_agree_with_cycles(byo, tmp_path):
    """Cycles draws the glTF checker floor and the OBJ's wood top in their colours; every visible
    instance's mask matches Cycles' own instance ids (IoU > 0.95)."""
    out = tmp_path / "cycles"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        rc = main(["build", str(byo / "spec.yaml"), "--out", str(out), "--quiet",
                   "--set", "backend={name: cycles, samples: 16, denoise: true}", *(a for s in SMALL for a in ("--set", s))])
    assert rc == 0
    pixels = np.concatenate([np.asarray(Image.open(p).convert("RGB")).reshape(-1, 3)
                             for p in sorted((out / "bop/train_pbr/000000/rgb").iterdir())]).astype(int)
    r, g, b = pixels.T
    blue_tiles = (b > r + 30) & (b > g + 10)  # the checker's dark tiles (70, 95, 140)
    wood = (r > b + 60) & (r > g + 20)  # the table top (150-210, 90-130, 45-65)
    assert blue_tiles.mean() > 0.02 and wood.mean() > 0.02, (blue_tiles.mean(), wood.mean())
    assert _masks_compared_with_cycles_rerender(byo, out) >= 2


def _masks_compared_with_cycles_rerender(byo: Path, out: Path) -> int:
    """The labels against an independent re-render: Cycles' own instance ids of each view."""
    from specsynth_cycles.backend import CyclesBackend

    graph = compile_spec(load_spec(byo / "spec.yaml", SMALL))
    world, store = World(graph.inputs.arrange, byo), Store(out)
    jobs = json.loads((out / ".specsynth" / "manifest.json").read_text())["jobs"]
    info = json.loads((out / "bop/train_pbr/000000/scene_gt_info.json").read_text())
    cyc = CyclesBackend({"name": "cycles"}, threads=2)
    compared = 0
    try:
        for arr_key in jobs["arrange"].values():
            arr = ArrangementRecord.from_json(store.load("arrange", arr_key))
            scene = world.render_scene(arr)
            cyc.load(scene)
            for vkey in jobs["view"].values():
                view = ViewRecord.from_json(store.load("view", vkey))
                if view.arr != arr.arr or not view.accepted:
                    continue
                K = graph.spec.intrinsics
                cam = CameraIR(K=as_tuple(np.array([[K.fx, 0, K.cx], [0, K.fy, K.cy], [0, 0, 1]])), width=K.width,
                               height=K.height, R_w2c=as_tuple(np.asarray(view.R_w2c)), t_w2c=as_tuple(np.asarray(view.t_w2c)))
                ids = cyc.render_index_masks(cam)
                for gt_id, gt in enumerate(info[str(view.index)]):
                    if gt["px_count_visib"] < 100:
                        continue
                    ours = np.asarray(Image.open(out / f"bop/train_pbr/000000/mask_visib/{view.index:06d}_{gt_id:06d}.png")) > 0
                    theirs = ids == scene.objects()[gt_id].inst
                    iou = (ours & theirs).sum() / (ours | theirs).sum()
                    assert iou > 0.95, (view.index, gt_id, iou)
                    compared += 1
    finally:
        cyc.close()
    return compared
