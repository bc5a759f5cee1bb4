"""Mitsuba backend: the mapping (no renderer needed) and small renders (64x48 or less)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from specsynth.assets.meshio import MeshData, write_mesh
from specsynth.model.ir import CameraIR, LightIR, MaterialIR, MeshInstance, RenderScene, WorldIR, as_tuple
from specsynth.spec.models import PAPER_PRESETS, QualityPreset
from specsynth.views.cameras import look_at
from specsynth_mitsuba import mapping

# ----------------------------------------------------------------------------- pure mapping


@pytest.mark.parametrize(("level", "spp", "depth"), [("low", 1, 4), ("medium", 36, 5), ("high", 225, 6)])
def test_quality_mapping(level, spp, depth):
    st = mapping.integrator_settings(PAPER_PRESETS[level])
    assert (st.spp, st.max_depth, st.rr_depth) == (spp, depth, depth)


def test_samples_override_and_sampler_rounding():
    assert mapping.integrator_settings(PAPER_PRESETS["high"], samples=7).spp == 7
    assert [mapping.round_spp(n, "ldsampler") for n in (1, 4, 9, 36, 225)] == [4, 4, 16, 64, 256]
    assert [mapping.round_spp(n, "stratified") for n in (1, 3, 9, 36, 37)] == [1, 4, 9, 36, 49]
    assert mapping.round_spp(37, "independent") == 37


@pytest.mark.parametrize("sampler", ["stratified", "ldsampler", "multijitter", "orthogonal"])
def test_the_rounding_is_mitsubas_own(sampler):
    """round_spp says the count Mitsuba's sampler takes, for every count asked up to 399 (in a child
    process: choosing a Mitsuba variant is global state)."""
    import json
    import subprocess
    import sys

    code = ("import json, mitsuba as mi; mi.set_variant('scalar_rgb'); mi.set_log_level(mi.LogLevel.Error); "
            f"print(json.dumps([mi.load_dict({{'type': '{sampler}', 'sample_count': n}}).sample_count() "
            "for n in range(1, 400)]))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=True)
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert got == [mapping.round_spp(n, sampler) for n in range(1, 400)]


def test_principal_point_offsets_centre_is_zero():
    W, H = 64, 48
    K = np.array([[50.0, 0, (W - 1) / 2], [0, 50.0, (H - 1) / 2], [0, 0, 1]])
    s = mapping.sensor_settings(K, W, H)
    assert abs(s.ppo_x) < 1e-12 and abs(s.ppo_y) < 1e-12
    assert s.x_fov == pytest.approx(math.degrees(2 * math.atan(W / 100.0)))
    assert s.fy_error_px == 0.0


def test_seed_folding_uses_high_bits():
    assert mapping.fold_seed(5) != mapping.fold_seed(5 + (1 << 40))
    assert 0 <= mapping.fold_seed(2**63 - 1) < 2**32


def test_light_units():
    assert mapping.area_radiance(math.pi, (1.0, 1.0), (1, 1, 1)) == pytest.approx([1.0] * 3)
    assert mapping.point_intensity(4 * math.pi, (1, 0.5, 0)) == pytest.approx([1.0, 0.5, 0.0])
    # the envmap basis is a rotation (a mirror would flip the sky's handedness)
    assert np.linalg.det(mapping.envmap_to_world(30.0)[:3, :3]) == pytest.approx(1.0)


# ----------------------------------------------------------------------------- renders

mi = pytest.importorskip("mitsuba")


@pytest.fixture(scope="module")
def backend(mitsuba_backend):
    return mitsuba_backend


def _write(tmp, name, mesh: MeshData) -> str:
    p = tmp / f"{name}.ply"
    write_mesh(p, mesh)
    return str(p)


def _sphere(tmp, radius=1.0, subdiv=4) -> str:
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=subdiv, radius=radius)
    return _write(
        tmp,
        f"sphere_{radius}_{subdiv}",
        MeshData(
            vertices=s.vertices.astype(np.float32),
            faces=s.faces.astype(np.int32),
            normals=s.vertex_normals.astype(np.float32),
        ),
    )


def _quad(tmp, colors=None, uv=False) -> str:
    """Unit square in the XY plane (z = 0), normal +Z, UV (0,0) at (-0.5,-0.5)."""
    v = np.array([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0.5, 0.5, 0], [-0.5, 0.5, 0]], np.float32)
    return _write(
        tmp,
        f"quad_{colors is not None}_{uv}",
        MeshData(
            vertices=v,
            faces=np.array([[0, 1, 2], [0, 2, 3]], np.int32),
            normals=np.tile(np.array([[0, 0, 1]], np.float32), (4, 1)),
            uv=(v[:, :2] + 0.5) if uv else None,
            colors=colors,
        ),
    )


def _pose(t=(0.0, 0.0, 0.0)) -> tuple:
    T = np.eye(4)
    T[:3, 3] = t
    return as_tuple(T)




def _camera(eye, target, K=None, W=64, H=48) -> CameraIR:
    R, t = look_at(np.asarray(eye, float), np.asarray(target, float))
    if K is None:
        K = np.array([[60.0, 0, 31.5], [0, 60.0, 23.5], [0, 0, 1]])
    return CameraIR(K=as_tuple(K), width=W, height=H, R_w2c=as_tuple(R), t_w2c=as_tuple(t))


def _spp(n: int) -> QualityPreset:
    return QualityPreset(aa=n, diffuse_rays=1, specular_rays=1, diffuse_depth=1, specular_depth=1, max_depth=2)


DIFFUSE = dict(specular=0.0, metallic=0.0, roughness=1.0)


def test_variant_is_reported(backend):
    assert backend.variant in ("cuda_ad_rgb", "llvm_ad_rgb", "scalar_rgb")
    assert backend.variant in backend.version()


def test_a_variant_that_cannot_run_here_is_a_clear_error():
    """Asking for CUDA without a GPU names the option and the fix when the backend starts, instead
    of a Dr.Jit error in every render; an explicit variant that runs here is used as asked."""
    import mitsuba as mi

    from specsynth_mitsuba import variant

    if variant._gpu_plausible():
        pytest.skip("this machine has an NVIDIA driver")
    with pytest.raises(RuntimeError, match=r"backend.variant is 'cuda_ad_rgb', but this machine has no NVIDIA"):
        variant.choose_variant("cuda_ad_rgb")
    with pytest.raises(RuntimeError, match=r"backend.variant is 'cuda_rgb': not in this Mitsuba build"):
        variant.choose_variant("cuda_rgb")
    if "llvm_ad_rgb" in mi.variants():
        assert variant.choose_variant("llvm_ad_rgb") == ("llvm_ad_rgb", {})


@pytest.mark.slow
def test_white_furnace(backend, tmp_path):
    """Convex Lambertian sphere, albedo 0.5, uniform radiance-1 world: every sphere pixel is 0.5."""
    mesh = MeshInstance("ball", _sphere(tmp_path), "sphere", _pose(), MaterialIR(base_color=(0.5,) * 3, **DIFFUSE))
    backend.load(RenderScene(meshes=(mesh,), world=WorldIR(kind="color", color=(1.0, 1.0, 1.0))))
    K = np.array([[40.0, 0, 15.5], [0, 40.0, 15.5], [0, 0, 1]])
    r = backend.render(_camera((0, -4, 0), (0, 0, 0), K, 32, 32), _spp(256), seed=3)
    assert r.stats["variant"] == backend.variant and r.stats["spp"] == 256
    centre = r.linear[10:22, 10:22]  # well inside the silhouette (radius ~10 px)
    assert centre.mean() == pytest.approx(0.5, rel=0.01)
    assert r.linear[0, 0].mean() == pytest.approx(1.0, rel=1e-3)  # the world itself
    assert r.rgb.dtype == np.uint8 and r.linear.dtype == np.float32


@pytest.mark.slow
def test_projection_matches_K(backend, tmp_path):
    """An emissive 1 cm ball's image centroid lands at K @ x within 0.5 px, with an off-centre
    principal point so the offsets' sign and half-pixel convention are both exercised."""
    K = np.array([[80.0, 0, 27.3], [0, 80.0, 26.1], [0, 0, 1]])
    cam = _camera((0.3, -1.0, 0.2), (0.0, 0.0, 0.0), K)
    R, t = np.asarray(cam.R_w2c), np.asarray(cam.t_w2c)
    ball = _sphere(tmp_path, radius=0.01, subdiv=3)
    for p in [(0.0, 0.0, 0.0), (0.12, 0.05, 0.1), (-0.2, 0.1, -0.05)]:
        mat = MaterialIR(base_color=(0, 0, 0), emission=(50.0, 50.0, 50.0), **DIFFUSE)
        backend.load(RenderScene(meshes=(MeshInstance("b", ball, "ball", _pose(p), mat),), world=WorldIR(color=(0, 0, 0))))
        img = backend.render(cam, _spp(64), seed=1).linear.mean(axis=2)
        ys, xs = np.mgrid[0 : img.shape[0], 0 : img.shape[1]]
        got = np.array([(img * xs).sum(), (img * ys).sum()]) / img.sum()
        x = R @ np.asarray(p) + t
        want = (K @ x)[:2] / x[2]
        assert np.abs(got - want).max() < 0.5, (p, got, want)


@pytest.mark.slow
def test_determinism(backend, tmp_path):
    mesh = MeshInstance("ball", _sphere(tmp_path, 0.3), "s", _pose(), MaterialIR(base_color=(0.6, 0.3, 0.2), roughness=0.3))
    light = LightIR(kind="area", pose=_pose((0, 0, 1.0)), power=20.0, size=(0.3, 0.3))
    backend.load(RenderScene(meshes=(mesh,), lights=(light,), world=WorldIR(color=(0.1, 0.1, 0.1))))
    cam = _camera((0, -1.5, 0.5), (0, 0, 0))
    a = backend.render(cam, _spp(4), seed=11)
    b = backend.render(cam, _spp(4), seed=11)
    c = backend.render(cam, _spp(4), seed=12)
    assert np.array_equal(a.linear, b.linear) and np.array_equal(a.rgb, b.rgb)
    assert not np.array_equal(a.linear, c.linear)


@pytest.mark.slow
def test_moving_only_the_sensor(backend, tmp_path):
    """Views of one arrangement: no reload, a different image, the same image when coming back,
    and (JIT variants) no new kernel compilation for the new pose."""
    import drjit as dr

    meshes = (
        MeshInstance("floor", _quad(tmp_path), "q", as_tuple(np.diag([4.0, 4.0, 1.0, 1.0])), MaterialIR(**DIFFUSE)),
        MeshInstance("ball", _sphere(tmp_path, 0.3), "s", _pose((0.2, 0, 0.3)), MaterialIR(base_color=(0.8, 0.2, 0.2))),
    )
    backend.load(RenderScene(meshes=meshes, lights=(LightIR(kind="point", pose=_pose((0, 0, 2)), power=200.0),)))
    scene_before = backend._scene
    v1, v2 = _camera((0, -2, 1), (0, 0, 0.2)), _camera((1.5, -1.2, 0.8), (0, 0, 0.2))
    a = backend.render(v1, _spp(2), seed=5)
    jit = dr.is_jit_v(mi.Float)
    if jit:
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        dr.kernel_history()  # clears it
    b = backend.render(v2, _spp(2), seed=5)
    if jit:
        misses = [k for k in dr.kernel_history() if k.get("type") == dr.KernelType.JIT
                  # a kernel loaded from ~/.drjit counts as a hit: that is still a per-view compilation
                  # key (e.g. a pose baked in as literals), so it is a miss here
                  and (not k.get("cache_hit") or k.get("cache_disk"))]
        dr.set_flag(dr.JitFlag.KernelHistory, False)
        assert not misses, "a new camera pose recompiled a kernel"
    a2 = backend.render(v1, _spp(2), seed=5)
    assert backend._scene is scene_before
    assert np.abs(a.linear - b.linear).mean() > 0.01
    assert np.array_equal(a.linear, a2.linear)


@pytest.mark.slow
def test_vertex_colours_and_texture_orientation(backend, tmp_path):
    """A Lambertian quad facing the camera in a uniform radiance-1 world renders its albedo, so
    colours are checked in linear units; the texture's top row must appear at the top."""
    from PIL import Image

    # looks down -Z with image up = world +Y; the 1 m quad covers pixels ~9..23
    R, _ = look_at(np.array([0.0, 0, 3]), np.zeros(3), up=np.array([0.0, 1, 0]))
    K = np.array([[40.0, 0, 15.5], [0, 40.0, 15.5], [0, 0, 1]])
    cam = CameraIR(K=as_tuple(K), width=32, height=32, R_w2c=as_tuple(R), t_w2c=as_tuple(-R @ np.array([0, 0, 3.0])))
    world = WorldIR(kind="color", color=(1.0, 1.0, 1.0))

    cols = np.tile(np.array([[255, 128, 0, 255]], np.uint8), (4, 1))
    quad = MeshInstance("q", _quad(tmp_path, colors=cols), "qc", _pose(), MaterialIR(base_color=(1, 1, 1), **DIFFUSE))
    backend.load(RenderScene(meshes=(quad,), world=world))
    px = backend.render(cam, _spp(64), seed=2).linear[12:20, 12:20].reshape(-1, 3).mean(0)
    want = [1.0, (128 / 255 + 0.055) ** 2.4 / 1.055**2.4, 0.0]
    assert px == pytest.approx(want, abs=0.02)

    tex = np.zeros((8, 8, 3), np.uint8)
    tex[:4] = (255, 0, 0)  # top rows red
    tex[4:] = (0, 255, 0)
    tp = tmp_path / "tex.png"
    Image.fromarray(tex).save(tp)
    quad = MeshInstance("q", _quad(tmp_path, uv=True), "qt", _pose(), MaterialIR(texture=str(tp), base_color=(1, 1, 1), **DIFFUSE))
    backend.load(RenderScene(meshes=(quad,), world=world))
    img = backend.render(cam, _spp(16), seed=2).linear
    top, bottom = img[11:14, 13:19].reshape(-1, 3).mean(0), img[18:21, 13:19].reshape(-1, 3).mean(0)
    assert top[0] > 0.9 and top[1] < 0.05, top
    assert bottom[1] > 0.9 and bottom[0] < 0.05, bottom


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["area", "point"])
def test_light_units_render(backend, tmp_path, kind):
    """Irradiance below a light at distance d, on a Lambertian floor of albedo rho:
    area (small, facing down): E = P / (pi d^2); point: E = P / (4 pi d^2); L_out = rho E / pi."""
    d, rho = 1.0, 0.5
    floor = MeshInstance("f", _quad(tmp_path), "q", as_tuple(np.diag([0.2, 0.2, 1.0, 1.0])), MaterialIR(base_color=(rho,) * 3, **DIFFUSE))
    P = 10.0
    light = LightIR(kind=kind, pose=_pose((0, 0, d)), power=P, size=(0.02, 0.02))
    backend.load(RenderScene(meshes=(floor,), lights=(light,), world=WorldIR(color=(0, 0, 0))))
    R, _ = look_at(np.array([0, -0.3, 0.5]), np.zeros(3))
    cam = CameraIR(
        K=as_tuple(np.array([[60.0, 0, 31.5], [0, 60.0, 23.5], [0, 0, 1]])), width=64, height=48,
        R_w2c=as_tuple(R), t_w2c=as_tuple(-R @ np.array([0, -0.3, 0.5])),
    )
    img = backend.render(cam, _spp(64), seed=4).linear
    E = P / (math.pi * d * d) if kind == "area" else P / (4 * math.pi * d * d)
    centre = img[22:26, 30:34].mean()  # the floor point under the light projects to ~(31.5, 23.5)
    assert centre == pytest.approx(rho * E / math.pi, rel=0.03)


@pytest.mark.slow
def test_clamp_is_reported_not_silent(backend, tmp_path):
    mesh = MeshInstance("ball", _sphere(tmp_path, 0.3, 2), "s", _pose(), MaterialIR(**DIFFUSE))
    backend.load(RenderScene(meshes=(mesh,), world=WorldIR(color=(0.5, 0.5, 0.5))))
    with pytest.warns(UserWarning, match="clamp"):
        r = backend.render(_camera((0, -2, 0), (0, 0, 0)), _spp(1), seed=0, clamp=10.0)
    assert r.stats["clamp_ignored"] == 10.0


@pytest.mark.slow
def test_vertex_colour_times_texture(backend, tmp_path):
    """base_color x vertex colour x texture, the Cycles backend's product."""
    from PIL import Image

    R, _ = look_at(np.array([0.0, 0, 3]), np.zeros(3), up=np.array([0.0, 1, 0]))
    K = np.array([[40.0, 0, 15.5], [0, 40.0, 15.5], [0, 0, 1]])
    cam = CameraIR(K=as_tuple(K), width=32, height=32, R_w2c=as_tuple(R), t_w2c=as_tuple(-R @ np.array([0, 0, 3.0])))
    tp = tmp_path / "grey.png"
    Image.fromarray(np.full((4, 4, 3), 255, np.uint8)).save(tp)
    cols = np.tile(np.array([[255, 255, 0, 255]], np.uint8), (4, 1))
    mat = MaterialIR(base_color=(0.5, 0.25, 1.0), texture=str(tp), **DIFFUSE)
    quad = MeshInstance("q", _quad(tmp_path, colors=cols, uv=True), "qct", _pose(), mat)
    backend.load(RenderScene(meshes=(quad,), world=WorldIR(kind="color", color=(1.0, 1.0, 1.0))))
    px = backend.render(cam, _spp(64), seed=2).linear[12:20, 12:20].reshape(-1, 3).mean(0)
    assert px == pytest.approx([0.5, 0.25, 0.0], abs=0.02)


def test_sun_and_spot_conventions():
    assert mapping.sun_direction(0.0, 0.0) == pytest.approx([0.0, 1.0, 0.0], abs=1e-12)
    assert mapping.sun_direction(0.0, 90.0) == pytest.approx([-1.0, 0.0, 0.0], abs=1e-12)
    assert mapping.sun_direction(90.0, 33.0)[2] == pytest.approx(1.0)
    cutoff, beam = mapping.spot_angles(60.0, 0.0)
    assert cutoff == pytest.approx(30.0) and beam == pytest.approx(30.0)
    assert mapping.spot_angles(60.0, 1.0)[1] == pytest.approx(0.0, abs=1e-6)


def kernel_misses(tmp: str) -> list[dict]:
    """Kernels compiled (or loaded from ~/.drjit) while a second and a third arrangement of the same
    structure as the first are loaded and rendered by one new backend; run in a process of its own
    (``test_new_arrangement_reuses_kernels``)."""
    import dataclasses
    from pathlib import Path

    import drjit as dr

    from specsynth_mitsuba.backend import MitsubaBackend

    tmp_path = Path(tmp)
    floor = MeshInstance("floor", _quad(tmp_path), "q", as_tuple(np.diag([4.0, 4.0, 1.0, 1.0])), MaterialIR(**DIFFUSE))
    ball = MeshInstance("ball", _sphere(tmp_path, 0.3, 2), "s", _pose((0.2, 0, 0.3)), MaterialIR(base_color=(0.8, 0.2, 0.2)))
    light = LightIR(kind="area", pose=_pose((0, 0, 2)), power=50.0)
    cam = _camera((0, -2, 1), (0, 0, 0.2))
    moved = dataclasses.replace(ball, pose=_pose((-0.1, 0.1, 0.3)), material=MaterialIR(base_color=(0.1, 0.5, 0.9)))
    backend = MitsubaBackend({"variant": "auto"}, threads=2)  # (sets the variant)
    try:
        if not dr.is_jit_v(mi.Float):
            return []  # the scalar variant has no kernels
        backend.load(RenderScene(meshes=(floor, ball), lights=(light,)))
        backend.render(cam, _spp(2), seed=1)
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        dr.kernel_history()
        for _ in range(2):
            backend.load(RenderScene(meshes=(floor, moved), lights=(light,)))
            backend.render(cam, _spp(2), seed=1)
        # a kernel loaded from ~/.drjit counts as a hit: that is still a per-view compilation key
        # (e.g. a pose baked in as literals), so it is a miss here
        return [{key: k.get(key) for key in ("hash", "operation_count", "cache_disk", "cache_hit", "size")}
                for k in dr.kernel_history() if k.get("type") == dr.KernelType.JIT
                and (not k.get("cache_hit") or k.get("cache_disk"))]
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
        backend.close()


@pytest.mark.slow
def test_new_arrangement_reuses_kernels(tmp_path):
    """A new arrangement with the same structure (moved objects, other colours) must not
    recompile: kernels key on the order of the objects' registry ids, which load() keeps stable
    (it frees the old scene first and loads serially: parallel loading created the emitters in a
    varying order, and about every other run compiled the render kernel again at the second
    arrangement). In a process of its own, as a worker's."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    code = (f"import sys, json; sys.path.insert(0, {str(Path(__file__).parent)!r}); import test_mitsuba; "
            f"print(json.dumps(test_mitsuba.kernel_misses({str(tmp_path)!r}), default=str))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    misses = json.loads(out.stdout.strip().splitlines()[-1])
    assert not misses, misses


@given(st.integers(1, 5000), st.integers(1, 5000))
def test_guide_samples_are_at_least_the_images_and_grow_with_them(a, b):
    lo, hi = sorted((a, b))
    g = mapping.guide_samples(lo)
    assert g >= lo and g <= max(lo, mapping.GUIDE_SAMPLES) and g <= mapping.GUIDE_FACTOR * lo
    assert mapping.guide_samples(hi) >= g  # more samples never get coarser guides
    assert mapping.guide_samples(1) == 16 and mapping.guide_samples(4) == 64 and mapping.guide_samples(225) == 225


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-10, 10), min_size=9, max_size=9))
def test_mesh_normals_use_the_exact_inverse(entries):
    """build_mesh's 3x3 inverse (cofactors, not LAPACK) equals numpy's wherever numpy's is finite."""
    from specsynth_mitsuba.scene import _inverse3

    R = np.asarray(entries, np.float64).reshape(3, 3)
    assume(abs(np.linalg.det(R)) > 1e-3 * max(1.0, np.abs(R).max()) ** 3)
    assert np.allclose(_inverse3(R), np.linalg.inv(R), rtol=1e-7, atol=1e-9 * np.abs(np.linalg.inv(R)).max())


@pytest.mark.slow
def test_parts_sharing_a_texture_render_as_with_their_own(backend, tmp_path, monkeypatch):
    """A scene whose parts share one texture decodes it once, and the next scene reuses what it
    shares with the last; each part still gets its own base-colour factor (the render equals the
    one with the texture copied per part)."""
    import shutil

    from PIL import Image

    tex = tmp_path / "t.png"
    Image.fromarray((np.indices((16, 16)).sum(0) % 2 * 200 + 30).astype(np.uint8)).convert("RGB").save(tex)
    copy = tmp_path / "t2.png"
    shutil.copy(tex, copy)
    light = LightIR(kind="area", pose=_pose((0, 0, 2)), power=80.0)
    cam = _camera((0, -2, 1.5), (0, 0, 0))

    def scene(second: str):
        a = MeshInstance("a", _quad(tmp_path, uv=True), "qa", _pose((-0.6, 0, 0)),
                         MaterialIR(texture=str(tex), base_color=(1.0, 0.5, 0.5)))
        b = MeshInstance("b", _quad(tmp_path, uv=True), "qb", _pose((0.6, 0, 0)),
                         MaterialIR(texture=second, base_color=(0.5, 0.5, 1.0)))
        return RenderScene(meshes=(a, b), lights=(light,))

    from specsynth_mitsuba import scene as scene_mod

    decodes = []
    real = scene_mod._linear_rgb
    monkeypatch.setattr(scene_mod, "_linear_rgb", lambda mi_, path: decodes.append(path) or real(mi_, path))
    backend.load(scene(str(tex)))
    shared = backend.render(cam, _spp(4), seed=3).linear
    assert decodes == [str(tex)]
    backend.load(scene(str(copy)))
    own = backend.render(cam, _spp(4), seed=3).linear
    assert decodes[1:] == [str(copy)] and np.array_equal(shared, own)


def test_eight_bit_textures_decode_exactly_as_the_srgb_curve():
    from specsynth.model.colour import srgb_to_linear
    from specsynth_mitsuba.scene import _SRGB8_TO_LINEAR

    codes = np.arange(256, dtype=np.float32)
    assert _SRGB8_TO_LINEAR.dtype == np.float32
    assert np.array_equal(_SRGB8_TO_LINEAR, srgb_to_linear(codes / 255.0))


def test_a_load_keeps_only_its_own_meshes(backend, tmp_path):
    """With a new room per arrangement the mesh cache must not grow with every load."""
    light = LightIR(kind="area", pose=_pose((0, 0, 2)), power=80.0)
    for k in range(3):
        quad = MeshInstance("q", _quad(tmp_path, uv=True), f"quad{k}", _pose((0, 0, 0)), MaterialIR())
        backend.load(RenderScene(meshes=(quad,), lights=(light,)))
        assert set(backend._mesh_cache) == {f"quad{k}"}


@pytest.mark.slow
def test_denoise_brings_a_noisy_render_near_the_reference(tmp_path):
    """`denoise` (pyoidn with albedo and normal AOVs): 1 spp + OIDN is much closer to a 1024 spp
    reference than 1 spp alone, as Cycles' OIDN is."""
    pytest.importorskip("pyoidn")
    from dataclasses import replace

    from specsynth.testing.materials import camera, quad, quality
    from specsynth_mitsuba.backend import MitsubaBackend

    floor = replace(quad(tmp_path, "floor", 1.5),
                    material=MaterialIR(base_color=(0.7, 0.5, 0.3), specular=0.3, roughness=0.6, use_vertex_colors=False))
    card = replace(quad(tmp_path, "card", 0.2), pose=_pose((0.0, 0.0, 0.25)),
                   material=MaterialIR(base_color=(0.2, 0.6, 0.3), specular=0.0, use_vertex_colors=False))
    light = LightIR(kind="area", pose=_pose((0.2, 0.1, 0.9)), power=40.0, size=(0.6, 0.6))  # soft shadows: noisy at 1 spp
    scene = RenderScene(meshes=(floor, card), lights=(light,), world=WorldIR(color=(0.05, 0.05, 0.06)))
    cam = camera((0.9, -0.9, 1.1), (0, 0, 0), 80.0, 96, 72)
    plain, noisy_dn, clean_guides = (MitsubaBackend({"variant": "auto", **o}, threads=2) for o in (
        {"denoise": False}, {"denoise": True, "denoise_prefilter": "fast"}, {"denoise": True}))
    try:
        for b in (plain, noisy_dn, clean_guides):
            b.load(scene)
        ref = plain.render(cam, quality(1024, 3), seed=9).linear
        raw = plain.render(cam, quality(1, 3), seed=1).linear
        den = noisy_dn.render(cam, quality(1, 3), seed=1)
        taken_as_clean = clean_guides.render(cam, quality(1, 3), seed=1).linear
    finally:
        plain.close()
        noisy_dn.close()
        clean_guides.close()
    mse = lambda a: float(((a - ref) ** 2).mean())  # noqa: E731
    assert den.stats["denoise_seconds"] >= 0 and mse(den.linear) < mse(raw) / 3, (mse(den.linear), mse(raw))
    # the prefilter reaches OIDN: guides taken as clean (the default, as Cycles' 'none') give another image, still denoised
    assert not np.array_equal(taken_as_clean, den.linear) and mse(taken_as_clean) < mse(raw) / 2


@pytest.mark.slow
def test_denoiser_guides_from_more_samples_keep_the_true_edges(tmp_path):
    """OIDN follows the edges of its albedo and normal guides. Along the edges of a light card on a
    dark floor, against a 1024-sample reference: guides from fewer samples than the image (4
    against 16) put other antialiased edges into it; guides from the image's own samples and seed
    do better, and the default (``mapping.guide_samples``: 64 here, taken as clean) better still
    (on two demo views at 320x240, 16 spp: 32.05 -> 32.54 dB and 31.08 -> 31.68 dB)."""
    pytest.importorskip("pyoidn")
    from dataclasses import replace

    from specsynth.testing.materials import camera, quad, quality
    from specsynth_mitsuba.backend import MitsubaBackend

    floor = replace(quad(tmp_path, "floor", 1.5),
                    material=MaterialIR(base_color=(0.05, 0.05, 0.05), specular=0.0, use_vertex_colors=False))
    card = replace(quad(tmp_path, "card", 0.3), pose=_pose((0.0, 0.0, 0.02)),
                   material=MaterialIR(base_color=(0.9, 0.9, 0.9), specular=0.0, use_vertex_colors=False))
    light = LightIR(kind="area", pose=_pose((0.2, 0.1, 0.9)), power=40.0, size=(0.6, 0.6))
    scene = RenderScene(meshes=(floor, card), lights=(light,), world=WorldIR(color=(0.05, 0.05, 0.06)))
    cam = camera((0.7, -0.6, 0.9), (0, 0, 0), 60.0, 96, 72)
    plain = MitsubaBackend({"variant": "auto"}, threads=2)
    dn = MitsubaBackend({"variant": "auto", "denoise": True, "denoise_prefilter": "none"}, threads=2)
    try:
        plain.load(scene)
        dn.load(scene)
        ref = plain.render(cam, quality(1024, 3), seed=9).linear
        default = dn.render(cam, quality(16, 3), seed=1)
        guides = dn._guides
        renders = {}
        for n in (16, 4):
            dn._guides = lambda sensor, seed, spp, n=n: guides(sensor, seed, n)
            renders[n] = dn.render(cam, quality(16, 3), seed=1).linear
    finally:
        plain.close()
        dn.close()
    assert default.stats["spp"] == 16 and default.stats["guide_spp"] == 64
    y = ref.mean(-1)
    edges = np.zeros_like(y, bool)
    edges[1:-1, 1:-1] = np.hypot(y[1:-1, 2:] - y[1:-1, :-2], y[2:, 1:-1] - y[:-2, 1:-1]) > 0.2 * y.max()
    err = lambda a: float(((a - ref)[edges] ** 2).mean())  # noqa: E731
    errors = (err(default.linear), err(renders[16]), err(renders[4]))
    assert edges.sum() > 50 and errors[0] < errors[1] < 0.7 * errors[2], (edges.sum(), errors)


@pytest.mark.slow
def test_a_denoised_render_carries_its_guides_and_denoise_remakes_the_image(tmp_path):
    """With denoising on, a render carries its guides (albedo, then normal) and ``denoise(noisy,
    guides)`` is the image it returned, bit for bit: the core denoises several renders' samples
    together with the same filter."""
    pytest.importorskip("pyoidn")
    from dataclasses import replace

    from specsynth.testing.materials import camera, quad, quality
    from specsynth_mitsuba.backend import MitsubaBackend

    card = replace(quad(tmp_path, "card", 0.3), material=MaterialIR(base_color=(0.7, 0.5, 0.3), use_vertex_colors=False))
    scene = RenderScene(meshes=(card,), lights=(LightIR(kind="point", pose=_pose((0.2, 0.1, 0.9)), power=20.0),),
                        world=WorldIR(color=(0.05, 0.05, 0.06)))
    dn = MitsubaBackend({"variant": "auto", "denoise": True}, threads=2)
    try:
        dn.load(scene)
        res = dn.render(camera((0.3, -0.3, 0.6), (0, 0, 0), 60.0, 48, 36), quality(4, 3), seed=2)
        again = dn.denoise(res.noisy, res.guides)
    finally:
        dn.close()
    assert res.guides.shape == (36, 48, 6) and res.guides.dtype == np.float32
    assert np.array_equal(again, res.linear)


# ----------------------------------------------------------------------------- files it keeps

DRJIT_PROBE = """
from specsynth_mitsuba.backend import MitsubaBackend
MitsubaBackend({"variant": "llvm_ad_rgb"})
import drjit as dr
from drjit.llvm import Float
dr.eval(dr.arange(Float, 1000) * 3.25 + 0.5)  # a kernel compiled, and cached on disk
print("ok")
"""


def test_mitsuba_keeps_drjits_kernel_cache_under_the_specsynth_cache(tmp_path):
    import os
    import subprocess
    import sys

    if "llvm_ad_rgb" not in mi.variants():
        pytest.skip("no LLVM variant: Dr.Jit compiles nothing")
    env = {k: v for k, v in os.environ.items() if k != "DRJIT_CACHE_DIR"}
    env.update(HOME=str(tmp_path / "home"), SPECSYNTH_CACHE=str(tmp_path / "cache"))
    (tmp_path / "home").mkdir()
    r = subprocess.run([sys.executable, "-c", DRJIT_PROBE], capture_output=True, text=True, timeout=120, env=env)
    if r.returncode != 0 and "llvm" in r.stderr.lower():
        pytest.skip("LLVM variant cannot run here")
    assert r.stdout.strip().endswith("ok"), r.stderr[-2000:]
    assert not (tmp_path / "home" / ".drjit").exists()
    assert any((tmp_path / "cache" / "drjit").iterdir())


# ----------------------------------------------------------------------------- error targets


def test_the_plugin_says_which_counts_the_sampler_takes():
    """Every count the plugin announces is the one Mitsuba's samplers round to (the backend
    raises when its sampler takes another), at least the count asked for and rising with it."""
    from specsynth_mitsuba import PLUGIN, MitsubaOptions

    for sampler in ("independent", "stratified", "ldsampler", "multijitter", "orthogonal"):
        opts = MitsubaOptions(sampler=sampler)
        counts = [PLUGIN.sample_counts(opts, n) for n in range(1, 300)]
        assert all(c >= n for n, c in zip(range(1, 300), counts)) and counts == sorted(counts)
        assert set(counts) >= {mapping.round_spp(n, sampler) for n in range(1, 300)}


def test_a_budget_no_pair_of_the_samplers_counts_fits_is_refused_at_validate(tmp_path):
    """ldsampler renders at least 4 samples per pixel: a max_samples of 6 fits no pair of renders,
    and validate says so, with the file and line, instead of an image past its budget."""
    from specsynth.plan.compiler import compile_spec
    from specsynth.spec.yamlio import SpecError, load_spec

    spec = tmp_path / "t.yaml"
    spec.write_text("name: t\nseed: 1\nintrinsics: {width: 64, height: 48, fx: 60.0, fy: 60.0, cx: 31.5, cy: 23.5}\n"
                    "objects: {builtin: [duck]}\nscenes: [{name: room}]\n"
                    "quality:\n  level: high\n  control: error\n  max_samples: 6\n"
                    "backend: {name: mitsuba, sampler: ldsampler}\n")
    with pytest.raises(SpecError, match=r"t.yaml:9:\d+: quality.max_samples: .*fits no pair of renders.*at least 4"):
        compile_spec(load_spec(spec))
    spec.write_text(spec.read_text().replace("max_samples: 6", "max_samples: 8"))
    compile_spec(load_spec(spec))


@pytest.mark.slow
@pytest.mark.parametrize("sampler", ["stratified", "ldsampler"])
def test_an_error_target_keeps_to_max_samples_with_a_rounding_sampler(tmp_path, sampler):
    """Under quality.control: error each image takes at most quality.max_samples, counted as the
    sampler renders them: the stratified sampler rounds a count up to a square, and planning with
    the counts asked for carried images to 242 samples per pixel against 225 (4, 4, 36, 36, then
    72 asked, 81 rendered). Its record says the samples rendered."""
    from dataclasses import replace

    from specsynth.run.render import draw_to_target
    from specsynth.spec.models import Quality
    from specsynth.testing.materials import camera, quad
    from specsynth_mitsuba import PLUGIN, MitsubaOptions
    from specsynth_mitsuba.backend import MitsubaBackend

    floor = replace(quad(tmp_path, "floor", 1.5),
                    material=MaterialIR(base_color=(0.7, 0.5, 0.3), specular=0.3, roughness=0.6, use_vertex_colors=False))
    card = replace(quad(tmp_path, "card", 0.2), pose=_pose((0.0, 0.0, 0.25)),
                   material=MaterialIR(base_color=(0.2, 0.6, 0.3), specular=0.0, use_vertex_colors=False))
    light = LightIR(kind="area", pose=_pose((0.2, 0.1, 0.9)), power=40.0, size=(0.6, 0.6))
    scene = RenderScene(meshes=(floor, card), lights=(light,), world=WorldIR(color=(0.05, 0.05, 0.06)))
    cam = camera((0.9, -0.9, 1.1), (0, 0, 0), 40.0, 48, 36)
    quality = Quality(level="high", control="error", max_samples=225)  # the paper's samples: a budget that binds
    spec_opts = MitsubaOptions(denoise=True, sampler=sampler)
    target = PLUGIN.error_target(spec_opts, quality)
    b = MitsubaBackend(PLUGIN.options_for(spec_opts, quality), threads=2)
    taken = []
    render = b.render
    b.render = lambda *a, **k: (r := render(*a, **k), taken.append(r.stats["spp"]))[0]
    try:
        b.load(scene)
        for seed in range(3):
            taken.clear()
            res = draw_to_target(b, [cam], quality.resolved(), seed, target, None)[0][0]
            assert res.stats["samples"] == sum(taken) <= 225, taken
            assert len(taken) == res.stats["renders"] >= 4  # more than one pair: the budget mattered
    finally:
        b.close()


TWO_ROOMS = """\
name: two_rooms
seed: 5
intrinsics: {width: 640, height: 480}
objects:
  builtin: [duck, mug]
scenes:
  - SCENE
arrangements:
  count: 1
cameras:
  per_arrangement: 1
  distance: [0.35, 0.7]
quality: {level: high}
backend: {name: mitsuba, denoise: true}
"""


@pytest.mark.slow
def test_two_rooms_of_very_different_noise_land_on_the_paper_presets_error(tmp_path):
    """`high` under an error target in a plain room and in an office lit by many lamps (at 64 x 48,
    the paper preset's error 2.7e-3 and 1.4e-2): each image's true error, against a reference of
    twice the preset's samples, is at most 10 % over the paper preset's true error at that view,
    and no image spends more than the preset's samples. (The target is the preset's error as the
    image estimates it from its own renders; the true one is measured here. Measured: 1.6e-3 for
    202 samples and 1.2e-2 for 110.)"""
    from specsynth.plan.compiler import compile_spec
    from specsynth.run.bench import run_bench
    from specsynth.spec.yamlio import load_spec

    errors = {}
    for name, scene in (("room", "{name: room}"), ("office_desk", "{name: office_desk, stages: [focus]}")):
        f = tmp_path / f"{name}.yaml"
        f.write_text(TWO_ROOMS.replace("SCENE", scene))
        rows, _ = run_bench(compile_spec(load_spec(f)), tmp_path / name, n_views=1, ref_factor=2, scale=0.1,
                            backends=["mitsuba"], levels=("high",), only=("high", "high+targeted"))
        [preset] = [r.views[0] for r in rows if r.setting == "high"]
        [image] = [r.views[0] for r in rows if r.setting == "high+targeted"]
        assert image["rel_mse"] <= 1.1 * preset["rel_mse"], (name, preset, image)
        assert image["samples"] <= preset["samples"] == 225 and image["error_target"] > 0
        errors[name] = preset["rel_mse"]
    assert errors["office_desk"] > 3 * errors["room"], errors  # very different noise
