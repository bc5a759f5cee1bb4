"""Mitsuba mapping fixes that make it agree with Cycles (benchmarks/breakdown_backends.py).

Pure mapping checks first, then small Mitsuba renders (<= 48x48); one cross-backend check of the
sky's sun direction runs only where bpy is installed.
"""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from specsynth.assets.meshio import MeshData
from specsynth.model.ir import CameraIR, LightIR, MaterialIR, MeshInstance, RenderScene, WorldIR, as_tuple
from specsynth.spec.models import QualityPreset
from specsynth.views.cameras import look_at
from specsynth_mitsuba import mapping
from specsynth_mitsuba import scene as mscene

PROJECT = Path(__file__).resolve().parents[1]  # backends/mitsuba: the child imports specsynth_mitsuba from here


# ----------------------------------------------------------------------------- pure mapping


@pytest.mark.parametrize("r", [0.0, 0.3, 0.5, 0.85, 1.0])
@pytest.mark.parametrize("s", [0.1, 0.3, 0.5, 0.6, 1.0])
def test_principled_calibration_matches_blender_albedo_table(r, s):
    """With the calibrated base factor and specular, Mitsuba's tabulated albedo (D_M k base + E_M(s'))
    equals Blender's ((1 - E_B) base + E_B) for every base colour."""
    k, s_m = mapping.principled_calibration(r, s)
    d_m = np.interp(r, mapping.CALIB_ROUGHNESS, mapping.MITSUBA_DIFFUSE_ALBEDO)
    e_b = np.interp(s, mapping.CALIB_SPECULAR, mapping._interp_row(mapping.BLENDER_SPECULAR_ALBEDO, r))
    e_m_row = mapping._interp_row(mapping.MITSUBA_SPECULAR_ALBEDO, r)
    if s_m <= 1.0:
        e_m = np.interp(s_m, mapping.CALIB_SPECULAR, e_m_row)
    else:
        e_m = e_m_row[-1] + (s_m - 1.0) * (e_m_row[-1] - e_m_row[-2]) / 0.1
    for base in (0.0, 0.5, 1.0):
        assert d_m * k * base + e_m == pytest.approx((1 - e_b) * base + e_b, abs=1e-6)
    assert 0.9 < k < 1.03 and abs(s_m - s) < 0.2


def test_calibration_leaves_lambertian_metal_and_glass_alone():
    for m in (
        MaterialIR(specular=0.0, metallic=0.0, roughness=0.4),
        MaterialIR(metallic=1.0, roughness=0.3),
        MaterialIR(transmission=1.0, roughness=0.1),
    ):
        assert mscene.mitsuba_material(m) == m
    m = mscene.mitsuba_material(MaterialIR(base_color=(0.5, 0.4, 0.3), roughness=0.9, specular=0.5))
    k, s = mapping.principled_calibration(0.9, 0.5)
    assert m.base_color == pytest.approx((0.5 * k, 0.4 * k, 0.3 * k)) and m.specular == pytest.approx(s)


def test_calibration_can_be_turned_off_and_area_lights_let_rays_through():
    m = MaterialIR(roughness=0.9, specular=0.5)
    assert mscene.mitsuba_material(m, calibrate=False) == m
    assert mscene.mitsuba_material(m) != m
    assert mscene.light_dict(LightIR(kind="area", pose=as_tuple(np.eye(4))))["bsdf"]["type"] == "null"


def test_sky_units_scale_mitsubas_sky_to_blenders():
    assert mapping.sky_scale(1.0, 3.0) > 10.0  # Blender's sky is ~50x brighter at equal strength
    assert mapping.sky_scale(0.5, 3.0) == pytest.approx(0.5 * mapping.sky_scale(1.0, 3.0))
    assert mapping.sky_scale(1.0, 3.0, 45.0) > mapping.sky_scale(1.0, 10.0, 45.0)  # hazier: less to make up
    d = mscene.world_dict(WorldIR(kind="sky", strength=0.3, turbidity=3.0, sun_elevation=38.0))
    assert d["sky_scale"] == pytest.approx(mapping.sky_scale(0.3, 3.0, 38.0))


# ----------------------------------------------------------------------------- renders

mi = pytest.importorskip("mitsuba")


@pytest.fixture(scope="module")
def backend(mitsuba_backend):
    return mitsuba_backend


from test_mitsuba import _sphere, _write  # noqa: E402  (after the importorskip above)


def _quad(tmp, half: float) -> str:
    v = np.array([[-half, -half, 0], [half, -half, 0], [half, half, 0], [-half, half, 0]], np.float32)
    return _write(tmp, f"quad{half}", MeshData(vertices=v, faces=np.array([[0, 1, 2], [0, 2, 3]], np.int32),
                                              normals=np.tile(np.array([[0, 0, 1]], np.float32), (4, 1))))


def _cam(eye, target, f, W, H, up=(0.0, 0.0, 1.0)) -> CameraIR:
    R, t = look_at(np.asarray(eye, float), np.asarray(target, float), up=up)
    K = np.array([[f, 0, (W - 1) / 2], [0, f, (H - 1) / 2], [0, 0, 1]])
    return CameraIR(K=as_tuple(K), width=W, height=H, R_w2c=as_tuple(R), t_w2c=as_tuple(t))


def _q(spp: int, depth: int = 1) -> QualityPreset:
    return QualityPreset(aa=spp, diffuse_rays=1, specular_rays=1, diffuse_depth=depth, specular_depth=depth, max_depth=depth)


@pytest.mark.slow
def test_calibrated_principled_furnace(backend, tmp_path):
    """Rough dielectric (roughness 0.9, specular 0.5, base 0.5) in a radiance-1 world: the sphere's
    mean is Blender's measured albedo 0.5 (1 - 0.0242) + 0.0242 = 0.5121 (Mitsuba's raw
    principled: 0.539)."""
    mat = MaterialIR(base_color=(0.5, 0.5, 0.5), roughness=0.9, specular=0.5)
    ball = MeshInstance("ball", _sphere(tmp_path), "sphere", as_tuple(np.eye(4)), mat)
    backend.load(RenderScene(meshes=(ball,), world=WorldIR(kind="color", color=(1.0, 1.0, 1.0))))
    img = backend.render(_cam((0, -4, 0), (0, 0, 0), 60.0, 48, 48), _q(64), seed=5).linear.mean(2)
    yy, xx = np.mgrid[0:48, 0:48]
    disc = np.hypot(xx - 23.5, yy - 23.5) < 14.5  # the sphere's radius is 15.5 px
    assert img[disc].mean() == pytest.approx(0.5121, rel=0.01)


@pytest.mark.slow
def test_area_light_is_not_an_occluder_from_behind(backend, tmp_path):
    """A 20 W 1 x 1 m area light 1 m over an albedo-0.5 floor, seen from behind (from above): the
    floor under it shows through, with radiance 0.5 / pi * E (E = 4.789 W/m^2 below the centre,
    closed form). Before the fix the light's back was black."""
    floor = MeshInstance("f", _quad(tmp_path, 2.0), "quad2", as_tuple(np.eye(4)),
                         MaterialIR(base_color=(0.5,) * 3, specular=0.0, roughness=1.0))
    T = np.eye(4)
    T[:3, 3] = (0.0, 0.0, 1.0)
    light = LightIR(kind="area", pose=as_tuple(T), power=20.0, size=(1.0, 1.0))
    backend.load(RenderScene(meshes=(floor,), lights=(light,), world=WorldIR(color=(0.0, 0.0, 0.0))))
    img = backend.render(_cam((0, 0, 3.0), (0, 0.001, 0), 60.0, 8, 8, up=(0, 1, 0)), _q(256, 2), seed=1).linear.mean(2)
    x, y = 0.5 / 1.0, 0.5 / 1.0  # corner form factor of a 0.5 x 0.5 quarter at 1 m
    f = (x / math.hypot(1, x) * math.atan(y / math.hypot(1, x)) + y / math.hypot(1, y) * math.atan(x / math.hypot(1, y))) / (2 * math.pi)
    want = 0.5 / math.pi * 20.0 * 4 * f  # E = pi L F, L = P / (pi A)
    assert img[3:5, 3:5].mean() == pytest.approx(want, rel=0.03)


def test_exr_envmap_with_one_thread_does_not_hang(tmp_path):
    """Mitsuba 3.9's EXR reader deadlocked with a 1-thread Dr.Jit pool (threads=1 workers)."""
    exr = tmp_path / "env.exr"
    code = f"""
import numpy as np, mitsuba as mi
mi.set_variant('scalar_rgb')
mi.Bitmap(np.full((8, 16, 3), 0.5, np.float32)).write({str(exr)!r})
from specsynth_mitsuba.backend import MitsubaBackend
from specsynth.model.ir import RenderScene, WorldIR
b = MitsubaBackend({{'variant': 'auto'}}, threads=1)
b.load(RenderScene(meshes=(), world=WorldIR(kind='envmap', envmap={str(exr)!r})))
print('loaded')
"""
    r = subprocess.run([sys.executable, "-c", code], cwd=PROJECT, capture_output=True, text=True, timeout=120)
    assert "loaded" in r.stdout, r.stderr[-2000:]


def test_plugin_check_works(backend):
    """It silently returned False on Mitsuba 3.9 (an API that no longer exists), so every sky was
    rendered with the crude fallback."""
    assert backend._has_plugin("diffuse") and not backend._has_plugin("no_such_plugin")


@pytest.mark.slow
@pytest.mark.parametrize(("turbidity", "elevation"), [(3.0, 45.0), (5.0, 38.0)])
def test_sky_brightness_agrees_with_cycles(backend, turbidity, elevation):
    """The sky scale's units are Blender's: the same sky rendered by both backends has the same
    mean radiance away from the sun (measured here by rendering Cycles, not read from the scale's
    table), at a table node and between nodes."""
    pytest.importorskip("bpy")
    from specsynth_cycles.backend import CyclesBackend

    if not backend._has_plugin("sunsky"):
        pytest.skip("this Mitsuba build has no sunsky")
    world = WorldIR(kind="sky", strength=0.5, sun_elevation=elevation, sun_azimuth=0.0, turbidity=turbidity)
    cyc = CyclesBackend({"name": "cycles"}, threads=1)
    try:
        mean = {}
        for name, b in (("cycles", cyc), ("mitsuba", backend)):
            b.load(RenderScene(meshes=(), world=world))
            # Looking up at 60 degrees in three directions away from the sun (azimuth 0 = +Y).
            views = [(math.cos(math.radians(phi)), math.sin(math.radians(phi)), 1.73) for phi in (0.0, 180.0, 315.0)]
            mean[name] = float(np.mean([b.render(_cam((0, 0, 0), d, 8.0, 8, 8), _q(16), seed=1).linear.mean() for d in views]))
    finally:
        cyc.close()
    assert mean["cycles"] > 0.01 and mean["mitsuba"] == pytest.approx(mean["cycles"], rel=0.1), mean


@pytest.mark.slow
def test_sky_sun_direction_agrees_with_cycles(backend):
    """Azimuth 90 puts the sky's brightest horizon towards -X in both backends (IR: azimuth 0 =
    +Y, counter-clockwise seen from above); before the fix Cycles put it towards +X."""
    pytest.importorskip("bpy")
    from specsynth_cycles.backend import CyclesBackend

    if not backend._has_plugin("sunsky"):
        pytest.skip("this Mitsuba build has no sunsky")
    world = WorldIR(kind="sky", sun_elevation=15.0, sun_azimuth=90.0, turbidity=3.0)
    cyc = CyclesBackend({"name": "cycles"}, threads=1)
    try:
        peaks = {}
        for name, b in (("cycles", cyc), ("mitsuba", backend)):
            b.load(RenderScene(meshes=(), world=world))
            vals = []
            for phi in (0.0, 90.0, 180.0, 270.0):
                d = (math.cos(math.radians(phi)), math.sin(math.radians(phi)), 0.27)
                vals.append(float(b.render(_cam((0, 0, 0), d, 8.0, 8, 8), _q(16), seed=1).linear.mean()))
            peaks[name] = (0.0, 90.0, 180.0, 270.0)[int(np.argmax(vals))]
    finally:
        cyc.close()
    assert peaks == {"cycles": 180.0, "mitsuba": 180.0}
