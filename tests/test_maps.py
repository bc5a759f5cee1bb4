"""Normals and NOCS maps: the maths on exact planes (hypothesis), then real builds read back."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from specsynth.annotate.maps import backproject, normals_from_depth
from specsynth.plan.compiler import compile_spec
from specsynth.run.build import build
from specsynth.spec.yamlio import load_spec

K = np.array([[80.0, 0.0, 39.5], [0.0, 82.0, 29.5], [0.0, 0.0, 1.0]])


def _plane_depth(n: np.ndarray, d: float, K: np.ndarray, w=80, h=60) -> np.ndarray:
    """z-depth of the plane n . x = d seen by camera K (every ray hits it in front)."""
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    rays = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
    return (d / (rays @ n)).astype(np.float32)


@settings(max_examples=200, deadline=None)
@given(st.floats(0.0, 55.0), st.floats(0.0, 360.0), st.floats(0.5, 5.0))
def test_normals_of_a_plane_are_its_normal(tilt, azimuth, dist):
    """Planes tilted up to 55 degrees from facing the camera, in any direction: the steepest the
    camera (32 degrees from its axis to a corner) sees in front of it everywhere, with a margin."""
    t, a = np.radians(tilt), np.radians(azimuth)
    n = np.array([np.sin(t) * np.cos(a), np.sin(t) * np.sin(a), -np.cos(t)])  # facing the camera (-z side)
    depth = _plane_depth(-n, dist, K)  # points x with (-n) . x = dist: in front of the camera
    assert (depth > 0).all()
    got = normals_from_depth(depth, K)
    assert np.allclose(np.linalg.norm(got, axis=-1), 1.0, atol=1e-5)
    assert np.abs(got - n).max() < 2e-3


def test_normals_at_an_edge_come_from_their_own_surface():
    depth = np.full((60, 80), 2.0, np.float32)
    depth[:, 40:] = 1.0  # a step: two fronto-parallel planes
    got = normals_from_depth(depth, K)
    assert np.allclose(got[:, 1:-1], (0.0, 0.0, -1.0), atol=1e-6)  # no slanted normal on the step
    depth[:, :5] = 0
    assert np.all(normals_from_depth(depth, K)[:, :5] == 0)


def test_backproject_inverts_projection():
    depth = np.random.default_rng(1).uniform(0.5, 3, (60, 80)).astype(np.float32)
    p = backproject(depth, K)
    uvw = p.reshape(-1, 3) @ K.T
    u, v = uvw[:, 0] / uvw[:, 2], uvw[:, 1] / uvw[:, 2]
    uu, vv = np.meshgrid(np.arange(80), np.arange(60))
    assert np.allclose(u, uu.ravel(), atol=1e-6) and np.allclose(v, vv.ravel(), atol=1e-6)


SPEC = """\
name: maps
seed: 4
intrinsics: {width: 96, height: 72, fx: 86.0, fy: 86.0, cx: 47.5, cy: 35.5}
objects: {builtin: [duck, mug, jenga]}
scenes: [{name: room}]
arrangements: {count: 1}
cameras: {per_arrangement: 2, distance: [0.35, 0.6]}
backend: {name: photo}
outputs: {image_format: png, normals: true, nocs: true}
"""


def _exr(path) -> np.ndarray:
    import OpenEXR

    with OpenEXR.File(str(path)) as f:
        return np.asarray(f.channels()["RGB"].pixels, dtype=np.float32)


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    d = tmp_path_factory.mktemp("maps")
    (d / "s.yaml").write_text(SPEC)
    s = build(compile_spec(load_spec(d / "s.yaml")), d / "out", jobs=1)
    assert not s.failures and s.images >= 1
    return d / "out"


def test_nocs_maps_back_onto_the_masks(built):
    """Every NOCS pixel, taken back to model coordinates and projected with the instance's pose,
    lands on its own pixel; values lie in [0, 1] and inside the model's box."""
    chunk = built / "bop" / "train_pbr" / "000000"
    gt = json.loads((chunk / "scene_gt.json").read_text())
    cams = json.loads((chunk / "scene_camera.json").read_text())
    models = json.loads((built / "bop" / "models" / "models_info.json").read_text())
    checked = 0
    for im, insts in gt.items():
        nocs = _exr(chunk / "nocs" / f"{int(im):06d}.exr")
        assert nocs.min() >= 0 and nocs.max() <= 1
        Kim = np.asarray(cams[im]["cam_K"]).reshape(3, 3)
        for gt_id, g in enumerate(insts):
            mask = np.asarray(Image.open(chunk / "mask_visib" / f"{int(im):06d}_{gt_id:06d}.png")) > 0
            if mask.sum() < 20:
                continue
            info = models[str(g["obj_id"])]
            ext = np.array([info["size_x"], info["size_y"], info["size_z"]])  # mm
            diag = np.linalg.norm(ext)
            model_mm = (nocs[mask].astype(np.float64) - 0.5) * diag
            assert (np.abs(model_mm) <= ext / 2 + 0.5).all()  # inside the box (0.5 mm)
            R = np.asarray(g["cam_R_m2c"]).reshape(3, 3)
            t = np.asarray(g["cam_t_m2c"])
            cam = model_mm @ R.T + t
            uv = cam @ Kim.T
            uv = uv[:, :2] / uv[:, 2:]
            vv, uu = np.nonzero(mask)
            err = np.hypot(uv[:, 0] - uu, uv[:, 1] - vv)
            assert np.percentile(err, 99) < 0.05, err.max()
            checked += 1
        outside = ~np.any([np.asarray(Image.open(chunk / "mask_visib" / f"{int(im):06d}_{k:06d}.png")) > 0
                           for k in range(len(insts))], axis=0)
        assert np.all(nocs[outside] == 0)
    assert checked >= 2


def test_normals_are_unit_and_in_the_parquet_table(built):
    import pyarrow.parquet as pq

    chunk = built / "bop" / "train_pbr" / "000000"
    for f in sorted((chunk / "normals").glob("*.exr")):
        n = _exr(f)
        length = np.linalg.norm(n, axis=-1)
        on = length > 0
        assert on.sum() > 50 and np.allclose(length[on], 1.0, atol=1e-5)
        assert (n[on][:, 2] < 0.2).mean() > 0.95  # seen surfaces face the camera (-z)
    images = pq.read_table(built / "parquet" / "images.parquet").to_pylist()
    for row in images:
        assert (built / row["normals"]).is_file() and (built / row["nocs"]).is_file()


def test_albedo_is_the_unlit_surface_colour(tmp_path):
    """Photo backend (objects only): the albedo covers exactly the objects, in their own colours."""
    (tmp_path / "s.yaml").write_text(SPEC.replace("normals: true, nocs: true", "albedo: true")
                                     .replace("[duck, mug, jenga]", "[mug, toys/cube]"))
    s = build(compile_spec(load_spec(tmp_path / "s.yaml")), tmp_path / "out", jobs=1)
    assert not s.failures and s.images >= 1
    chunk = tmp_path / "out" / "bop" / "train_pbr" / "000000"
    gt = json.loads((chunk / "scene_gt.json").read_text())
    for im, insts in gt.items():
        albedo = np.asarray(Image.open(chunk / "albedo" / f"{int(im):06d}.png"))
        masks = [np.asarray(Image.open(chunk / "mask_visib" / f"{int(im):06d}_{k:06d}.png")) > 0 for k in range(len(insts))]
        seen = np.any(masks, axis=0) if masks else np.zeros(albedo.shape[:2], bool)
        lit = albedo.max(axis=-1) > 0
        assert (lit == seen).mean() > 0.99  # the albedo covers what the labels cover
        for m in masks:
            if m.sum() > 30:  # one flat colour per instance (no light, no shading): small spread
                assert albedo[m].std(axis=0).max() < 25


ODD_TEXTURE_SNIPPET = """
import hashlib, sys
import numpy as np
from PIL import Image
from specsynth.annotate.albedo import AlbedoRenderer
from specsynth.model.ir import CameraIR, MaterialIR, MeshInstance, RenderScene, as_tuple
from specsynth.assets.meshio import MeshData, write_mesh
d = sys.argv[1]
Image.fromarray(np.random.default_rng(0).integers(0, 255, (255, 255, 3), dtype=np.uint8)).save(d + "/odd.png")
quad = MeshData(vertices=np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float),
                faces=np.array([[0, 1, 2], [0, 2, 3]]), uv=np.array([[0, 0], [3, 0], [3, 3], [0, 3]], float))
write_mesh(d + "/quad.ply", quad)
scene = RenderScene(meshes=(MeshInstance("floor", d + "/quad.ply", "quad", as_tuple(np.eye(4)),
                                         MaterialIR(texture=d + "/odd.png")),), lights=())
R = np.diag([1.0, -1.0, -1.0])
cam = CameraIR(K=((60.0, 0, 31.5), (0, 60.0, 23.5), (0, 0, 1.0)), width=64, height=48, R_w2c=as_tuple(R),
               t_w2c=tuple(-R @ [0.0, 0.0, 1.2]))
r = AlbedoRenderer(64, 48)
r.load(scene)
print(hashlib.sha256(r.render(cam).tobytes()).hexdigest())
"""


def test_albedo_of_an_odd_width_texture_is_the_same_in_every_process(tmp_path):
    """A 255-px RGB texture (robosuite's floor tile has one) used to be read past its rows' ends
    (OpenGL's 4-byte row alignment): seams took whatever memory held, different in every run."""
    import subprocess
    import sys

    runs = {subprocess.run([sys.executable, "-c", ODD_TEXTURE_SNIPPET, str(tmp_path)], capture_output=True, text=True,
                           check=True).stdout.strip() for _ in range(3)}
    assert len(runs) == 1, runs


COPLANAR_SNIPPET = """
import hashlib, random, sys
import numpy as np
from specsynth.annotate.albedo import AlbedoRenderer
from specsynth.model.ir import CameraIR, MaterialIR, MeshInstance, RenderScene, as_tuple
from specsynth.assets.meshio import MeshData, write_mesh
d = sys.argv[1]
junk = [object() for _ in range(random.randrange(1, 5000))]  # the heap moved, as other work moves it
write_mesh(d + "/q.ply", MeshData(vertices=np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float),
                                  faces=np.array([[0, 1, 2], [0, 2, 3]])))
colours = [(1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 0), (0, 1, 1), (1, 0, 1)]
scene = RenderScene(meshes=tuple(MeshInstance(f"part{k}", d + "/q.ply", f"q{k}", as_tuple(np.eye(4)),
                                              MaterialIR(base_color=c)) for k, c in enumerate(colours)), lights=())
R = np.diag([1.0, -1.0, -1.0])
cam = CameraIR(K=((60.0, 0, 31.5), (0, 60.0, 23.5), (0, 0, 1.0)), width=64, height=48, R_w2c=as_tuple(R),
               t_w2c=tuple(-R @ [0.0, 0.0, 1.2]))
r = AlbedoRenderer(64, 48)
r.load(scene)
print(hashlib.sha256(r.render(cam).tobytes()).hexdigest())
"""


def test_coplanar_parts_at_one_pose_draw_the_same_in_every_process(tmp_path):
    """A furniture model's parts share one pose; pyrender ordered such ties by a set, so which of
    two coplanar parts won changed from process to process (measured: 4 results in 5 runs)."""
    import subprocess
    import sys

    runs = {subprocess.run([sys.executable, "-c", COPLANAR_SNIPPET, str(tmp_path)], capture_output=True, text=True,
                           check=True).stdout.strip() for _ in range(4)}
    assert len(runs) == 1, runs


BASE_COLOUR_SNIPPET = """
import sys
import numpy as np
from specsynth.annotate.albedo import AlbedoRenderer
from specsynth.assets.meshio import MeshData, write_mesh
from specsynth.model.ir import CameraIR, MaterialIR, MeshInstance, RenderScene, as_tuple
d = sys.argv[1]
colors = np.tile(np.array([[255, 128, 30, 255]], np.uint8), (4, 1))
quad = MeshData(vertices=np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], float),
                faces=np.array([[0, 1, 2], [0, 2, 3]]), colors=colors)
write_mesh(d + "/quad.ply", quad)
R = np.diag([1.0, -1.0, -1.0])
cam = CameraIR(K=((60.0, 0, 31.5), (0, 60.0, 23.5), (0, 0, 1.0)), width=64, height=48, R_w2c=as_tuple(R),
               t_w2c=tuple(-R @ [0.0, 0.0, 1.2]))
for vertex in (False, True):
    r = AlbedoRenderer(64, 48)
    r.load(RenderScene(meshes=(MeshInstance("q", d + "/quad.ply", "q", as_tuple(np.eye(4)),
                                            MaterialIR(base_color=(0.5, 0.2, 0.05), use_vertex_colors=vertex)),),
                       lights=()))
    print(*r.render(cam)[24, 32])
    r.close()
"""


def test_albedo_of_base_and_vertex_colours_is_their_srgb_product(tmp_path):
    """A base colour alone, and times vertex colours, come out as the sRGB encoding of the linear
    product (as a texture does), within a level of 8-bit rounding."""
    import subprocess
    import sys

    from specsynth.model.colour import linear_to_srgb, srgb_to_linear

    out = subprocess.run([sys.executable, "-c", BASE_COLOUR_SNIPPET, str(tmp_path)], capture_output=True, text=True,
                         check=True).stdout.split("\n")
    base = np.array([0.5, 0.2, 0.05])
    vertex = srgb_to_linear(np.array([255, 128, 30]) / 255.0)
    for line, linear in zip(out, (base, base * vertex)):
        got = np.array([int(v) for v in line.split()])
        assert np.abs(got - 255 * linear_to_srgb(linear)).max() <= 1.5, (got, 255 * linear_to_srgb(linear))
