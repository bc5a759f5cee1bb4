"""Stereo pairs: the right eye is the left camera moved by the baseline along its own +x, written
as the split '<split>_right' with the same image ids and its own annotations; every visible left
pixel, moved by the disparity fx * b / z its depth gives, lands on the same object in the right eye."""

from __future__ import annotations

import json

import numpy as np
import pyarrow.parquet as pq
import pytest
from PIL import Image

from specsynth.plan.compiler import compile_spec
from specsynth.run.build import build
from specsynth.spec.yamlio import load_spec

SPEC = """\
name: stereo
seed: 21
intrinsics: {width: 128, height: 96, fx: 115.0, fy: 115.0, cx: 63.5, cy: 47.5}
objects: {builtin: [duck, mug, jenga, lego]}
scenes: [{name: room}]
arrangements: {count: 1}
cameras: {per_arrangement: 3, distance: [0.3, 0.45], stereo: {baseline: 0.06}}
backend: {name: photo}
outputs: {image_format: png}
"""


@pytest.fixture(scope="module")
def stereo_build(tmp_path_factory):
    d = tmp_path_factory.mktemp("stereo")
    (d / "s.yaml").write_text(SPEC)
    result = build(compile_spec(load_spec(d / "s.yaml")), d / "out", jobs=1)
    assert not result.failures and result.images >= 4 and result.images % 2 == 0
    return d / "out"


def _json(path):
    return json.loads(path.read_text())


def test_right_eye_is_a_split_of_its_own_with_the_same_ids(stereo_build):
    left, right = (stereo_build / "bop" / s / "000000" for s in ("train_pbr", "train_pbr_right"))
    cl, cr = _json(left / "scene_camera.json"), _json(right / "scene_camera.json")
    assert cl.keys() == cr.keys() and len(cl) >= 2
    for im in cl:
        assert cl[im]["stereo"] == {"eye": "left", "baseline_mm": 60.0}
        assert cr[im]["stereo"] == {"eye": "right", "baseline_mm": 60.0}
        assert cl[im]["cam_R_w2c"] == cr[im]["cam_R_w2c"] and cl[im]["cam_K"] == cr[im]["cam_K"]
        assert np.allclose(np.subtract(cl[im]["cam_t_w2c"], cr[im]["cam_t_w2c"]), [60.0, 0.0, 0.0], atol=1e-6)
    gl, gr = _json(left / "scene_gt.json"), _json(right / "scene_gt.json")
    for im in gl:  # the same objects, seen from 6 cm to the right
        for a, b in zip(gl[im], gr[im]):
            assert a["obj_id"] == b["obj_id"] and a["cam_R_m2c"] == b["cam_R_m2c"]
            assert np.allclose(np.subtract(a["cam_t_m2c"], b["cam_t_m2c"]), [60.0, 0.0, 0.0], atol=1e-4)
    assert (stereo_build / "coco" / "train_pbr_right.json").is_file()
    images = pq.read_table(stereo_build / "parquet" / "images_right.parquet").to_pandas()
    assert len(images) == len(cr) and all(p.startswith("bop/train_pbr_right/") for p in images["rgb"])


def test_disparity_carries_left_pixels_onto_the_same_object(stereo_build):
    left, right = (stereo_build / "bop" / s / "000000" for s in ("train_pbr", "train_pbr_right"))
    cam = _json(left / "scene_camera.json")
    checked = 0
    for im, c in cam.items():
        fx, scale = c["cam_K"][0], c["depth_scale"]
        depth = np.asarray(Image.open(left / "depth" / f"{int(im):06d}.png"), np.float64) * scale  # mm
        for gt in range(len(_json(left / "scene_gt.json")[im])):
            name = f"{int(im):06d}_{gt:06d}.png"
            visib = np.asarray(Image.open(left / "mask_visib" / name)) > 0
            target = np.asarray(Image.open(right / "mask" / name)) > 0
            grown = target | np.roll(target, 1, 1) | np.roll(target, -1, 1) | np.roll(target, 1, 0) | np.roll(target, -1, 0)
            ys, xs = np.nonzero(visib & (depth > 0))
            if len(xs) < 20:
                continue
            xr = np.rint(xs - fx * 60.0 / depth[ys, xs]).astype(int)  # right eye sees points further left
            inside = (xr >= 0) & (xr < visib.shape[1])
            if inside.sum() < 20:  # it left the right eye's view
                continue
            assert grown[ys[inside], xr[inside]].mean() > 0.97, (im, gt)
            checked += 1
    assert checked >= 3


def test_rebuilt_without_stereo_the_right_eye_is_gone(stereo_build, tmp_path):
    """Outputs follow the spec: the same folder rebuilt without `stereo` keeps no right eye."""
    import shutil

    out = tmp_path / "out"
    shutil.copytree(stereo_build, out)
    spec = tmp_path / "s.yaml"
    spec.write_text(SPEC.replace(", stereo: {baseline: 0.06}", ""))
    result = build(compile_spec(load_spec(spec)), out, jobs=1)
    assert not result.failures and result.images >= 2
    assert not (out / "bop" / "train_pbr_right").exists() and not (out / "coco" / "train_pbr_right.json").exists()
    assert not list((out / "parquet").glob("*_right.parquet")) and (out / "bop" / "train_pbr").is_dir()
