"""Lens distortion: the model is OpenCV's (checked against cv2.projectPoints), inverts exactly,
refuses coefficients that fold the image, and a real build's masks, boxes, depth and colour all
follow the distorted image: model points projected by OpenCV land on their masks."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from specsynth.assets.meshio import read_mesh
from specsynth.model import lens
from specsynth.plan.compiler import compile_spec
from specsynth.run.build import build
from specsynth.spec.yamlio import SpecError, load_spec

cv2 = pytest.importorskip("cv2")

K = np.array([[115.0, 0.0, 63.5], [0.0, 116.0, 47.0], [0.0, 0.0, 1.0]])
W, H = 128, 96
coefficients = st.tuples(st.floats(-0.3, 0.3), st.floats(-0.1, 0.1), st.floats(-0.005, 0.005),
                         st.floats(-0.005, 0.005), st.floats(-0.05, 0.05))


@settings(max_examples=80, deadline=None)
@given(coefficients, st.integers(0, 2 ** 31))
def test_distort_is_opencvs_model(k, seed):
    pts = np.random.default_rng(seed).uniform(-0.6, 0.6, (50, 2))
    xyz = np.concatenate([pts, np.ones((50, 1))], axis=1)
    want, _ = cv2.projectPoints(xyz, np.zeros(3), np.zeros(3), K, np.array(k))
    got = lens.distorted_pixels(K, pts * [K[0, 0], K[1, 1]] + K[:2, 2], k)
    assert np.abs(got - want.reshape(-1, 2)).max() < 1e-6


@settings(max_examples=80, deadline=None)
@given(coefficients)
def test_undistort_inverts_distort_over_the_image(k):
    try:
        lens.check(K, W, H, k)
    except lens.LensError:
        return  # a folding lens is refused, not inverted
    warp = lens.warp_for(K, W, H, k)
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    back = lens.distorted_pixels(K, np.stack([warp.map_u + warp.x0, warp.map_v + warp.y0], -1), k)
    assert np.abs(back - np.stack([u, v], -1)).max() < 1e-4
    # The window covers every lookup with a pixel to spare for bilinear interpolation.
    assert warp.map_u.min() >= 0 and warp.map_u.max() <= warp.width - 2
    assert warp.map_v.min() >= 0 and warp.map_v.max() <= warp.height - 2


def test_folding_coefficients_are_refused():
    for k in ([-0.9, 0, 0, 0, 0], [1.5, -3.0, 0, 0, 0], [0.0, 0.0, 0.0, 0.0, -40.0]):
        with pytest.raises(lens.LensError):
            lens.check(K, W, H, k)
    lens.check(K, W, H, [-0.25, 0.08, 0.002, -0.001, 0.0])


SPEC = """\
name: lens
seed: 11
intrinsics: {width: 128, height: 96, fx: 115.0, fy: 116.0, cx: 63.5, cy: 47.0,
             distortion: [-0.25, 0.08, 0.002, -0.001, 0.0]}
objects: {builtin: [duck, mug, jenga, lego, teddy, torus]}
scenes: [{name: room}]
arrangements: {count: 1}
cameras: {per_arrangement: 3, distance: [0.25, 0.35]}
backend: {name: photo, backgrounds: BACKGROUNDS}
outputs: {image_format: png, coco: false, normals: true, nocs: true}
"""


@pytest.fixture(scope="module")
def lens_build(tmp_path_factory):
    d = tmp_path_factory.mktemp("lens")
    bg = d / "black"
    bg.mkdir()
    for i in range(2):
        Image.fromarray(np.zeros((480, 640, 3), np.uint8)).save(bg / f"{i}.png")
    (d / "s.yaml").write_text(SPEC.replace("BACKGROUNDS", str(bg)))
    result = build(compile_spec(load_spec(d / "s.yaml")), d / "out", jobs=1)
    assert not result.failures and result.images >= 2
    return d / "out"


def _model_points(out, obj_id: int) -> np.ndarray:
    return read_mesh(str(out / "bop" / "models" / f"obj_{obj_id:06d}.ply")).vertices.astype(np.float64)  # mm


def test_opencv_projections_land_on_the_masks(lens_build):
    """Every model vertex cv2.projectPoints puts inside the image lies on the object's amodal mask
    (one pixel of tolerance: the mask is sampled at pixel centres); without the distortion
    coefficients the same points miss by pixels, so the test sees the lens."""
    chunk = lens_build / "bop" / "train_pbr" / "000000"
    cams = json.loads((chunk / "scene_camera.json").read_text())
    gts = json.loads((chunk / "scene_gt.json").read_text())
    checked, moved = 0, []
    for im, cam in cams.items():
        Kc, dist = np.array(cam["cam_K"]).reshape(3, 3), np.array(cam["cam_dist"])
        assert dist.tolist() == [-0.25, 0.08, 0.002, -0.001, 0.0]
        for gt_id, gt in enumerate(gts[im]):
            mask = np.asarray(Image.open(chunk / "mask" / f"{int(im):06d}_{gt_id:06d}.png")) > 0
            grown = mask.copy()
            for dy in (-1, 0, 1):
                for dx in (-1, 0, 1):
                    grown |= np.roll(np.roll(mask, dy, 0), dx, 1)
            rvec, _ = cv2.Rodrigues(np.array(gt["cam_R_m2c"]).reshape(3, 3))
            t = np.array(gt["cam_t_m2c"], np.float64)
            pts = _model_points(lens_build, gt["obj_id"])
            uv = cv2.projectPoints(pts, rvec, t, Kc, dist)[0].reshape(-1, 2)
            flat = cv2.projectPoints(pts, rvec, t, Kc, np.zeros(5))[0].reshape(-1, 2)
            inside = (uv[:, 0] > 0.5) & (uv[:, 1] > 0.5) & (uv[:, 0] < W - 1.5) & (uv[:, 1] < H - 1.5)
            if inside.sum() < 20:
                continue
            px = np.rint(uv[inside]).astype(int)
            assert grown[px[:, 1], px[:, 0]].mean() > 0.99, (im, gt_id)
            moved.append(np.linalg.norm(uv[inside] - flat[inside], axis=1).mean())
            checked += 1
    assert checked >= 6 and max(moved) > 2.0, moved


def test_boxes_depth_and_colour_follow_the_distorted_image(lens_build):
    chunk = lens_build / "bop" / "train_pbr" / "000000"
    info = json.loads((chunk / "scene_gt_info.json").read_text())
    for im, entries in info.items():
        rgb = np.asarray(Image.open(chunk / "rgb" / f"{int(im):06d}.png").convert("RGB"))
        depth = np.asarray(Image.open(chunk / "depth" / f"{int(im):06d}.png"))
        union = np.zeros((H, W), bool)
        for gt_id, e in enumerate(entries):
            visib = np.asarray(Image.open(chunk / "mask_visib" / f"{int(im):06d}_{gt_id:06d}.png")) > 0
            union |= visib
            assert e["px_count_visib"] == int(visib.sum())
            if visib.any():
                ys, xs = np.nonzero(visib)
                assert e["bbox_visib"] == [xs.min(), ys.min(), xs.max() - xs.min(), ys.max() - ys.min()]
                assert (depth[visib] > 0).all()  # the depth is warped like the masks
                assert 0 < e["visib_fract"] <= 1 and e["px_count_all"] >= e["px_count_visib"]
        # The photo baseline draws the objects over a black photograph: lit pixels are the objects'.
        # Colour is anti-aliased and interpolated, masks are not: they may differ within two pixels
        # of an edge, nowhere else.
        lit = rgb.max(axis=-1) > 12
        near_edge = np.zeros_like(union)
        for dy in range(-2, 3):
            for dx in range(-2, 3):
                near_edge |= union != np.roll(np.roll(union, dy, 0), dx, 1)
        assert not ((lit != union) & ~near_edge).any(), im
        assert (lit & union).sum() > 0.8 * union.sum()


def test_normals_and_nocs_follow_the_distorted_image(lens_build):
    """Through the lens, each pixel's NOCS taken back to the model and projected by OpenCV with the
    distortion lands on that pixel; normals are unit length where there is depth."""
    import OpenEXR

    chunk = lens_build / "bop" / "train_pbr" / "000000"
    cams, gts = json.loads((chunk / "scene_camera.json").read_text()), json.loads((chunk / "scene_gt.json").read_text())
    models = {}
    for im, cam in cams.items():
        with OpenEXR.File(str(chunk / "nocs" / f"{int(im):06d}.exr")) as f:
            nocs = np.asarray(f.channels()["RGB"].pixels, np.float64)
        with OpenEXR.File(str(chunk / "normals" / f"{int(im):06d}.exr")) as f:
            normals = np.asarray(f.channels()["RGB"].pixels, np.float64)
        depth = np.asarray(Image.open(chunk / "depth" / f"{int(im):06d}.png"))
        length = np.linalg.norm(normals, axis=-1)
        assert np.allclose(length[length > 0], 1.0, atol=1e-3) and (length[depth == 0] == 0).all()
        # (a pixel with no neighbour of depth along an axis has no slope: thin parts of small objects)
        assert (length[depth > 0] > 0).mean() > 0.9
        Kc, dist = np.array(cam["cam_K"]).reshape(3, 3), np.array(cam["cam_dist"])
        for gt_id, gt in enumerate(gts[im]):
            visib = np.asarray(Image.open(chunk / "mask_visib" / f"{int(im):06d}_{gt_id:06d}.png")) > 0
            ys, xs = np.nonzero(visib)
            if len(xs) < 10:
                continue
            if gt["obj_id"] not in models:
                v = _model_points(lens_build, gt["obj_id"])
                models[gt["obj_id"]] = float(np.linalg.norm(v.max(0) - v.min(0)))  # mm
            pts = (nocs[ys, xs] - 0.5) * models[gt["obj_id"]]  # model frame, mm
            rvec, _ = cv2.Rodrigues(np.array(gt["cam_R_m2c"]).reshape(3, 3))
            uv = cv2.projectPoints(pts, rvec, np.array(gt["cam_t_m2c"], np.float64), Kc, dist)[0].reshape(-1, 2)
            err = np.linalg.norm(uv - np.stack([xs, ys], -1), axis=1)
            assert np.percentile(err, 99) < 0.1, (im, gt_id, np.percentile(err, 99))


def test_bad_distortion_is_a_located_error(tmp_path):
    f = tmp_path / "s.yaml"
    f.write_text(SPEC.replace("[-0.25, 0.08, 0.002, -0.001, 0.0]", "[-0.9, 0.0, 0.0, 0.0, 0.0]")
                 .replace("BACKGROUNDS", "builtin"))
    with pytest.raises(SpecError) as e:
        load_spec(f)
    msg = str(e.value)
    assert "s.yaml:4:" in msg and "intrinsics.distortion" in msg and "fold" in msg


def test_depth_of_field_errors_are_located(tmp_path):
    """An aperture of 0 with depth of field on, and a backend that cannot defocus, are refused
    before any work, at the field and line. (Each backend's defocus is checked by the shipped
    conformance suite: in focus the textured box keeps its gradients, focused 4x farther it loses them.)"""
    f = tmp_path / "s.yaml"
    base = SPEC.replace("BACKGROUNDS", "builtin").replace("             distortion: [-0.25, 0.08, 0.002, -0.001, 0.0]}", "}")
    base = base.replace("intrinsics: {width: 128, height: 96, fx: 115.0, fy: 116.0, cx: 63.5, cy: 47.0,\n}",
                        "intrinsics: {width: 128, height: 96, fx: 115.0, fy: 116.0, cx: 63.5, cy: 47.0}")
    f.write_text(base.replace("distance: [0.25, 0.35]}", "distance: [0.25, 0.35],\n          depth_of_field: {aperture: [0, 4]}}"))
    with pytest.raises(SpecError) as e:
        load_spec(f)
    assert "s.yaml:8:" in str(e.value) and "cameras.depth_of_field.aperture" in str(e.value) and "aperture of 0" in str(e.value)
    f.write_text(base.replace("distance: [0.25, 0.35]}", "distance: [0.25, 0.35],\n          depth_of_field: {aperture: [2, 4]}}"))
    with pytest.raises(SpecError, match="cameras.depth_of_field.*'photo' cannot render depth of field"):
        compile_spec(load_spec(f))
    compile_spec(load_spec(f, ["backend={name: cycles}"]))  # a backend that can: fine


def test_motion_blur_errors_are_located(tmp_path):
    f = tmp_path / "s.yaml"
    base = SPEC.replace("BACKGROUNDS", "builtin").replace(",\n             distortion: [-0.25, 0.08, 0.002, -0.001, 0.0]}", "}")
    f.write_text(base.replace("distance: [0.25, 0.35]}", "distance: [0.25, 0.35],\n          motion_blur: {speed: [0, 0], rotation: [0, 0]}}"))
    with pytest.raises(SpecError, match=r"s.yaml:8:.*cameras.motion_blur.*blurs nothing"):
        load_spec(f)
    f.write_text(base.replace("distance: [0.25, 0.35]}", "distance: [0.25, 0.35],\n          motion_blur: {shutter: 0.02}}"))
    with pytest.raises(SpecError, match="cameras.motion_blur.*'photo' cannot render motion blur"):
        compile_spec(load_spec(f))
    compile_spec(load_spec(f, ["backend={name: mitsuba}"]))


@settings(max_examples=100, deadline=None)
@given(st.tuples(*[st.floats(-0.2, 0.2)] * 6), st.tuples(*[st.floats(-3, 3)] * 3))
def test_exposure_poses_run_around_the_mid_pose(motion, rvec):
    """c2w_during_exposure: the mid-exposure pose is the record's; open and close are rigid and
    the camera turns by exactly the rotation vector between them (in its own frame)."""
    from specsynth.model.conventions import c2w_during_exposure, rotation_vector_matrix

    T = np.eye(4)
    T[:3, :3], T[:3, 3] = rotation_vector_matrix(rvec), (0.3, -1.0, 2.0)
    assert np.allclose(c2w_during_exposure(T, motion, 0.0), T)
    open_, close = c2w_during_exposure(T, motion, -0.5), c2w_during_exposure(T, motion, 0.5)
    for M in (open_, close):
        assert np.allclose(M[:3, :3].T @ M[:3, :3], np.eye(3), atol=1e-9) and np.linalg.det(M[:3, :3]) > 0
    assert np.allclose(open_[:3, :3].T @ close[:3, :3], rotation_vector_matrix(motion[3:]), atol=1e-9)
    if not any(motion[3:]):
        assert np.allclose(close[:3, 3] - open_[:3, 3], T[:3, :3] @ np.asarray(motion[:3]), atol=1e-12)
    want, _ = cv2.Rodrigues(np.asarray(rvec, np.float64))
    assert np.allclose(rotation_vector_matrix(rvec), want, atol=1e-9)


def test_visibility_precheck_measures_through_the_lens(lens_build):
    """The camera pre-check's visible fraction of the focused object is the distorted image's: the
    same number the annotation gives it."""
    info = json.loads((lens_build / "bop" / "train_pbr" / "000000" / "scene_gt_info.json").read_text())
    views = [json.loads(p.read_text()) for p in (lens_build / ".specsynth" / "store" / "view").glob("*/*/record.json")]
    checked = 0
    for v in views:
        rec = v.get("record", v)
        if not rec.get("accepted"):
            continue
        got = info[str(rec["index"])][rec["focus_inst"]]["visib_fract"]
        assert got == pytest.approx(rec["focus_visib_fract"], abs=1e-9), rec
        checked += 1
    assert checked >= 2
