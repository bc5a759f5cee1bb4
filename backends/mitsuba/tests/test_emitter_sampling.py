"""``emitter_sampling``: which emitter a shadow ray aims at, by Mitsuba's ``sampling_weight``."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from specsynth.assets.meshio import MeshData
from specsynth.model.error import split_rel_mse
from specsynth.model.ir import CameraIR, LightIR, MaterialIR, MeshInstance, RenderScene, WorldIR, as_tuple
from specsynth.spec.models import QualityPreset
from specsynth.views.cameras import look_at
from specsynth_mitsuba import mapping
from specsynth_mitsuba.scene import sampling_weights

powers = st.lists(st.floats(0.0, 1e4, allow_nan=False), min_size=1, max_size=12)


@given(powers)
def test_uniform_is_mitsubas_own_weight_of_one(ps):
    assert mapping.emitter_weights(ps, "uniform") == [1.0] * len(ps)


@given(powers)
def test_power_keeps_the_finite_emitters_share_and_orders_them_by_power(ps):
    w = mapping.emitter_weights(ps, "power")
    assert len(w) == len(ps) and all(x > 0 for x in w)
    # the finite emitters together weigh what they weigh under uniform choice (1 each), so an
    # environment's or a sun's share (weight 1) is unchanged
    assert sum(w) == pytest.approx(len(ps))
    if sum(ps) < mapping.MIN_POWER:
        assert w == [1.0] * len(ps)
        return
    for i in range(len(ps)):
        for j in range(len(ps)):
            if ps[i] >= ps[j]:
                assert w[i] >= w[j]
            if min(ps[i], ps[j]) >= 1e-3 * sum(ps) / len(ps):  # both above the floor: weights as powers
                assert w[i] * ps[j] == pytest.approx(w[j] * ps[i])
    assert min(w) >= 1e-3 / len(ps) * max(w) / 1.001  # the floor: no emitter is never aimed at


def test_two_emitters_in_numbers():
    assert mapping.emitter_weights([30.0, 10.0], "power") == pytest.approx([1.5, 0.5])
    assert mapping.emitter_weights([5e-324, 0.0], "power") == [1.0, 1.0]  # nothing to divide


def test_an_unknown_mode_is_an_error():
    with pytest.raises(ValueError, match="unknown emitter sampling 'importance'"):
        mapping.emitter_weights([1.0], "importance")


def test_light_powers():
    assert mapping.light_power("sun", 5.0, (1, 1, 1)) is None
    assert mapping.light_power("point", 10.0, (1, 1, 1)) == pytest.approx(10.0)
    assert mapping.light_power("area", 10.0, (0, 1, 0)) == pytest.approx(7.152)
    # a spot of a full 180 degrees lights a hemisphere: half its point's power
    assert mapping.light_power("spot", 10.0, (1, 1, 1), 180.0) == pytest.approx(5.0)
    assert mapping.light_power("spot", 10.0, (1, 1, 1), 60.0) == pytest.approx(10.0 * (1 - math.cos(math.radians(30))) / 2)
    assert mapping.surface_power((2.0, 2.0, 2.0), 0.5) == pytest.approx(math.pi)


def test_the_calibrated_levels_pick_by_power_and_an_error_target_as_the_preset_does():
    """Sample-controlled levels use the calibration's way; the paper presets render Mitsuba's own;
    an error target measures the preset's error on the image's own renders, so they draw their
    samples as the preset does; a spec's own choice is kept."""
    from specsynth.spec.models import Quality
    from specsynth_mitsuba import PLUGIN, MitsubaOptions

    def way(quality, **opts):
        return PLUGIN.options_for(MitsubaOptions(**opts), quality).emitter_sampling

    assert way(Quality(level="high")) == way(Quality(level="medium")) == "power"
    assert way(Quality(level="paper_high")) == "uniform"
    assert way(Quality(level="high", control="error")) == "uniform"
    assert way(Quality(level="high"), denoise=False) == "uniform"  # no calibration without its denoiser
    assert way(Quality(level="high"), emitter_sampling="uniform") == "uniform"
    assert way(Quality(level="paper_high"), emitter_sampling="power") == "power"


def _quad_data() -> MeshData:
    v = np.array([[-0.5, -0.5, 0], [0.5, -0.5, 0], [0.5, 0.5, 0], [-0.5, 0.5, 0]], np.float32)
    return MeshData(vertices=v, faces=np.array([[0, 1, 2], [0, 2, 3]], np.int32),
                    normals=np.tile(np.array([[0, 0, 1]], np.float32), (4, 1)))


def _pose(scale=1.0, t=(0.0, 0.0, 0.0)) -> tuple:
    T = np.diag([scale, scale, scale, 1.0])
    T[:3, 3] = t
    return as_tuple(T)


def test_emissive_meshes_weigh_their_power_as_placed_and_the_world_keeps_its_share():
    """A lamp shade of radiance 1 scaled to 2 x 2 m emits 4 pi W, a screen of radiance 2 and
    1 x 1 m whose emission texture averages 0.25 emits pi / 2 W; beside a 4 pi W point light and a
    0 W one (kept at a floor), with a sun: the four finite emitters share 4 by power, the sun 1."""
    data = {"q": _quad_data()}
    shade = MeshInstance("shade", "unused.ply", "q", _pose(2.0), MaterialIR(emission=(1.0, 1.0, 1.0)))
    screen = MeshInstance("screen", "unused.ply", "q", _pose(1.0),
                          MaterialIR(emission=(2.0, 2.0, 2.0), emission_texture="screen.png"))
    wall = MeshInstance("wall", "unused.ply", "q", _pose(5.0), MaterialIR())
    lights = (LightIR(kind="point", pose=_pose(), power=4 * math.pi), LightIR(kind="sun", pose=_pose(), power=3.0),
              LightIR(kind="point", pose=_pose(), power=0.0))
    scene = RenderScene(meshes=(wall, shade, screen), lights=lights, world=WorldIR(color=(0.1, 0.1, 0.1)))
    read = []
    light_w, surface_w = sampling_weights(scene, data, "power", lambda path: read.append(path) or 0.25)
    powers = [4 * math.pi, 4 * math.pi, math.pi / 2]
    floor = 1e-3 * sum(powers) / 4
    total = sum(powers) + floor
    assert read == ["screen.png"]
    assert light_w == pytest.approx([4 * powers[0] / total, 1.0, 4 * floor / total])
    assert surface_w == pytest.approx([4 * powers[1] / total, 4 * powers[2] / total])
    assert sampling_weights(scene, data, "uniform", None) == ([1.0, 1.0, 1.0], [1.0, 1.0])


# ----------------------------------------------------------------------------- renders

mi = pytest.importorskip("mitsuba")


@pytest.fixture(scope="module")
def backend(mitsuba_backend):
    return mitsuba_backend


def _lamps_scene(tmp_path) -> RenderScene:
    """A grey floor under one bright lamp and five dim ones: a room's desk lamp and far fittings."""
    from specsynth.assets.meshio import write_mesh

    path = tmp_path / "quad.ply"
    write_mesh(path, _quad_data())
    floor = MeshInstance("floor", str(path), "quad", _pose(4.0), MaterialIR(base_color=(0.5,) * 3, specular=0.0,
                                                                             metallic=0.0, roughness=1.0))
    bright = LightIR(kind="area", pose=_pose(1.0, (0.3, 0.0, 1.0)), power=200.0, size=(0.2, 0.2))
    dim = tuple(LightIR(kind="point", pose=_pose(1.0, (x, 1.5, 2.0)), power=2.0) for x in (-1.0, -0.5, 0.0, 0.5, 1.0))
    return RenderScene(meshes=(floor,), lights=(bright, *dim), world=WorldIR(color=(0.0, 0.0, 0.0)))


def test_scene_dict_puts_each_weight_on_its_own_emitter(backend, tmp_path):
    """The weights reach the emitters they belong to: the area lamp's nested emitter, each point
    light, and the glowing mesh built between plain ones."""
    import mitsuba as mi

    from specsynth.assets.meshio import write_mesh
    from specsynth_mitsuba.scene import scene_dict

    path = tmp_path / "quad.ply"
    write_mesh(path, _quad_data())
    base = _lamps_scene(tmp_path)
    glow = MeshInstance("glow", str(path), "quad", _pose(0.5, (0, 0, 0.5)), MaterialIR(emission=(1.0, 1.0, 1.0)))
    floor = base.meshes[0]
    scene = RenderScene(meshes=(floor, glow, dataclasses.replace(floor, name="floor2")), lights=base.lights,
                        world=base.world)
    meshes = {"quad": _quad_data()}
    light_w, surface_w = sampling_weights(scene, meshes, "power", None)
    d = scene_dict(mi, scene, meshes, emitter_sampling="power")
    assert d["light_000"]["emitter"]["sampling_weight"] == pytest.approx(light_w[0]) == pytest.approx(max(light_w))
    assert [d[f"light_{i:03d}"]["sampling_weight"] for i in range(1, 6)] == pytest.approx(light_w[1:])
    assert d["mesh_0001"].emitter().sampling_weight() == pytest.approx(surface_w[0])
    assert d["mesh_0000"].emitter() is None and d["mesh_0002"].emitter() is None


def _camera() -> CameraIR:
    eye = np.array([0.0, -2.0, 1.5])
    R, t = look_at(eye, np.zeros(3))
    K = np.array([[60.0, 0, 31.5], [0, 60.0, 23.5], [0, 0, 1]])
    return CameraIR(K=as_tuple(K), width=64, height=48, R_w2c=as_tuple(R), t_w2c=as_tuple(t))


def _renders(tmp_path, mode: str) -> tuple[list[float], list[np.ndarray]]:
    from specsynth_mitsuba.backend import MitsubaBackend

    b = MitsubaBackend({"variant": "auto", "sampler": "independent", "emitter_sampling": mode}, threads=2)
    try:
        b.load(_lamps_scene(tmp_path))
        weights = [e.sampling_weight() for e in b._scene.emitters()]
        preset = QualityPreset(aa=16, diffuse_rays=1, specular_rays=1, diffuse_depth=1, specular_depth=1, max_depth=1)
        return weights, [b.render(_camera(), preset, seed=s).linear for s in (1, 2)]
    finally:
        b.close()


@pytest.mark.slow
def test_power_sampling_keeps_the_image_and_takes_out_most_of_its_noise(tmp_path):
    """Six lamps, one of them 100x the others' power: picked by power, the bright lamp gets nearly
    every shadow ray instead of one in six. Same mean (both are unbiased), far less noise."""
    w_uniform, uniform = _renders(tmp_path, "uniform")
    w_power, power = _renders(tmp_path, "power")
    assert w_uniform == [1.0] * 6
    assert max(w_power) == pytest.approx(6 * 200 / 210, rel=1e-3)  # the area lamp's share (which emitter: above)
    mean_u, mean_p = np.mean(uniform), np.mean(power)
    assert mean_p == pytest.approx(mean_u, rel=0.03)
    noise_u = split_rel_mse(*uniform)
    noise_p = split_rel_mse(*power)
    assert noise_p < noise_u / 10, (noise_u, noise_p)  # measured: 94x less
