"""A window of an image as a camera of its own (``CameraIR.cropped``) and the bench's centred
window (``specsynth bench --ref-crop``)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from specsynth.model.ir import CameraIR, as_tuple
from specsynth.run.bench import centre_window, in_window
from specsynth.views.cameras import project


def _camera(fx, fy, cx, cy, w=64, h=48) -> CameraIR:
    return CameraIR(K=((fx, 0.0, cx), (0.0, fy, cy), (0.0, 0.0, 1.0)), width=w, height=h,
                    R_w2c=as_tuple(np.eye(3)), t_w2c=(0.0, 0.0, 0.0))


@settings(max_examples=200, deadline=None)
@given(fx=st.floats(10, 2000), fy=st.floats(10, 2000), cx=st.floats(-50, 120), cy=st.floats(-50, 100),
       x0=st.integers(0, 63), y0=st.integers(0, 47), data=st.data(),
       x=st.floats(-2, 2), y=st.floats(-2, 2), z=st.floats(0.1, 10))
def test_a_cropped_camera_sees_each_point_at_its_pixel_less_the_windows_corner(fx, fy, cx, cy, x0, y0, data, x, y, z):
    cam = _camera(fx, fy, cx, cy)
    w, h = data.draw(st.integers(1, 64 - x0)), data.draw(st.integers(1, 48 - y0))
    part = cam.cropped(x0, y0, w, h)
    X = np.array([[x, y, z]])
    p, q = (project(c.K, c.R_w2c, c.t_w2c, X)[0] for c in (cam, part))
    assert np.allclose(q, p - (x0, y0), rtol=1e-9, atol=1e-6 * max(1.0, abs(p).max()))
    assert (part.width, part.height) == (w, h)
    assert (part.R_w2c, part.t_w2c, part.motion, part.aperture) == (cam.R_w2c, cam.t_w2c, cam.motion, cam.aperture)


@pytest.mark.parametrize("window", [(-1, 0, 8, 8), (0, 0, 65, 48), (60, 0, 5, 8), (0, 0, 0, 8), (0, 0, 8.0, 8),
                                    (True, 0, 8, 8)])
def test_a_window_outside_the_image_or_not_in_whole_pixels_is_refused(window):
    with pytest.raises(ValueError, match="window|whole pixels"):
        _camera(100, 100, 31.5, 23.5).cropped(*window)


@settings(max_examples=300, deadline=None)
@given(width=st.integers(1, 4000), height=st.integers(1, 4000), fraction=st.floats(1e-3, 1.0))
def test_the_centre_window_lies_in_the_image_centred_to_half_a_pixel(width, height, fraction):
    window = centre_window(width, height, fraction)
    if window is None:
        assert (max(1, round(width * fraction)), max(1, round(height * fraction))) == (width, height)
        return
    x0, y0, w, h = window
    assert 0 <= x0 and 0 <= y0 and 1 <= w <= width and 1 <= h <= height and (w, h) != (width, height)
    assert abs((x0 + w / 2) - width / 2) <= 0.5 and abs((y0 + h / 2) - height / 2) <= 0.5
    assert abs(w - width * fraction) <= 0.5 + 1 and abs(h - height * fraction) <= 0.5 + 1
    image = np.arange(width * height).reshape(height, width)
    assert in_window(image, window).shape == (h, w)
    assert in_window(image, window)[0, 0] == image[y0, x0]


@pytest.mark.parametrize("fraction", [0.0, -0.5, 1.5, float("nan")])
def test_a_window_fraction_outside_0_to_1_is_refused(fraction):
    with pytest.raises(ValueError, match="--ref-crop"):
        centre_window(640, 480, fraction)


def test_the_vga_benchs_window_is_its_centre_quarter():
    assert centre_window(640, 480, 0.5) == (160, 120, 320, 240)
    assert centre_window(640, 480, 1.0) is None
