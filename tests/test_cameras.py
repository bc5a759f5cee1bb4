import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from specsynth.spec.models import Cameras, Intrinsics
from specsynth.views.cameras import (
    CameraSample,
    camera_ir,
    camera_pose,
    intrinsics_matrix,
    look_at,
    project,
    rotate_inplane,
    sample_camera,
    spherical_offset,
)

coord = st.floats(-100, 100, allow_nan=False)
vec3 = st.tuples(coord, coord, coord)
angle = st.floats(-720, 720, allow_nan=False)
elev = st.one_of(st.sampled_from([-90.0, 90.0, 0.0]), st.floats(-90, 90, allow_nan=False))
dist = st.floats(1e-3, 1e4, allow_nan=False)
INTR = Intrinsics()
K = intrinsics_matrix(INTR)
PP = np.array([INTR.cx, INTR.cy])


def assert_rotation(R):
    assert np.isfinite(R).all()
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)
    assert abs(np.linalg.det(R) - 1.0) < 1e-9


@given(eye=vec3, target=vec3, up=vec3)
def test_look_at_orthonormal_for_any_up(eye, target, up):
    assume(np.linalg.norm(np.subtract(target, eye)) > 1e-3)
    R, t = look_at(eye, target, up)
    assert_rotation(R)
    # the optical axis points at the target, and the camera sits at eye
    fwd = np.subtract(target, eye) / np.linalg.norm(np.subtract(target, eye))
    np.testing.assert_allclose(R[2], fwd, atol=1e-9)
    np.testing.assert_allclose(-R.T @ t, eye, atol=1e-9 * (1 + np.abs(eye).max()))


@pytest.mark.parametrize("up", [(0, 0, 1), (0, 0, -1), (0, 0, 5), (0, 0, 0), (np.nan, 0, 0), (0, 0, 1 + 1e-12)])
@pytest.mark.parametrize("direction", [(0, 0, 1), (0, 0, -1)])
def test_look_at_parallel_up_is_deterministic(up, direction):
    eye = np.array([0.1, 0.2, 0.3])
    R1, t1 = look_at(eye, eye + np.array(direction), up)
    R2, t2 = look_at(eye, eye + np.array(direction), up)
    assert_rotation(R1)
    np.testing.assert_array_equal(R1, R2)
    np.testing.assert_array_equal(t1, t2)


def test_look_at_axes_opencv():
    # Looking north (+Y) with Z up: image right is east (+X), image down is -Z.
    R, _ = look_at((0, 0, 0), (0, 1, 0))
    np.testing.assert_allclose(R, [[1, 0, 0], [0, 0, -1], [0, 1, 0]], atol=1e-15)


def test_look_at_rejects_coincident_points():
    with pytest.raises(ValueError):
        look_at((1, 2, 3), (1, 2, 3))


@given(target=vec3, az=angle, el=elev, d=dist, inplane=angle)
@settings(max_examples=200)
def test_camera_pose_properties(target, az, el, d, inplane):
    R, t = camera_pose(target, az, el, d, inplane)
    assert_rotation(R)
    centre = -R.T @ t
    scale = 1 + np.abs(target).max() + d
    assert abs(np.linalg.norm(centre - np.asarray(target)) - d) <= 1e-9 * scale
    # the target sits on the optical axis: it projects to the principal point, in-plane or not
    uv = project(K, R, t, [target])[0]
    np.testing.assert_allclose(uv, PP, atol=1e-6 * scale / d)


@given(target=vec3, az=angle, el=st.floats(-90, 90, allow_nan=False), d=dist)
def test_azimuth_wraps(target, az, el, d):
    R1, t1 = camera_pose(target, az, el, d)
    R2, t2 = camera_pose(target, az + 360.0, el, d)
    np.testing.assert_allclose(R1, R2, atol=1e-9)
    np.testing.assert_allclose(t1, t2, atol=1e-9 * (1 + np.abs(target).max() + d))


@given(az=angle, el=st.floats(-89.9, 89.9), d=st.floats(0.1, 10))
def test_sphere_camera_is_upright(az, el, d):
    # Without in-plane rotation world +Z points up in the image (negative camera y).
    R, _ = camera_pose((0, 0, 0), az, el, d)
    assert R[1] @ np.array([0, 0, 1.0]) < 0
    assert abs(R[0, 2]) < 1e-9  # image x axis is horizontal


def test_poles_continuous_in_azimuth():
    for el in (90.0, -90.0):
        R_pole, _ = camera_pose((0, 0, 0), 30.0, el, 1.0)
        R_near, _ = camera_pose((0, 0, 0), 30.0, el - np.sign(el) * 1e-6, 1.0)
        np.testing.assert_allclose(R_pole, R_near, atol=1e-6)


@given(inplane=angle)
def test_inplane_rotates_about_optical_axis(inplane):
    R, t = camera_pose((0.1, -0.2, 0.0), 40.0, 30.0, 1.0)
    R2, t2 = rotate_inplane(R, t, inplane)
    np.testing.assert_allclose(R2[2], R[2], atol=1e-12)
    np.testing.assert_allclose(-R2.T @ t2, -R.T @ t, atol=1e-12)
    # a point right of the centre turns by `inplane` degrees (clockwise on screen, y down)
    p_world = -R.T @ t + R.T @ np.array([0.1, 0.0, 1.0])
    u, v = project(K, R2, t2, [p_world])[0] - PP
    a = np.radians(inplane)
    np.testing.assert_allclose([u / INTR.fx, v / INTR.fy], [0.1 * np.cos(a), 0.1 * np.sin(a)], atol=1e-9)


def test_spherical_offset():
    np.testing.assert_allclose(spherical_offset(0, 0, 2), [2, 0, 0], atol=1e-15)
    np.testing.assert_allclose(spherical_offset(90, 0, 1), [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(spherical_offset(123, 90, 1), [0, 0, 1], atol=1e-15)
    np.testing.assert_allclose(spherical_offset(0, -90, 3), [0, 0, -3], atol=1e-15)


ranges = st.tuples(st.floats(-720, 720), st.floats(-720, 720)).map(sorted)


@given(
    seed=st.integers(0, 2**32 - 1),
    az=ranges,
    el=st.tuples(st.floats(-90, 90), st.floats(-90, 90)).map(sorted),
    d=st.tuples(st.floats(0.02, 100), st.floats(0.02, 100)).map(sorted),
    inplane=st.tuples(st.floats(-360, 360), st.floats(-360, 360)).map(sorted),
)
def test_sample_camera(seed, az, el, d, inplane):
    cams = Cameras(azimuth=az, elevation=el, distance=d, inplane=inplane)
    target = np.array([0.3, -0.1, 0.05])
    rng = np.random.default_rng(seed)
    s = sample_camera(rng, target, cams)
    assert isinstance(s, CameraSample)
    assert az[0] <= s.azimuth <= az[1] and el[0] <= s.elevation <= el[1]
    assert d[0] <= s.distance <= d[1] and inplane[0] <= s.inplane <= inplane[1]
    assert_rotation(s.R_w2c)
    assert abs(np.linalg.norm(s.center - target) - s.distance) < 1e-9 * (1 + s.distance)
    np.testing.assert_allclose(project(K, s.R_w2c, s.t_w2c, [target])[0], PP, atol=1e-6)
    # fixed draw count: the generator's state afterwards does not depend on the ranges
    ref = np.random.default_rng(seed)
    ref.random(4)
    assert rng.random() == ref.random()
    # determinism
    s2 = sample_camera(np.random.default_rng(seed), target, cams)
    np.testing.assert_array_equal(s.R_w2c, s2.R_w2c)
    np.testing.assert_array_equal(s.t_w2c, s2.t_w2c)


@settings(max_examples=200, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    offset=st.tuples(st.floats(0, 1), st.floats(0, 1)).map(sorted),
    cx=st.floats(0.05, 0.95), cy=st.floats(0.05, 0.95), fy_over_fx=st.floats(0.5, 2.0),
)
def test_an_aim_offset_puts_the_target_where_it_says_inside_the_image(seed, offset, cx, cy, fy_over_fx):
    """The focused object's centre appears ``f`` of the way from the principal point to the largest
    ellipse about it inside the image, f drawn in the range: always in the image. The camera stays
    where it was (distance, azimuth, elevation kept); only its direction turns. Two more draws."""
    intr = Intrinsics(width=640, height=480, fx=572.0, fy=572.0 * fy_over_fx, cx=cx * 639, cy=cy * 479)
    cams = Cameras(distance=(0.5, 1.2), aim_offset=tuple(offset), inplane=(-30, 30))
    target = np.array([0.3, -0.1, 0.05])
    rng = np.random.default_rng(seed)
    s = sample_camera(rng, target, cams, intr)
    assert_rotation(s.R_w2c)
    assert abs(np.linalg.norm(s.center - target) - s.distance) < 1e-9 * (1 + s.distance)
    u, v = project(intrinsics_matrix(intr), s.R_w2c, s.t_w2c, [target])[0]
    a, b = min(intr.cx, 639 - intr.cx), min(intr.cy, 479 - intr.cy)
    f = np.hypot((u - intr.cx) / a, (v - intr.cy) / b)
    assert offset[0] - 1e-7 <= f <= offset[1] + 1e-7
    assert -1e-6 <= u <= 639 + 1e-6 and -1e-6 <= v <= 479 + 1e-6
    ref = np.random.default_rng(seed)
    ref.random(4)
    if offset[1] > 0:
        ref.random(2)
    assert rng.random() == ref.random()
    centred = sample_camera(np.random.default_rng(seed), target, Cameras(distance=(0.5, 1.2), inplane=(-30, 30)), intr)
    np.testing.assert_allclose(centred.center, s.center, atol=1e-12)


def test_no_aim_offset_draws_the_cameras_drawn_before_there_was_one():
    """A spec that sets no offset builds the images it built before the field existed."""
    cams = Cameras(distance=(0.5, 1.2), inplane=(-30, 30))
    for seed in range(20):
        a = sample_camera(np.random.default_rng(seed), np.zeros(3), cams, INTR)
        b = sample_camera(np.random.default_rng(seed), np.zeros(3), cams)
        np.testing.assert_array_equal(a.R_w2c, b.R_w2c)
        np.testing.assert_allclose(project(K, a.R_w2c, a.t_w2c, [np.zeros(3)])[0], PP, atol=1e-6)


@given(seed=st.integers(0, 2**32 - 1), el=st.tuples(st.floats(-90, 90), st.floats(-90, 90)).map(sorted))
def test_area_sampling_keeps_the_range_and_the_draw_count(seed, el):
    cams = Cameras(elevation=el, elevation_sampling="area")
    rng = np.random.default_rng(seed)
    s = sample_camera(rng, np.zeros(3), cams)
    assert el[0] <= s.elevation <= el[1]
    ref = np.random.default_rng(seed)
    ref.random(4)
    assert rng.random() == ref.random()
    angle = sample_camera(np.random.default_rng(seed), np.zeros(3), Cameras(elevation=el))
    assert (angle.azimuth, angle.distance, angle.inplane) == (s.azimuth, s.distance, s.inplane)


@pytest.mark.parametrize("el", [(12.0, 74.0), (-30.0, 80.0), (0.0, 90.0)])
def test_area_sampling_is_uniform_over_the_sphere(el):
    """Positions uniform over the band's area: their height above the target's plane (the sine
    of the elevation) is uniform between the band's edges."""
    from scipy.stats import kstest, uniform

    rng = np.random.default_rng(7)
    cams = Cameras(elevation=el, elevation_sampling="area")
    heights = [np.sin(np.radians(sample_camera(rng, np.zeros(3), cams).elevation)) for _ in range(4000)]
    lo, hi = np.sin(np.radians(el[0])), np.sin(np.radians(el[1]))
    assert kstest(heights, uniform(loc=lo, scale=hi - lo).cdf).pvalue > 1e-3
    angles = [sample_camera(rng, np.zeros(3), Cameras(elevation=el)).elevation for _ in range(4000)]
    assert kstest(np.sin(np.radians(angles)), uniform(loc=lo, scale=hi - lo).cdf).pvalue < 1e-6


def test_sample_camera_range_limits():
    cams = Cameras(azimuth=(10, 10), elevation=(90, 90), distance=(0.4, 0.4), inplane=(0, 0))
    s = sample_camera(np.random.default_rng(0), np.zeros(3), cams)
    assert (s.azimuth, s.elevation, s.distance, s.inplane) == (10.0, 90.0, 0.4, 0.0)
    np.testing.assert_allclose(s.center, [0, 0, 0.4], atol=1e-12)
    assert_rotation(s.R_w2c)


def test_camera_ir_and_intrinsics():
    intr = Intrinsics(width=64, height=48, fx=50, fy=60, cx=31.5, cy=23.5, clip=(0.05, 20))
    R, t = camera_pose((0, 0, 0), 10, 20, 1.0)
    cam = camera_ir(intr, R, t)
    assert (cam.width, cam.height, cam.near, cam.far) == (64, 48, 0.05, 20.0)
    np.testing.assert_array_equal(cam.K_array, [[50, 0, 31.5], [0, 60, 23.5], [0, 0, 1]])
    np.testing.assert_allclose(cam.T_w2c[:3, :3], R)
    np.testing.assert_allclose(cam.T_w2c[:3, 3], t)
    hash(cam)  # tuples only: hashable and picklable


def test_project_known_point():
    uv = project(K, np.eye(3), np.zeros(3), [[0.1, -0.2, 2.0]])
    np.testing.assert_allclose(uv, [[INTR.cx + INTR.fx * 0.05, INTR.cy - INTR.fy * 0.1]])
