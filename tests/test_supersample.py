"""Supersampling (``backend.supersample``): the camera at a whole multiple of its resolution, the
render brought back to it, and which options carry it."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from specsynth.model.colour import linear_to_srgb8
from specsynth.views.cameras import project
from specsynth.model.ir import CameraIR, RenderResult, as_tuple
from specsynth.model.supersample import block_mean, downsampled
from specsynth.plugins import BackendPlugin
from specsynth.spec.models import BackendOptions, Quality

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
    for bad in (0, 1.5, -2):
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
    assert np.allclose(small[-1, -1], img[-factor:, -factor:].mean(axis=(0, 1)), rtol=1e-5)


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
    eight_bit = downsampled(RenderResult(rgb=np.full((4, 4, 3), 128, np.uint8)), 2)
    assert eight_bit.linear is None and (eight_bit.rgb == 128).all()
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


@pytest.mark.parametrize("bad", [0, 5])
def test_supersample_is_bounded(bad):
    from pydantic import ValidationError

    with pytest.raises(ValidationError, match="supersample"):
        BackendOptions(name="x", supersample=bad)


def test_the_first_pair_of_an_error_target_costs_a_calibrated_supersampled_render():
    """Under an error target an image renders at its own resolution: its first pair takes half the
    samples per pixel a calibrated render traces, f^2 times its count when supersampled."""
    plugin = BackendPlugin(name="x", options=BackendOptions, backend="nowhere:X",
                           calibrated={"high": {"samples": 4, "denoise": True, "supersample": 2}})
    target = plugin.error_target(BackendOptions(name="x"), Quality(level="high", control="error"))
    assert target.start_samples == 8
