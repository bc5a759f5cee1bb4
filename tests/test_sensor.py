"""Sensor noise, exposure, white balance, JPEG quality and RGB-D depth errors: the statistics match
the model's parameters, every draw is seed-locked, and a real build writes both depths."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from specsynth.model.colour import linear_to_srgb8, srgb_to_linear
from specsynth.plan.compiler import compile_spec
from specsynth.run.build import build
from specsynth.spec.models import DepthSensor, Sensor
from specsynth.spec.yamlio import SpecError, load_spec
from specsynth.views.sensor import (
    AE_RANGE,
    AWB_GAINS,
    MIDDLE_GREY,
    REC709_LUMA,
    balance_gains,
    exposure_gain,
    metered_luminance,
    illuminant,
    jpeg_quality,
    sensor_depth,
    sensor_rgb,
)


def _linear_of(rgb8: np.ndarray) -> np.ndarray:
    return srgb_to_linear(rgb8.astype(np.float64) / 255.0)


def test_shot_and_read_noise_have_the_model_std():
    flat = np.full((200, 200, 3), 0.25, np.float32)
    rgb8 = linear_to_srgb8(flat)
    for shot, read in ((0.05, 0.0), (0.0, 0.02), (0.04, 0.01)):
        out = sensor_rgb(flat, rgb8, Sensor(shot_noise=shot, read_noise=read), np.random.default_rng(3))
        want = np.sqrt(shot ** 2 * 0.25 + read ** 2)
        got = _linear_of(out).std()
        assert got == pytest.approx(want, rel=0.08), (shot, read, got, want)  # 8-bit rounding adds a little
        assert _linear_of(out).mean() == pytest.approx(0.25, abs=0.004)


def test_exposure_and_white_balance_scale_the_signal():
    flat = np.full((16, 16, 3), 0.1, np.float32)
    rgb8 = linear_to_srgb8(flat)
    brighter = sensor_rgb(flat, rgb8, Sensor(exposure=(1.0, 1.0)), np.random.default_rng(0))
    assert _linear_of(brighter).mean() == pytest.approx(0.2, rel=0.02)
    warm = _linear_of(sensor_rgb(flat, rgb8, Sensor(white_balance=(3000, 3000)), np.random.default_rng(0)))
    # Balanced for a warm light under neutral light: the image turns blue.
    assert warm[..., 2].mean() > warm[..., 0].mean() * 1.3
    off = sensor_rgb(flat, rgb8, Sensor(), np.random.default_rng(0))
    assert off is rgb8  # nothing asked: the render untouched


def test_seed_locked_and_independent_streams():
    lin = np.random.default_rng(1).random((32, 32, 3)).astype(np.float32)
    rgb8 = linear_to_srgb8(lin)
    s = Sensor(shot_noise=0.03, read_noise=0.01, exposure=(-0.5, 0.5))
    a = sensor_rgb(lin, rgb8, s, np.random.default_rng(7))
    b = sensor_rgb(lin, rgb8, s, np.random.default_rng(7))
    c = sensor_rgb(lin, rgb8, s, np.random.default_rng(8))
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    qs = {jpeg_quality(Sensor(jpeg_quality=(60, 95)), 95, np.random.default_rng(k)) for k in range(50)}
    assert min(qs) >= 60 and max(qs) <= 95 and len(qs) > 10


@pytest.mark.parametrize("sigma", [0.8, 1.5, 3.0])
def test_blur_softens_a_step_by_its_sigma_and_keeps_earlier_draws(sigma):
    """A vertical step through the sensor's blur has the profile of a Gaussian of that sigma (its
    10-90 % width is 2.563 sigma), and turning blur on leaves the noise of the same seed unchanged."""
    lin = np.zeros((40, 200, 3), np.float32)
    lin[:, 100:] = 0.5
    out = _linear_of(sensor_rgb(lin, linear_to_srgb8(lin), Sensor(blur=(sigma, sigma)), np.random.default_rng(0)))
    row = out[20, :, 1] / 0.5
    x = np.arange(200)
    rise = np.interp(0.9, row[80:120], x[80:120]) - np.interp(0.1, row[80:120], x[80:120])
    assert rise == pytest.approx(2.563 * sigma, rel=0.1, abs=0.35)  # 8-bit steps limit tiny blurs
    noisy = Sensor(shot_noise=0.03, read_noise=0.01)
    a = sensor_rgb(lin, linear_to_srgb8(lin), noisy, np.random.default_rng(5))
    b = sensor_rgb(lin, linear_to_srgb8(lin), noisy.model_copy(update={"blur": (sigma, sigma)}), np.random.default_rng(5))
    flat = np.s_[:, :60]  # far from the step, blur changes nothing but the noise must be the same draw
    assert np.array_equal(a[flat], b[flat])


def test_depth_noise_grows_with_distance_and_holes_sit_on_edges():
    model = DepthSensor(axial_noise=(0.001, 0.002), edge_holes=1, dropout=0.0, quantisation=0.0)
    for z in (0.5, 2.0, 4.0):
        d = sensor_depth(np.full((300, 300), z, np.float32), model, np.random.default_rng(2))
        assert d.std() == pytest.approx(0.001 + 0.002 * z * z, rel=0.05)
    step = np.full((50, 60), 2.0, np.float32)
    step[:, 30:] = 1.0
    holes = sensor_depth(step, model, np.random.default_rng(0)) == 0
    assert holes[:, 29:31].all() and holes.sum() == 2 * 50  # the two pixels at the jump, no others
    q = sensor_depth(np.full((40, 40), 1.2345, np.float32), DepthSensor(axial_noise=(0.0, 0.0), edge_holes=0,
                                                                      quantisation=0.01), np.random.default_rng(0))
    assert np.allclose(q, 1.23, atol=1e-6)
    drop = sensor_depth(np.full((200, 200), 1.0, np.float32), DepthSensor(dropout=0.2, edge_holes=0),
                        np.random.default_rng(0))
    assert (drop == 0).mean() == pytest.approx(0.2, abs=0.01)


SPEC = """\
name: sensor
seed: 5
intrinsics: {width: 96, height: 72, fx: 86.0, fy: 86.0, cx: 47.5, cy: 35.5}
objects: {builtin: [duck, mug]}
scenes: [{name: room}]
arrangements: {count: 1}
cameras: {per_arrangement: 2, distance: [0.35, 0.6]}
backend: {name: photo}
sensor:
  shot_noise: 0.03
  read_noise: 0.005
  exposure: [-0.3, 0.3]
  jpeg_quality: [70, 90]
  depth: {axial_noise: [0.001, 0.002], edge_holes: 1, dropout: 0.01}
"""


def test_build_writes_noisy_rgb_and_both_depths(tmp_path):
    f = tmp_path / "s.yaml"
    f.write_text(SPEC)
    a = build(compile_spec(load_spec(f)), tmp_path / "a", jobs=1)
    clean = build(compile_spec(load_spec(f, ["sensor={}"])), tmp_path / "clean", jobs=1)
    assert not a.failures and a.images == clean.images >= 1
    chunk = "bop/train_pbr/000000"
    for p in sorted((tmp_path / "a" / chunk / "depth").glob("*.png")):
        exact = np.asarray(Image.open(p)).astype(np.float64)
        noisy = np.asarray(Image.open(tmp_path / "a" / chunk / "depth_noisy" / p.name)).astype(np.float64)
        both = (exact > 0) & (noisy > 0)
        assert both.sum() > 0.5 * (exact > 0).sum() > 0 and 0 < np.abs(noisy - exact)[both].mean()
        assert np.array_equal(exact, np.asarray(Image.open(tmp_path / "clean" / chunk / "depth" / p.name)))
    rgb_a = sorted((tmp_path / "a" / chunk / "rgb").glob("*.jpg"))
    rgb_c = sorted((tmp_path / "clean" / chunk / "rgb").glob("*.jpg"))
    assert [p.name for p in rgb_a] == [p.name for p in rgb_c]
    assert all(p.read_bytes() != q.read_bytes() for p, q in zip(rgb_a, rgb_c))
    # Labels describe the scene, not the sensor: the same with and without it.
    gt = "scene_gt_info.json"
    assert json.loads((tmp_path / "a" / chunk / gt).read_text()) == json.loads((tmp_path / "clean" / chunk / gt).read_text())
    again = build(compile_spec(load_spec(f)), tmp_path / "b", jobs=1)
    assert again.images == a.images
    for p in rgb_a:
        assert p.read_bytes() == (tmp_path / "b" / chunk / "rgb" / p.name).read_bytes()


def test_bad_sensor_values_are_located(tmp_path):
    f = tmp_path / "s.yaml"
    f.write_text(SPEC.replace("jpeg_quality: [70, 90]", "jpeg_quality: [70, 120]"))
    with pytest.raises(SpecError) as e:
        load_spec(f)
    assert [(p.line, p.path) for p in e.value.problems] == [(13, "sensor.jpeg_quality")]


@settings(max_examples=60, deadline=None)
@given(st.tuples(*[st.floats(0.05, 20.0)] * 3), st.integers(0, 2 ** 31))
def test_auto_white_balance_recovers_any_uniform_light(light, seed):
    """Under one light of any colour, the balanced image is the albedo times the light's luminance."""
    rng = np.random.default_rng(seed)
    albedo = rng.uniform(0.03, 1.0, (24, 32, 3))
    light = np.asarray(light)
    got = illuminant(albedo * light, albedo)
    assert np.allclose(got, light, rtol=1e-9)
    gains = balance_gains(got)
    if np.all((gains > AWB_GAINS[0]) & (gains < AWB_GAINS[1])):  # inside the camera's range: exact
        assert np.allclose(albedo * light * gains, albedo * float(light @ REC709_LUMA), rtol=1e-9)
    assert np.all(gains >= AWB_GAINS[0]) and np.all(gains <= AWB_GAINS[1])
    assert np.array_equal(balance_gains(illuminant(albedo, np.zeros_like(albedo))), np.ones(3))  # nothing seen


AWB_SPEC = """\
name: awb
seed: 3
intrinsics: {width: 64, height: 48, fx: 58.0, fy: 58.0, cx: 31.5, cy: 23.5}
objects: {builtin: [duck, mug]}
scenes: [{name: room, randomize: {light_temperature: [2700, 2700]}}]
arrangements: {count: 1}
cameras: {per_arrangement: 2, distance: [0.5, 0.8]}
quality: {level: low}
backend: {name: cycles, denoise: true}
outputs: {image_format: png, albedo: true, depth: false, coco: false, parquet: false}
"""


def _light_in_view(out):
    """The light's colour measured on written images: sRGB render over sRGB albedo, both decoded."""
    chunk = out / "bop" / "train_pbr" / "000000"
    lights = []
    for p in sorted((chunk / "rgb").glob("*.png")):
        x = _linear_of(np.asarray(Image.open(p).convert("RGB")))
        a = _linear_of(np.asarray(Image.open(chunk / "albedo" / p.name).convert("RGB")))
        lights.append(illuminant(x, a, clipped=0.99))
    return np.array(lights)


@pytest.mark.slow
def test_auto_white_balance_neutralises_a_warm_room_in_a_real_render(tmp_path):
    """Cycles, the built-in room with every light at 2700 K: without AWB the light in view is
    orange; with it, grey surfaces are grey (the measured light is neutral within a few percent)."""
    f = tmp_path / "s.yaml"
    f.write_text(AWB_SPEC)
    warm = build(compile_spec(load_spec(f)), tmp_path / "warm", jobs=1)
    awb = build(compile_spec(load_spec(f, ["sensor.auto_white_balance=true"])), tmp_path / "awb", jobs=1)
    assert not warm.failures and not awb.failures and warm.images == awb.images >= 1
    before, after = _light_in_view(tmp_path / "warm"), _light_in_view(tmp_path / "awb")
    assert np.all(before[:, 0] > 2.0 * before[:, 2])  # 2700 K: red over blue > 2
    assert np.all(np.abs(after / after.mean(axis=1, keepdims=True) - 1.0) < 0.06), after
    # Brightness about kept (exactly in the property test above; here the warm image's red channel
    # clips on bright surfaces, which drops them from its measurement).
    assert np.allclose(after @ REC709_LUMA, before @ REC709_LUMA, rtol=0.25)


@settings(max_examples=60, deadline=None)
@given(st.floats(1e-3, 50.0), st.integers(0, 2 ** 31))
def test_auto_exposure_meters_to_middle_grey(scale, seed):
    """Any image, at any brightness: after metering the log-average luminance of its zones is
    0.18 (within the camera's 1/16-16x range), and the metered image does not depend on how bright
    the render was."""
    img = np.random.default_rng(seed).uniform(0.05, 1.0, (20, 30, 3)) * scale
    g = exposure_gain(img)
    y = metered_luminance(img * g)
    assert y.shape == (5, 7)  # 4 x 4 zones; the last two columns fill none
    key = float(np.exp(np.mean(np.log(y))))
    if AE_RANGE[0] < g < AE_RANGE[1]:
        assert key == pytest.approx(MIDDLE_GREY, rel=1e-9)
        assert np.allclose(img * g, (img / scale) * exposure_gain(img / scale), rtol=1e-9)
    else:
        assert g in AE_RANGE
    assert exposure_gain(np.zeros((4, 4, 3))) == 1.0


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2 ** 31), st.sampled_from([0.5, 0.25]))
def test_auto_exposure_meters_the_light_not_the_noise(seed, found):
    """A one-sample render finds a light path in some pixels only (each such pixel the light's
    value over the chance of finding it, so the mean is kept): metered, it is exposed within half
    a stop of its converged image, as a camera meters the scene's light (0.01-0.37 stops over 200
    seeds). Metering single pixels had exposed it 5.3-5.5 stops brighter: the zeros weigh in the
    log-average."""
    rng = np.random.default_rng(seed)
    smooth = np.kron(rng.uniform(0.05, 1.0, (12, 16, 3)), np.ones((8, 8, 1)))  # 96 x 128, varying over 8 px
    noisy = smooth * (rng.random(smooth.shape[:2]) < found)[..., None] / found
    stops = np.log2(exposure_gain(noisy) / exposure_gain(smooth))
    assert abs(stops) < 0.5, stops


@settings(max_examples=80, deadline=None)
@given(st.floats(0.5, 4.0), st.lists(st.floats(0.0, 1.0), min_size=2, max_size=50))
def test_the_tone_curve_is_a_symmetric_s_of_slope_k_at_mid_grey(k, vs):
    from specsynth.views.sensor import tone_curve

    v = np.sort(np.array(vs))
    out = tone_curve(v, k)
    assert np.all(np.diff(out) >= -1e-12)  # monotonic
    np.testing.assert_allclose(tone_curve(np.array([0.0, 0.5, 1.0]), k), [0.0, 0.5, 1.0], atol=1e-12)
    np.testing.assert_allclose(tone_curve(1.0 - v, k), 1.0 - out, atol=1e-9)
    h = 1e-6
    assert (tone_curve(np.array([0.5 + h]), k)[0] - tone_curve(np.array([0.5 - h]), k)[0]) / (2 * h) == pytest.approx(k, rel=1e-4)


@settings(max_examples=80, deadline=None)
@given(st.floats(0.0, 3.0), st.integers(0, 2**32 - 1))
def test_saturation_keeps_luminance_and_scales_chroma(factor, seed):
    from specsynth.views.sensor import REC709_LUMA, saturate

    x = np.random.default_rng(seed).uniform(0.28, 0.32, (16, 3))  # chroma x 3 stays above 0: nothing clips
    y = saturate(x, factor)
    np.testing.assert_allclose(y @ REC709_LUMA, x @ REC709_LUMA, atol=1e-12)
    lum = (x @ REC709_LUMA)[:, None]
    np.testing.assert_allclose(y - lum, factor * (x - lum), atol=1e-12)


def test_the_camera_processing_is_the_plain_encoding_when_neutral():
    from specsynth.model.colour import linear_to_srgb8
    from specsynth.views.sensor import process

    x = np.random.default_rng(0).uniform(0, 1.2, (8, 8, 3)).astype(np.float32)
    np.testing.assert_array_equal(process(x), linear_to_srgb8(x))
    assert process(x, 1.0, 1.5).std() > process(x).std()  # more contrast spreads the values


@settings(max_examples=40, deadline=None)
@given(st.floats(0.0, 2.0), st.integers(0, 2**32 - 1))
def test_sharpening_moves_every_channel_by_the_luma_detail_and_leaves_flat_colour(amount, seed):
    """The unsharp mask adds one luma difference to every channel: chroma (R - G, B - G) is kept
    wherever nothing clips, a flat colour is unchanged, and 0 is the identity."""
    from scipy.ndimage import gaussian_filter

    from specsynth.views.sensor import SHARPEN_SIGMA, sharpen

    rng = np.random.default_rng(seed)
    v = 0.3 + 0.4 * gaussian_filter(rng.uniform(0, 1, (24, 32, 3)), (1.5, 1.5, 0))  # in [0.3, 0.7]: no clipping
    out = sharpen(v, amount)
    y = v @ REC709_LUMA
    detail = y - gaussian_filter(y, SHARPEN_SIGMA, mode="mirror")
    np.testing.assert_allclose(out - v, np.repeat(amount * detail[..., None], 3, -1), atol=1e-12)
    np.testing.assert_array_equal(sharpen(v, 0.0), v)
    flat = np.full((8, 8, 3), [0.2, 0.5, 0.4])
    np.testing.assert_allclose(sharpen(flat, amount), flat, atol=1e-12)


def test_sharpening_is_part_of_the_camera_processing_and_of_the_sensor():
    from specsynth.views.sensor import process

    step = np.full((20, 20, 3), 0.05, np.float32)
    step[:, 10:] = 0.5
    plain, sharp = process(step).astype(int), process(step, sharpening=1.0).astype(int)
    assert sharp[:, 9].max() < plain[:, 9].min() and sharp[:, 10].min() > plain[:, 10].max()  # dark and bright halos
    np.testing.assert_array_equal(sharp[:, :5], plain[:, :5])  # away from the edge, unchanged
    assert Sensor(sharpening=0.5).affects_rgb and not Sensor().affects_rgb
    rgb8 = linear_to_srgb8(step)
    out = sensor_rgb(step, rgb8, Sensor(sharpening=1.0), np.random.default_rng(0))
    np.testing.assert_array_equal(out, sharp.astype(np.uint8))


@settings(max_examples=60, deadline=None)
@given(st.floats(0.0, 0.95), st.integers(2, 60), st.integers(2, 80))
def test_vignetting_keeps_the_centre_and_leaves_the_corners_their_share(amount, h, w):
    """The corners keep 1 - amount of the light, the gain falls monotonically with the distance from
    the centre and is the same at mirrored pixels; 0 is no vignetting."""
    from specsynth.views.sensor import vignette

    g = vignette(h, w, amount)
    assert g.shape == (h, w) and np.all(g <= 1.0) and np.all(g > 0.0)
    for corner in (g[0, 0], g[0, -1], g[-1, 0], g[-1, -1]):
        assert corner == pytest.approx(1.0 - amount, rel=1e-9)
    np.testing.assert_allclose(g, g[::-1, ::-1], rtol=1e-12)
    cy, cx = (h - 1) / 2, (w - 1) / 2
    rho = np.hypot(*np.mgrid[0:h, 0:w] - np.array([cy, cx])[:, None, None]).ravel()
    order = np.argsort(rho, kind="stable")
    assert np.all(np.diff(g.ravel()[order]) <= 1e-12)
    np.testing.assert_array_equal(vignette(h, w, 0.0), np.ones((h, w)))


def test_vignetting_is_part_of_the_sensor_after_exposure():
    """sensor.vignetting darkens the corners of the image after metering: a grey field metered by
    auto exposure comes out as without vignetting at the centre, darker towards the corners."""
    from specsynth.views.sensor import vignette

    grey = np.full((48, 64, 3), 0.18, np.float32)
    rgb8 = linear_to_srgb8(grey)
    plain = sensor_rgb(grey, rgb8, Sensor(auto_exposure=True), np.random.default_rng(0)).astype(int)
    dark = sensor_rgb(grey, rgb8, Sensor(auto_exposure=True, vignetting=0.4), np.random.default_rng(0)).astype(int)
    assert Sensor(vignetting=0.1).affects_rgb
    assert abs(dark[24, 32] - plain[24, 32]).max() <= 1
    np.testing.assert_array_equal(dark[0, 0], linear_to_srgb8(np.full(3, 0.18 * 0.6, np.float32)))
    np.testing.assert_array_equal(dark, linear_to_srgb8((grey * vignette(48, 64, 0.4)[..., None]).astype(np.float32)))
