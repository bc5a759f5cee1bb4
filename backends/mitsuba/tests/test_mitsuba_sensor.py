"""Mitsuba's exact K sensor (backends/mitsuba/sensor.py): fy != fx, skew, crop; renders <= 64x48."""

from __future__ import annotations

import numpy as np
import pytest

from specsynth.assets.meshio import MeshData, write_mesh
from specsynth.model.ir import CameraIR, LightIR, MaterialIR, MeshInstance, RenderScene, WorldIR, as_tuple
from specsynth.spec.models import QualityPreset
from specsynth.views.cameras import look_at
from specsynth_mitsuba import mapping
from specsynth_mitsuba.sensor import PINHOLE, local_coefficients

# ----------------------------------------------------------------------------- pure numbers


@pytest.mark.parametrize("crop", [((0, 0), (64, 48)), ((5, 7), (20, 11))])
def test_local_coefficients_invert_K(crop):
    """The affine map sample -> Mitsuba-local direction is K^-1 [u, v, 1] with X and Y flipped,
    u = film x - 0.5 (OpenCV pixel centres are integers; film pixel i spans [i, i + 1])."""
    K = np.array([[70.0, 1.3, 27.3], [0, 77.0, 26.1], [0, 0, 1]])
    (ox, oy), (w, h) = crop
    ax, axy, bx, ay, by = local_coefficients(K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1], (ox, oy), (w, h))
    rng = np.random.default_rng(0)
    for sx, sy in rng.uniform(0, 1, size=(20, 2)):
        x, y = ox + sx * w, oy + sy * h  # film position, pixels
        d_cv = np.linalg.solve(K, [x - 0.5, y - 0.5, 1.0])
        got = np.array([ax * sx + axy * sy + bx, ay * sy + by, 1.0])
        np.testing.assert_allclose(got, d_cv * [-1, -1, 1], rtol=0, atol=1e-12)


# ----------------------------------------------------------------------------- renders

mi = pytest.importorskip("mitsuba")


@pytest.fixture(scope="module")
def backend(mitsuba_backend):
    if not mitsuba_backend._dr.is_jit_v(mitsuba_backend._mi.Float):
        pytest.skip("scalar_rgb keeps the perspective sensor (the Python sensor would run per sample)")
    return mitsuba_backend


def _write(tmp, name, mesh: MeshData) -> str:
    p = tmp / f"{name}.ply"
    write_mesh(p, mesh)
    return str(p)


def _sphere(tmp, radius, subdiv=3) -> str:
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=subdiv, radius=radius)
    m = MeshData(vertices=s.vertices.astype(np.float32), faces=s.faces.astype(np.int32), normals=s.vertex_normals.astype(np.float32))
    return _write(tmp, f"sphere_{radius}_{subdiv}", m)


def _quad(tmp) -> str:
    v = np.array([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0.5, 0.5, 0], [-0.5, 0.5, 0]], np.float32)
    m = MeshData(vertices=v, faces=np.array([[0, 1, 2], [0, 2, 3]], np.int32), normals=np.tile(np.array([[0, 0, 1]], np.float32), (4, 1)))
    return _write(tmp, "quad", m)


def _pose(t=(0.0, 0.0, 0.0)) -> tuple:
    T = np.eye(4)
    T[:3, 3] = t
    return as_tuple(T)


def _camera(eye, target, K, W=64, H=48) -> CameraIR:
    R, t = look_at(np.asarray(eye, float), np.asarray(target, float))
    return CameraIR(K=as_tuple(K), width=W, height=H, R_w2c=as_tuple(R), t_w2c=as_tuple(t))


def _spp(n: int) -> QualityPreset:
    return QualityPreset(aa=n, diffuse_rays=1, specular_rays=1, diffuse_depth=1, specular_depth=1, max_depth=2)


def _project(cam: CameraIR, p) -> np.ndarray:
    x = np.asarray(cam.R_w2c) @ np.asarray(p, float) + np.asarray(cam.t_w2c)
    return (cam.K_array @ x)[:2] / x[2]


DIFFUSE = dict(specular=0.0, metallic=0.0, roughness=1.0)
GLOW = MaterialIR(base_color=(0, 0, 0), emission=(20.0, 20.0, 20.0), **DIFFUSE)
# fy = 1.1 fx, off-centre principal point: a square-pixel sensor would be ~1-2 px off at the balls
K_NONSQUARE = np.array([[70.0, 0, 27.3], [0, 77.0, 26.1], [0, 0, 1]])


def _centroid(img: np.ndarray, centre: np.ndarray, r: int = 5) -> np.ndarray:
    x0, y0 = int(round(centre[0])) - r, int(round(centre[1])) - r
    win = img[y0 : y0 + 2 * r + 1, x0 : x0 + 2 * r + 1]
    ys, xs = np.mgrid[y0 : y0 + win.shape[0], x0 : x0 + win.shape[1]]
    return np.array([(win * xs).sum(), (win * ys).sum()]) / win.sum()


@pytest.mark.slow
def test_projection_matches_K_non_square(backend, tmp_path):
    """Tiny emissive balls (one scene, far from the principal point in x and y) land at K @ x
    within 0.15 px with fy = 1.1 fx; the square-pixel perspective would be > 1 px off."""
    cam = _camera((0.3, -1.0, 0.2), (0.0, 0.0, 0.0), K_NONSQUARE)
    ball = _sphere(tmp_path, radius=0.015)
    points = [(0.0, 0.0, 0.0), (0.17, 0.05, 0.19), (-0.2, 0.1, 0.17), (-0.22, 0.1, -0.24), (0.2, -0.1, -0.14)]
    meshes = tuple(MeshInstance(f"b{i}", ball, "ball15mm", _pose(p), GLOW) for i, p in enumerate(points))
    backend.load(RenderScene(meshes=meshes, world=WorldIR(color=(0, 0, 0))))
    r = backend.render(cam, _spp(64), seed=1)
    assert r.stats["sensor"] == PINHOLE and "fy_error_px" not in r.stats
    img = r.linear.mean(axis=2)
    fx, fy, cy = K_NONSQUARE[0, 0], K_NONSQUARE[1, 1], K_NONSQUARE[1, 2]
    for p in points:
        want = _project(cam, p)
        got = _centroid(img, want)
        assert np.abs(got - want).max() < 0.15, (p, got, want)
        if p != points[0]:
            square_error = abs(want[1] - cy) * abs(fy - fx) / fy  # where perspective (fx) puts it
            assert square_error > 1.0, (p, square_error)


@pytest.mark.slow
def test_masks_agree_with_annotation_engine(backend, tmp_path):
    """A 10 cm emissive ball (radius ~7 px) rendered with fy != fx: its coverage > 1/2 mask matches the annotation
    engine's (pyrender, exact K) mask up to silhouette pixels, and the centroids agree."""
    from specsynth.annotate.engine import Annotator

    ann = Annotator(64, 48)
    cam = _camera((0.3, -1.0, 0.2), (0.0, 0.0, 0.0), K_NONSQUARE)
    p = (-0.2, 0.1, -0.22)  # bottom left, ~11.5 px below the principal point row
    ball = MeshInstance("b", _sphere(tmp_path, radius=0.1), "ball10cm", _pose(p), GLOW, obj_id=1, inst=0)
    scene = RenderScene(meshes=(ball,), world=WorldIR(color=(0, 0, 0)))
    try:
        ann.load(scene)
        want = ann.annotate(cam, delta=0.005).masks[0]
    finally:
        ann.close()
    backend.load(scene)
    cover = backend.render(cam, _spp(64), seed=2).linear.mean(axis=2) / 20.0
    got = cover > 0.5
    assert want.sum() > 100
    differ = got ^ want
    # only pixels whose centre is within ~1/2 px of the silhouette may differ
    assert differ.sum() <= 0.1 * want.sum(), differ.sum()
    assert np.all(np.abs(cover[differ] - 0.5) < 0.4)
    ys, xs = np.mgrid[0:48, 0:64]
    c_ann = np.array([xs[want].mean(), ys[want].mean()])
    c_cov = np.array([(cover * xs).sum(), (cover * ys).sum()]) / cover.sum()
    assert np.abs(c_ann - c_cov).max() < 0.2, (c_ann, c_cov)


def _two_view_scene(backend, tmp_path):
    meshes = (
        MeshInstance("floor", _quad(tmp_path), "q", as_tuple(np.diag([4.0, 4.0, 1.0, 1.0])), MaterialIR(**DIFFUSE)),
        MeshInstance("ball", _sphere(tmp_path, 0.3), "s", _pose((0.2, 0, 0.3)), MaterialIR(base_color=(0.8, 0.2, 0.2))),
    )
    backend.load(RenderScene(meshes=meshes, lights=(LightIR(kind="point", pose=_pose((0, 0, 2)), power=200.0),)))
    K = np.array([[60.0, 0, 31.5], [0, 66.0, 23.5], [0, 0, 1]])
    return _camera((0, -2, 1), (0, 0, 0.2), K), _camera((1.5, -1.2, 0.8), (0, 0, 0.2), K)


@pytest.mark.slow
def test_moving_only_the_sensor_non_square(backend, tmp_path):
    """Same contract as test_mitsuba.py::test_moving_only_the_sensor with the K sensor: the pose
    is an opaque parameter, so a new view compiles no kernel; coming back gives the same image."""
    import drjit as dr

    v1, v2 = _two_view_scene(backend, tmp_path)
    scene_before = backend._scene
    a = backend.render(v1, _spp(2), seed=5)
    sensor_before = backend._sensor
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()  # clears it
        b = backend.render(v2, _spp(2), seed=5)
        # A kernel loaded from the on-disk cache (~/.drjit) is new to this process too: with a
        # cold cache it compiles. A pose baked into a kernel as literals would hide that way.
        misses = [
            k for k in dr.kernel_history()
            if k.get("type") == dr.KernelType.JIT and (not k.get("cache_hit") or k.get("cache_disk"))
        ]
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    assert not misses, "a new camera pose compiled (or loaded from disk) a kernel"
    a2 = backend.render(v1, _spp(2), seed=5)
    assert backend._scene is scene_before and backend._sensor is sensor_before
    assert a.stats["sensor"] == PINHOLE
    assert np.abs(a.linear - b.linear).mean() > 0.01
    assert np.array_equal(a.linear, a2.linear)


@pytest.mark.slow
def test_determinism_non_square(backend, tmp_path):
    v1, _ = _two_view_scene(backend, tmp_path)
    a = backend.render(v1, _spp(4), seed=11)
    b = backend.render(v1, _spp(4), seed=11)
    c = backend.render(v1, _spp(4), seed=12)
    assert np.array_equal(a.linear, b.linear) and np.array_equal(a.rgb, b.rgb)
    assert not np.array_equal(a.linear, c.linear)


@pytest.mark.slow
def test_square_pixels_keep_perspective_and_k_sensor_matches_it(backend, tmp_path, monkeypatch):
    """fx == fy renders with Mitsuba's own perspective sensor; the K sensor forced on the same
    camera draws the same samples and gives the same image up to float rounding (same frame, same
    half-pixel convention, same near clip)."""
    v1, _ = _two_view_scene(backend, tmp_path)
    K = np.array([[60.0, 0, 29.2], [0, 60.0, 25.9], [0, 0, 1]])
    cam = CameraIR(K=as_tuple(K), width=64, height=48, R_w2c=v1.R_w2c, t_w2c=v1.t_w2c)
    a = backend.render(cam, _spp(4), seed=3)
    assert a.stats["sensor"] == "perspective" and "fy_error_px" not in a.stats
    monkeypatch.setattr(backend, "_use_k_sensor", lambda sset: True)
    backend._sensor_key = None  # rebuild
    b = backend.render(cam, _spp(4), seed=3)
    backend._sensor_key = None
    assert b.stats["sensor"] == PINHOLE
    assert np.abs(a.linear - b.linear).max() < 1e-4


def test_tiny_aspect_difference_keeps_perspective():
    """Below 1e-3 px of worst-case error the perspective sensor is used (it is exact enough)."""
    K = np.array([[500.0, 0, 31.5], [0, 500.0 * (1 + 1e-6), 23.5], [0, 0, 1]])
    assert mapping.sensor_settings(K, 64, 48).fy_error_px < 1e-3
    K[1, 1] = 501.0
    assert mapping.sensor_settings(K, 64, 48).fy_error_px > 1e-3


def test_crop_window_and_scaled_pose(backend):
    """A crop window renders the corresponding pixels of the full film (the sample is relative to
    the crop window); a to_world with a scale is refused, as Mitsuba's perspective refuses it."""
    scene = mi.load_dict(
        {
            "type": "scene",
            # identity to_world: Mitsuba camera frame = OpenCV with X, Y flipped, so the centre is
            # at (0.1, 0.2, 3) in OpenCV camera coordinates
            "ball": {"type": "sphere", "center": [-0.1, -0.2, 3.0], "radius": 0.6,
                     "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [0.0, 0.0, 0.0]}}},
            "sky": {"type": "constant", "radiance": {"type": "rgb", "value": [1.0, 1.0, 1.0]}},
        }
    )
    integrator = mi.load_dict({"type": "path", "max_depth": 2})

    def sensor(**film):
        return mi.load_dict(
            {
                "type": PINHOLE, "fx": 30.0, "fy": 36.0, "cx": 17.2, "cy": 10.4, "skew": 2.0,
                "film": {"type": "hdrfilm", "width": 32, "height": 24, "rfilter": {"type": "box"}, **film},
                "sampler": {"type": "independent", "sample_count": 64},
            }
        )

    def cover(s):  # black ball in a white sky: ball coverage per pixel
        return 1.0 - np.array(mi.render(scene, sensor=s, integrator=integrator, spp=64))[..., :3].mean(axis=2)

    full = cover(sensor())
    crop = cover(sensor(crop_offset_x=4, crop_offset_y=2, crop_width=26, crop_height=21))
    assert crop.shape == (21, 26)
    ref = full[2:23, 4:30]
    assert ref.sum() > 100 and ref.sum() == pytest.approx(full.sum(), rel=1e-3)  # the ball is inside the crop
    assert np.abs(crop - ref).max() < 0.35  # silhouette pixels: Monte Carlo noise only
    ys, xs = np.mgrid[0:21, 0:26]
    c_crop = np.array([(crop * xs).sum(), (crop * ys).sum()]) / crop.sum()
    c_ref = np.array([(ref * xs).sum(), (ref * ys).sum()]) / ref.sum()
    assert np.abs(c_crop - c_ref).max() < 0.05
    # and the ball's centre is where K puts it: u = fx X/Z + skew Y/Z + cx, v = fy Y/Z + cy
    c_full = np.array([(full * np.mgrid[0:24, 0:32][1]).sum(), (full * np.mgrid[0:24, 0:32][0]).sum()]) / full.sum()
    want = np.array([30.0 * 0.1 / 3 + 2.0 * 0.2 / 3 + 17.2, 36.0 * 0.2 / 3 + 10.4])
    assert np.abs(c_full - want).max() < 0.15, (c_full, want)
    s = sensor()
    params = mi.traverse(s)
    params["to_world"] = mi.Transform4f().scale([2.0, 2.0, 2.0])
    with pytest.raises(ValueError, match="rigid"):
        params.update()
