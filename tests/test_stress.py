"""Numerical-stability stress suite. Each test states the property and its tolerance."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from specsynth.assets.meshio import MeshData, write_mesh
from specsynth.model.colour import NonFiniteRender, check_finite
from specsynth.model.ir import CameraIR, MeshInstance, RenderScene, as_tuple
from specsynth.outputs.images import DepthOverflowError, encode_depth
from specsynth.spec.models import Cameras, Intrinsics
from specsynth.views import cameras

pytestmark = pytest.mark.stress

W, H = 160, 120
INTR = Intrinsics(width=W, height=H, fx=150.0, fy=151.0, cx=79.3, cy=60.2, clip=(0.01, 100.0))


def _orthonormal_err(R: np.ndarray) -> float:
    return float(np.abs(R @ R.T - np.eye(3)).max())


@pytest.mark.parametrize("elevation", [-90.0, 90.0, 89.999999, -89.999999])
@pytest.mark.parametrize("azimuth", [0.0, 360.0, -720.0, 720.0, 359.9999999])
@pytest.mark.parametrize("distance", [1e-3, 1e4])
def test_look_at_at_the_poles_and_range_limits(elevation, azimuth, distance):
    """Property: R finite, orthonormal to 1e-12, det +1; the target sits on the optical axis to 1e-9 rad."""
    target = np.array([0.3, -0.2, 0.9])
    eye = target + cameras.spherical_offset(azimuth, elevation, distance)
    R, t = cameras.look_at(eye, target)
    assert np.isfinite(R).all() and np.isfinite(t).all()
    assert _orthonormal_err(R) < 1e-12 and abs(np.linalg.det(R) - 1) < 1e-12
    pc = R @ target + t
    assert pc[2] > 0 and np.hypot(pc[0], pc[1]) / pc[2] < 1e-9


def test_azimuth_wraps_around():
    """Property: azimuth a and a + 360 give the same pose to 1e-9."""
    for az in np.linspace(-360, 360, 17):
        R1, t1 = cameras.look_at(cameras.spherical_offset(az, 30, 2.0), np.zeros(3))
        R2, t2 = cameras.look_at(cameras.spherical_offset(az + 360, 30, 2.0), np.zeros(3))
        assert np.abs(R1 - R2).max() < 1e-9 and np.abs(t1 - t2).max() < 1e-9


def test_sampled_cameras_at_range_limits_are_orthonormal():
    """Property: 2000 cameras with degenerate and extreme ranges are finite and orthonormal to 1e-12."""
    rng = np.random.default_rng(0)
    for cams in (Cameras(elevation=(90, 90)), Cameras(elevation=(-90, -90)), Cameras(distance=(0.02, 0.02)),
                 Cameras(distance=(1e4, 1e4), inplane=(-360, 360)), Cameras(azimuth=(-720, 720))):
        for _ in range(400):
            s = cameras.sample_camera(rng, np.array([1e3, -1e3, 5.0]), cams)
            assert np.isfinite(s.R_w2c).all() and _orthonormal_err(np.asarray(s.R_w2c)) < 1e-12


def _box_scene(tmp_path, size, centre) -> RenderScene:
    m = trimesh.creation.box(extents=size)
    path = tmp_path / f"box_{size[0]:.4f}.ply"
    write_mesh(path, MeshData(vertices=m.vertices.astype(np.float32), faces=m.faces.astype(np.int32)))
    T = np.eye(4)
    T[:3, 3] = centre
    return RenderScene(meshes=(MeshInstance(name="box", mesh_path=str(path), mesh_key=path.name, pose=as_tuple(T), obj_id=1, inst=0),))


def _analytic_mask(size, centre, cam: CameraIR) -> np.ndarray:
    """Pixels whose centre ray hits the box (exact ray/box slab test in float64)."""
    K = cam.K_array
    R, t = np.asarray(cam.R_w2c), np.asarray(cam.t_w2c)
    u, v = np.meshgrid(np.arange(cam.width), np.arange(cam.height))
    d_cam = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u, dtype=float)], -1)
    d = d_cam @ R  # world directions (R^T d)
    o = -R.T @ t - np.asarray(centre)
    half = np.asarray(size) / 2
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (-half - o) / d, (half - o) / d
    tmin = np.nanmax(np.minimum(t1, t2), axis=-1)
    tmax = np.nanmin(np.maximum(t1, t2), axis=-1)
    return tmax >= np.maximum(tmin, 0)


@pytest.mark.parametrize("size,distance,offset", [
    ((0.005, 0.005, 0.005), 0.06, 0.0),       # a 5 mm object, close
    ((3.0, 3.0, 3.0), 10.0, 0.0),             # a 3 m object, camera 10 m away
    ((0.1, 0.08, 0.06), 0.8, 1000.0),         # 1 km from the origin, re-centred before rendering
    ((1.0, 0.8, 0.6), 10.0, 1000.0),          # 1 km away, camera 10 m from it
])
def test_masks_and_depth_match_the_analytic_projection(tmp_path, size, distance, offset):
    """Property: rasterised mask IoU with the exact ray/box test >= 0.98 (edge pixels may differ) and
    the depth at the centre pixel equals the analytic depth within the 24-bit depth buffer's
    quantisation, z^2/near * 2^-22 (0.2 um at 6 cm, 2.1 mm at 9.5 m with near = 1 cm)."""
    from specsynth.annotate.engine import Annotator

    centre = np.array([offset, -offset, 0.5 * size[2]])
    eye = centre + cameras.spherical_offset(30.0, 35.0, distance)
    R, t = cameras.look_at(eye, centre)
    cam = cameras.camera_ir(INTR, R, t)
    scene = _box_scene(tmp_path, size, centre)
    origin = centre.copy()  # what specsynth.run.worker.Worker.frame does
    ann = Annotator(W, H)
    try:
        ann.load(scene.translated(origin))
        a = ann.annotate(cam.translated(origin), delta=0.005)
    finally:
        ann.close()
    truth = _analytic_mask(size, centre, cam)
    mask = a.masks[0]
    iou = (mask & truth).sum() / max(1, (mask | truth).sum())
    assert truth.sum() > 50 and iou >= 0.98, (iou, truth.sum(), mask.sum())
    # Pose is exact whatever the re-centring: t_m2c is the world centre seen from the camera.
    assert np.allclose(a.instances[0].t_m2c, R @ centre + t, rtol=0, atol=1e-9 * max(1.0, offset))
    v, u = H // 2, W // 2
    if truth[v, u] and mask[v, u]:
        K = cam.K_array
        d_cam = np.array([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], 1.0])
        o = -R.T @ t - centre
        d = R.T @ d_cam
        with np.errstate(divide="ignore"):
            t1, t2 = (-np.asarray(size) / 2 - o) / d, (np.asarray(size) / 2 - o) / d
        z_true = float(np.max(np.minimum(t1, t2)))  # z-depth since d_cam has z = 1
        assert abs(a.depth[v, u] - z_true) <= z_true**2 / cam.near * 2.0**-22 + 1e-6


def test_recentring_is_exact_for_cameras():
    """Property: moving scene and camera together leaves every camera-frame point unchanged (1e-9 m)."""
    R, t = cameras.look_at(np.array([1003.0, -998.0, 2.0]), np.array([1000.0, -1000.0, 0.1]))
    cam = cameras.camera_ir(INTR, R, t)
    o = np.array([1000.0, -1000.0, 0.0])
    moved = cam.translated(o)
    p = np.array([1000.05, -999.97, 0.12])
    assert np.allclose(R @ p + t, np.asarray(moved.R_w2c) @ (p - o) + np.asarray(moved.t_w2c), atol=1e-9)


@pytest.mark.parametrize("scale", [0.1, 0.25, 1.0])
def test_depth_round_trip_and_overflow(scale):
    """Property: |decoded - true| <= depth_scale/2 mm; depth beyond 65535*scale mm is an error, never a wrap."""
    rng = np.random.default_rng(1)
    depth = rng.uniform(0.0, 65535 * scale / 1000.0 * 0.999, size=(64, 64))
    depth[0, 0] = 0.0
    enc, used = encode_depth(depth, scale)
    assert enc.dtype == np.uint16 and used == scale
    err_mm = np.abs(enc.astype(np.float64) * scale - depth * 1000.0)
    assert err_mm[depth > 0].max() <= scale / 2 + 1e-9 and enc[0, 0] == 0
    too_far = depth.copy()
    too_far[3, 3] = 65536 * scale / 1000.0
    with pytest.raises(DepthOverflowError):
        encode_depth(too_far, scale)


@pytest.mark.parametrize("defect", ["zero_area", "duplicate_vertices", "flipped_normals", "open_mesh"])
def test_degenerate_meshes_load_without_nan(tmp_path, defect):
    """Property: a degenerate but non-empty mesh loads to finite geometry and normals (no NaN)."""
    from specsynth.assets.meshio import read_mesh
    from specsynth.assets.resolve import resolve_objects
    from specsynth.spec.models import Objects

    m = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    v, f = m.vertices.copy(), m.faces.copy()
    if defect == "zero_area":
        v = np.vstack([v, [[0.2, 0, 0], [0.2, 0, 0], [0.2, 0, 0]]])
        f = np.vstack([f, [[8, 9, 10]]])
    elif defect == "duplicate_vertices":
        v = np.vstack([v, v])
        f = np.vstack([f, f + 8])
    elif defect == "flipped_normals":
        f = f[:, ::-1]
    elif defect == "open_mesh":
        f = f[:-2]
    path = tmp_path / f"{defect}.ply"
    trimesh.Trimesh(vertices=v, faces=f, process=False).export(path)
    assets = resolve_objects(Objects(meshes=[{"path": str(path), "unit": "m"}]), tmp_path, cache=tmp_path / "cache")
    mesh = read_mesh(assets[0].mesh_path)
    assert np.isfinite(mesh.vertices).all()
    assert mesh.normals is None or np.isfinite(mesh.normals).all()
    assert np.isfinite(assets[0].diameter) and assets[0].diameter > 0


def test_nan_in_a_render_is_a_clear_error():
    """Property: any NaN/Inf pixel of a backend's linear output stops the job with a message naming it."""
    img = np.zeros((4, 4, 3), np.float32)
    check_finite(img, "ok")
    img[1, 2, 0] = np.nan
    img[3, 3, 1] = np.inf
    with pytest.raises(NonFiniteRender, match="2 pixel"):
        check_finite(img, "cycles render of arr=000001/cam=002")


def test_thirty_objects_on_a_small_stage_settle_or_are_reported(tmp_path):
    """Property: 30 objects on a 20x20 cm stage: every kept pose finite, kept + removed == dropped, bounded time."""
    from specsynth.assets.resolve import ObjectAsset
    from specsynth.model.ir import MaterialIR
    from specsynth.physics import arrange
    from specsynth.scenes.types import SceneDesc, Stage
    from specsynth.spec.models import Arrangements

    table = trimesh.creation.box(extents=(0.6, 0.6, 0.04))
    tp = tmp_path / "table.ply"
    write_mesh(tp, MeshData(vertices=table.vertices.astype(np.float32), faces=table.faces.astype(np.int32)))
    T = np.eye(4)
    T[2, 3] = 0.70
    scene = SceneDesc(
        name="t", meshes=(MeshInstance(name="table", mesh_path=str(tp), mesh_key="table", pose=as_tuple(T)),),
        lights=(), world=__import__("specsynth.model.ir", fromlist=["WorldIR"]).WorldIR(),
        stages={"small": Stage("small", ((-0.1, -0.1), (0.1, -0.1), (0.1, 0.1), (-0.1, 0.1)), 0.72)},
    )
    box = trimesh.creation.box(extents=(0.04, 0.03, 0.02))
    bp = tmp_path / "box.ply"
    write_mesh(bp, MeshData(vertices=box.vertices.astype(np.float32), faces=box.faces.astype(np.int32)))
    asset = ObjectAsset(obj_id=1, name="box", mesh_path=str(bp), mesh_key="box", material=MaterialIR(),
                        diameter=0.054, bbox_min=(-0.02, -0.015, -0.01), extents=(0.04, 0.03, 0.02), source="test")
    res = arrange(scene, scene.stages["small"], [asset] * 30, Arrangements(), "random", np.random.default_rng(3))
    assert len(res.placed) + res.removed == 30
    for _, pose in res.placed:
        assert np.isfinite(pose).all() and _orthonormal_err(np.asarray(pose)[:3, :3]) < 1e-6
