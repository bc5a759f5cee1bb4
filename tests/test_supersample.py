"""Supersampling (``backend.supersample``): the camera at a whole multiple of its resolution, the
render brought back to it, and which options carry it."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_error_target import TINY

from specsynth.model.colour import linear_to_srgb8
from specsynth.model.ir import CameraIR, RenderResult, as_tuple
from specsynth.model.supersample import block_mean, downsampled
from specsynth.plugins import BackendPlugin
from specsynth.spec.models import BackendOptions, Quality
from specsynth.views.cameras import project

finite = st.floats(-1e3, 1e3, allow_nan=False)


def _camera(fx, fy, cx, cy, w=64, h=48) -> CameraIR:
    return CameraIR(K=((fx, 0.0, cx), (0.0, fy, cy), (0.0, 0.0, 1.0)), width=w, height=h,
                    R_w2c=as_tuple(np.eye(3)), t_w2c=(0.0, 0.0, 0.0))


@settings(max_examples=200, deadline=None)
@given(fx=st.floats(10, 2000), fy=st.floats(10, 2000), cx=finite, cy=finite, factor=st.integers(1, 4),
       x=st.floats(-2, 2), y=st.floats(-2, 2), z=st.floats(0.1, 10))
def test_a_scaled_camera_puts_each_pixel_centre_at_its_blocks_mean(fx, fy, cx, cy, factor, x, y, z):
    """A point at pixel coordinate p of the camera lands at the mean of the sub-pixel centres of
    p's block in the scaled one: (p + 0.5) f - 0.5 (OpenCV's centres at integers)."""
    cam = _camera(fx, fy, cx, cy)
    big = cam.scaled(factor)
    X = np.array([[x, y, z]])
    p, q = (project(c.K, c.R_w2c, c.t_w2c, X)[0] for c in (cam, big))
    assert np.allclose(q, (p + 0.5) * factor - 0.5, rtol=1e-9, atol=1e-6 * max(1.0, abs(q).max()))
    assert (big.width, big.height) == (64 * factor, 48 * factor)
    assert (big.R_w2c, big.t_w2c, big.motion, big.aperture) == (cam.R_w2c, cam.t_w2c, cam.motion, cam.aperture)


def test_a_camera_is_scaled_by_a_whole_factor_only():
    cam = _camera(100, 100, 31.5, 23.5)
    for bad in (0, 1.5, 2.0, -2, True):
        with pytest.raises(ValueError, match="whole factor"):
            cam.scaled(bad)
    assert cam.scaled(1) == cam


@settings(max_examples=100, deadline=None)
@given(h=st.integers(1, 6), w=st.integers(1, 6), factor=st.integers(1, 4), seed=st.integers(0, 2**32 - 1))
def test_block_means_keep_the_images_mean_and_each_block(h, w, factor, seed):
    img = np.random.default_rng(seed).random((h * factor, w * factor, 3)) * 10
    small = block_mean(img, factor)
    assert small.shape == (h, w, 3) and small.dtype == np.float32
    assert np.isclose(small.mean(), img.mean(), rtol=1e-5)
    for i in range(h):
        for j in range(w):
            block = img[i * factor:(i + 1) * factor, j * factor:(j + 1) * factor]
            assert np.allclose(small[i, j], block.mean(axis=(0, 1)), rtol=1e-5)


def test_an_image_not_made_of_whole_blocks_is_refused():
    with pytest.raises(ValueError, match="not made of 2x2 blocks"):
        block_mean(np.zeros((5, 4, 3)), 2)


def test_a_downsampled_render_is_encoded_from_its_averaged_radiance():
    """Averaged before the sRGB curve and the clip, not after: a highlight brighter than white in
    one sub-pixel of four still brightens its pixel by a quarter of itself."""
    lin = np.zeros((4, 4, 3), np.float32)
    lin[0, 0] = 3.0  # one of block (0, 0)'s four sub-pixels, three times white
    res = downsampled(RenderResult(rgb=linear_to_srgb8(lin), linear=lin, stats={"samples": 8}), 2)
    assert res.linear.shape == (2, 2, 3) and np.allclose(res.linear[0, 0], 0.75)
    assert (res.rgb == linear_to_srgb8(res.linear)).all() and res.rgb[0, 0, 0] > 200
    assert res.stats == {"samples": 8, "supersample": 2}
    # an 8-bit render is averaged in linear light too: black and white make 188, not 128
    checker = np.zeros((4, 4, 3), np.uint8)
    checker[::2, ::2] = checker[1::2, 1::2] = 255
    eight_bit = downsampled(RenderResult(rgb=checker), 2)
    assert eight_bit.linear is None and (eight_bit.rgb == 188).all()
    # the raw radiance and the guides beside a denoised render are brought to the image's size alike
    guides = np.arange(4 * 4 * 6, dtype=np.float32).reshape(4, 4, 6)
    both = downsampled(RenderResult(rgb=linear_to_srgb8(lin), linear=lin, noisy=2 * lin, guides=guides), 2)
    assert np.allclose(both.noisy, 2 * both.linear) and np.allclose(both.guides, block_mean(guides, 2))
    assert downsampled(res, 1) is res


def test_a_calibrated_supersample_goes_with_its_samples():
    """A level's calibration is a unit: a spec with a count of its own renders at its own
    resolution; under an error target, and without the calibration's denoiser, none applies."""
    plugin = BackendPlugin(name="x", options=BackendOptions, backend="nowhere:X",
                           calibrated={"high": {"samples": 8, "denoise": True, "supersample": 2}})
    high = Quality(level="high")
    filled = plugin.options_for(BackendOptions(name="x"), high)
    assert (filled.samples, filled.denoise, filled.supersample) == (8, True, 2)
    assert plugin.options_for(BackendOptions(name="x", samples=30), high).supersample == 1
    assert plugin.options_for(BackendOptions(name="x", samples=30, supersample=3), high).supersample == 3
    assert plugin.options_for(BackendOptions(name="x", denoise=False), high).supersample == 1
    assert plugin.options_for(BackendOptions(name="x"), Quality(level="high", control="error")).supersample == 1
    assert plugin.options_for(BackendOptions(name="x"), Quality(level="paper_high")).supersample == 1
    # a spec's own factor keeps the samples the calibration traces per pixel of the image: 8 at 2x
    # are 32, so 32 at 1x and 4 at 3x (36, the fewest at 3x that trace as many)
    own = [plugin.options_for(BackendOptions(name="x", supersample=f), high) for f in (1, 3)]
    assert [(o.samples, o.supersample) for o in own] == [(32, 1), (4, 3)]
    flat = BackendPlugin(name="y", options=BackendOptions, backend="nowhere:Y",
                         calibrated={"high": {"samples": 16, "denoise": True}})
    assert flat.options_for(BackendOptions(name="y", supersample=2), high).samples == 4


def test_an_error_target_keeps_what_a_calibration_sets_but_how_samples_are_drawn():
    """Under an error target the calibration loses its counts and its plugin's sampling options
    (the image's renders measure the preset's error, so they draw samples as the preset does);
    whatever else it sets stays."""
    plugin = BackendPlugin(name="x", options=BackendOptions, backend="nowhere:X", sampling_options=("supersample",),
                           calibrated={"high": {"samples": 8, "denoise": True, "denoise_quality": "balanced"}})
    error = Quality(level="high", control="error")
    assert plugin.calibration(BackendOptions(name="x"), error) == {"denoise": True, "denoise_quality": "balanced"}
    filled = plugin.options_for(BackendOptions(name="x"), error)
    assert (filled.samples, filled.denoise, filled.denoise_quality) == (None, True, "balanced")


@pytest.mark.parametrize("bad", [0, 5])
def test_supersample_is_bounded(bad):
    from pydantic import ValidationError

    with pytest.raises(ValidationError, match="supersample"):
        BackendOptions(name="x", supersample=bad)


def test_the_first_pair_of_an_error_target_costs_a_calibrated_supersampled_render():
    """Under an error target an image renders at its own resolution: its first pair takes half the
    samples per pixel a calibrated render traces, f^2 times its count when supersampled."""
    plugin = BackendPlugin(name="x", options=BackendOptions, backend="nowhere:X",
                           calibrated={"high": {"samples": 6, "denoise": True, "supersample": 3}})
    target = plugin.error_target(BackendOptions(name="x"), Quality(level="high", control="error"))
    assert target.start_samples == 27  # 6 x 3^2 / 2


class _Recording:
    """A backend that records the cameras it renders and draws each pixel's column index."""

    def __init__(self):
        self.cameras = []

    def render(self, cam, preset, seed, clamp=None):
        self.cameras.append(cam)
        lin = np.broadcast_to(np.arange(cam.width, dtype=np.float32)[None, :, None], (cam.height, cam.width, 3))
        return RenderResult(rgb=linear_to_srgb8(lin), linear=np.ascontiguousarray(lin), stats={"samples": 3})


def test_render_at_renders_the_larger_camera_and_returns_the_images_size():
    from specsynth.run.render import render_at

    backend, cam = _Recording(), _camera(50.0, 50.0, 15.5, 11.5, w=32, h=24)
    res = render_at(backend, cam, None, 0, None, supersample=2)
    assert backend.cameras == [cam.scaled(2)] and res.linear.shape == (24, 32, 3)
    assert np.allclose(res.linear[0, :, 0], 2 * np.arange(32) + 0.5)  # columns 2u and 2u + 1 averaged
    assert render_at(backend, cam, None, 0, None).linear.shape == (24, 32, 3) and backend.cameras[-1] == cam


def test_a_builds_render_setup_carries_its_levels_supersampling(tmp_path):
    """What a build's render step renders with: the calibrated factor of its level, 1 elsewhere."""
    import dataclasses

    from specsynth.plan.compiler import compile_spec
    from specsynth.plugins import backend_plugin
    from specsynth.run.render import RenderSetup
    from specsynth.spec.yamlio import load_spec

    spec = tmp_path / "t.yaml"
    spec.write_text(TINY.replace("BACKEND", "cycles").replace("control: error", "control: samples"))
    plugin = dataclasses.replace(backend_plugin("cycles"), calibrated={"high": {"samples": 3, "supersample": 2,
                                                                                "denoise": True}})
    for level, factor in (("high", 2), ("low", 1), ("paper_high", 1)):
        graph = compile_spec(load_spec(spec, [f"quality.level={level}"]))
        assert RenderSetup.of(graph.inputs.render, plugin).supersample == factor
    graph = compile_spec(load_spec(spec, ["quality.level=high", "backend.samples=20"]))
    assert RenderSetup.of(graph.inputs.render, plugin).supersample == 1

