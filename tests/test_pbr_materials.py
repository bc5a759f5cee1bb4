"""Every PBR channel of the scene IR, rendered for real by Cycles and by Mitsuba at tiny sizes:
normal maps change shading the way their vectors say, roughness maps change a highlight, emission
maps light the surroundings, coverage maps cut holes that the annotation engine sees too."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from specsynth.assets.meshio import MeshData, write_mesh
from specsynth.model.ir import CameraIR, LightIR, MaterialIR, MeshInstance, RenderScene, WorldIR, as_tuple
from specsynth.spec.models import QualityPreset
from specsynth.views.cameras import look_at

pytestmark = pytest.mark.slow


def _quad(tmp, name: str, half: float, z: float = 0.0) -> str:
    v = np.array([[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]], np.float32)
    mesh = MeshData(vertices=v, faces=np.array([[0, 1, 2], [0, 2, 3]], np.int32),
                    normals=np.tile(np.array([[0, 0, 1]], np.float32), (4, 1)),
                    uv=np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32))
    p = tmp / f"{name}.ply"
    write_mesh(p, mesh)
    return str(p)


def _png(tmp, name: str, array: np.ndarray) -> str:
    p = tmp / f"{name}.png"
    Image.fromarray(array.astype(np.uint8)).save(p)
    return str(p)


def _cam(eye, target, f, W, H, up=(0.0, 0.0, 1.0)) -> CameraIR:
    R, t = look_at(np.asarray(eye, float), np.asarray(target, float), up=up)
    K = np.array([[f, 0, (W - 1) / 2], [0, f, (H - 1) / 2], [0, 0, 1]])
    return CameraIR(K=as_tuple(K), width=W, height=H, R_w2c=as_tuple(R), t_w2c=as_tuple(t))


def _q(spp: int, depth: int = 2) -> QualityPreset:
    return QualityPreset(aa=spp, diffuse_rays=1, specular_rays=1, diffuse_depth=depth, specular_depth=depth, max_depth=depth)


def _sun(direction_to_sun) -> LightIR:
    """A sun shining from ``direction_to_sun`` (lights emit along their local -Z)."""
    z = np.asarray(direction_to_sun, float)
    z /= np.linalg.norm(z)
    x = np.cross([0.0, 0.0, 1.0] if abs(z[2]) < 0.99 else [1.0, 0.0, 0.0], z)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    return LightIR(kind="sun", pose=as_tuple(T), power=3.0, sun_angle=1.0)


@pytest.fixture(scope="module", params=["cycles", "mitsuba"])
def backend(request):
    if request.param == "cycles":
        pytest.importorskip("bpy")
        from specsynth_cycles.backend import CyclesBackend

        b = CyclesBackend({"name": "cycles"}, threads=2)
    else:
        pytest.importorskip("mitsuba")
        from specsynth_mitsuba.backend import MitsubaBackend

        b = MitsubaBackend({"variant": "auto"}, threads=2)
    yield b
    b.close()


def _render(backend, meshes, lights=(), world=WorldIR(color=(0.0, 0.0, 0.0)), cam=None, spp=16, depth=2):
    backend.load(RenderScene(meshes=tuple(meshes), lights=tuple(lights), world=world))
    cam = cam or _cam((0, 0, 3.0), (0, 0.001, 0), 40.0, 24, 24, up=(0, 1, 0))
    return backend.render(cam, _q(spp, depth), seed=3).linear.mean(2)


def _normal_map(tmp, tilt) -> str:
    n = np.array([tilt[0], tilt[1], 1.0])
    n /= np.linalg.norm(n)
    return _png(tmp, f"n_{tilt[0]}_{tilt[1]}", np.tile(np.rint((n * 0.5 + 0.5) * 255), (8, 8, 1)))


@pytest.mark.parametrize("axis", [0, 1])  # 0: red = +u = +x; 1: green = +v = +y (OpenGL maps)
def test_normal_map_turns_the_surface_towards_its_vectors(backend, tmp_path, axis):
    plane = _quad(tmp_path, "plane", 1.0)
    sun_dir = [0.0, 0.0, 0.6]
    sun_dir[axis] = 1.0
    toward, away = [0.0, 0.0], [0.0, 0.0]
    toward[axis], away[axis] = 0.6, -0.6
    lum = {}
    for name, tilt in (("flat", (0.0, 0.0)), ("toward", tuple(toward)), ("away", tuple(away))):
        mat = MaterialIR(base_color=(0.6,) * 3, specular=0.0, roughness=1.0, use_vertex_colors=False,
                         normal_texture=None if name == "flat" else _normal_map(tmp_path, tilt))
        img = _render(backend, [MeshInstance("p", plane, "plane", as_tuple(np.eye(4)), mat)], [_sun(sun_dir)])
        lum[name] = float(img[8:16, 8:16].mean())
    assert lum["toward"] > 1.15 * lum["flat"] > 1.15 * 1.15 * lum["away"], lum


def test_roughness_map_sharpens_a_highlight(backend, tmp_path):
    plane = _quad(tmp_path, "plane", 1.0)
    light = LightIR(kind="point", pose=as_tuple(np.array([[1, 0, 0, -0.6], [0, 1, 0, 0], [0, 0, 1, 1.2], [0, 0, 0, 1]], float)), power=40.0)
    cam = _cam((0.6, 0, 1.2), (0, 0, 0), 40.0, 24, 24)  # mirror direction of the light
    peaks = {}
    for r in (0.1, 0.9):
        mat = MaterialIR(base_color=(0.2,) * 3, roughness=0.5, specular=1.0, use_vertex_colors=False,
                         roughness_texture=_png(tmp_path, f"r{r}", np.full((8, 8), round(r * 255))))
        peaks[r] = float(_render(backend, [MeshInstance("p", plane, "plane", as_tuple(np.eye(4)), mat)], [light], cam=cam,
                                 spp=32).max())
    assert peaks[0.1] > 3.0 * peaks[0.9], peaks


def test_emission_map_lights_the_floor(backend, tmp_path):
    floor = MeshInstance("floor", _quad(tmp_path, "floor", 1.5), "floor", as_tuple(np.eye(4)),
                         MaterialIR(base_color=(0.8,) * 3, specular=0.0, roughness=1.0, use_vertex_colors=False))
    T = np.diag([1.0, -1.0, -1.0, 1.0])  # the lamp faces down, at the floor
    T[:3, 3] = (0.0, 0.0, 0.5)
    floor_pixels = {}
    for name, tex in (("white", 255), ("black", 0)):
        lamp_mat = MaterialIR(base_color=(0.0,) * 3, specular=0.0, use_vertex_colors=False, emission=(4.0, 4.0, 4.0),
                              emission_texture=_png(tmp_path, f"e{name}", np.full((8, 8, 3), tex)))
        lamp = MeshInstance("lamp", _quad(tmp_path, "lamp", 0.2), "lamp", as_tuple(T), lamp_mat)
        img = _render(backend, [floor, lamp], cam=_cam((1.2, -1.2, 1.2), (0, 0, 0), 20.0, 24, 24), spp=32)
        floor_pixels[name] = float(np.median(img))  # most pixels are floor, lit by the lamp alone
    assert floor_pixels["white"] > 0.005 and floor_pixels["black"] < 0.0005, floor_pixels


def test_coverage_map_cuts_holes_in_the_image_and_the_labels(backend, tmp_path):
    """A card, opaque on its left half only, in front of a lit object: the RGB shows the object
    through the right half, and the annotation engine sees it there too."""
    from specsynth.annotate.engine import Annotator

    obj = MeshInstance("obj", _quad(tmp_path, "obj", 0.5), "obj", as_tuple(np.eye(4)),
                       MaterialIR(base_color=(0.9, 0.1, 0.1), specular=0.0, use_vertex_colors=False), obj_id=1, inst=0)
    coverage = np.zeros((8, 8), np.uint8)
    coverage[:, :4] = 255  # u < 0.5 opaque
    T = np.eye(4)
    T[:3, 3] = (0.0, 0.0, 0.4)
    card_mat = MaterialIR(base_color=(0.1, 0.1, 0.9), specular=0.0, use_vertex_colors=False, alpha_mode="mask",
                          opacity_texture=_png(tmp_path, "cov", coverage))
    card = MeshInstance("card", _quad(tmp_path, "card", 0.8), "card", as_tuple(T), card_mat)
    cam = _cam((0, 0, 3.0), (0, 0.001, 0), 40.0, 24, 24, up=(0, 1, 0))
    world = WorldIR(color=(1.0, 1.0, 1.0))
    backend.load(RenderScene(meshes=(obj, card), world=world))
    rgb = backend.render(cam, _q(16), seed=3).linear
    ann = Annotator(24, 24)
    try:
        ann.load(RenderScene(meshes=(obj, card), world=world))
        a = ann.annotate(cam, delta=0.005)
    finally:
        ann.close()
    full, visib = a.masks[0], a.masks_visib[0]
    cols = np.nonzero(full.any(0))[0]
    assert len(cols) > 6
    left, right = cols[: len(cols) // 2 - 1], cols[len(cols) // 2 + 1 :]
    # Image x grows with world x here; u grows with x: the card hides the object's left half only.
    assert not visib[:, left].any() and visib[:, right][full[:, right]].all()
    red = (rgb[..., 0] > 2 * rgb[..., 2])
    blue = (rgb[..., 2] > 2 * rgb[..., 0])
    assert red[:, right][full[:, right]].mean() > 0.9 and blue[:, left][full[:, left]].mean() > 0.9


def test_mitsuba_denoise_brings_a_noisy_render_near_the_reference(tmp_path):
    """`denoise` on Mitsuba (pyoidn with albedo and normal AOVs): 1 spp + OIDN is much closer to a
    1024 spp reference than 1 spp alone, as Cycles' OIDN is."""
    pytest.importorskip("mitsuba")
    pytest.importorskip("pyoidn")
    from specsynth_mitsuba.backend import MitsubaBackend

    floor = MeshInstance("f", _quad(tmp_path, "floor", 1.5), "floor", as_tuple(np.eye(4)),
                         MaterialIR(base_color=(0.7, 0.5, 0.3), specular=0.3, roughness=0.6, use_vertex_colors=False))
    T = np.eye(4)
    T[:3, 3] = (0.0, 0.0, 0.25)
    card = MeshInstance("c", _quad(tmp_path, "card", 0.2), "card", as_tuple(T),
                        MaterialIR(base_color=(0.2, 0.6, 0.3), specular=0.0, use_vertex_colors=False))
    L = np.eye(4)
    L[:3, 3] = (0.2, 0.1, 0.9)
    light = LightIR(kind="area", pose=as_tuple(L), power=40.0, size=(0.6, 0.6))  # soft shadows: noisy at 1 spp
    scene = RenderScene(meshes=(floor, card), lights=(light,), world=WorldIR(color=(0.05, 0.05, 0.06)))
    cam = _cam((0.9, -0.9, 1.1), (0, 0, 0), 80.0, 96, 72)
    plain, noisy_dn = (MitsubaBackend({"variant": "auto", "denoise": d}, threads=2) for d in (False, True))
    try:
        for b in (plain, noisy_dn):
            b.load(scene)
        ref = plain.render(cam, _q(1024, 3), seed=9).linear
        raw = plain.render(cam, _q(1, 3), seed=1).linear
        den = noisy_dn.render(cam, _q(1, 3), seed=1)
    finally:
        plain.close()
        noisy_dn.close()
    mse = lambda a: float(((a - ref) ** 2).mean())  # noqa: E731
    assert den.stats["denoise_seconds"] >= 0 and mse(den.linear) < mse(raw) / 3, (mse(den.linear), mse(raw))
