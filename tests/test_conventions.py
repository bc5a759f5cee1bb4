import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from specsynth.model.conventions import (
    M_TO_MM,
    cam_to_world,
    m_to_mm,
    mm_to_m,
    model_to_camera,
    opencv_to_blender_c2w,
    opencv_to_mitsuba_c2w,
    opencv_to_opengl_c2w,
    opengl_projection,
)
from specsynth.views.cameras import camera_pose, project

FLIP_YZ = np.diag([1.0, -1.0, -1.0])


def random_pose(rng):
    return camera_pose(rng.uniform(-1, 1, 3), rng.uniform(0, 360), rng.uniform(-90, 90), rng.uniform(0.2, 5), rng.uniform(-180, 180))


def gl_pixels(P, x_gl, width, height):
    """OpenGL pipeline: clip -> NDC -> window coordinates, returned as OpenCV pixel-centre coordinates."""
    clip = np.c_[x_gl, np.ones(len(x_gl))] @ P.T
    ndc = clip[:, :3] / clip[:, 3:4]
    x_win = (ndc[:, 0] + 1) / 2 * width  # pixel edges at integers, origin bottom-left
    y_win = (ndc[:, 1] + 1) / 2 * height
    # window pixel i spans [i, i+1) with its centre at i + 0.5; OpenCV puts that centre at integer i
    return np.c_[x_win - 0.5, height - y_win - 0.5], ndc[:, 2]


@given(
    fx=st.floats(10, 5000), fy=st.floats(10, 5000), cx=st.floats(-100, 800), cy=st.floats(-100, 600),
    skew=st.sampled_from([0.0, 0.7]), seed=st.integers(0, 2**16),
)
def test_opengl_projection_reproduces_K(fx, fy, cx, cy, skew, seed):
    width, height, near, far = 640, 480, 0.05, 50.0
    K = np.array([[fx, skew, cx], [0, fy, cy], [0, 0, 1]])
    P = opengl_projection(K, width, height, near, far)
    rng = np.random.default_rng(seed)
    x_cv = np.c_[rng.uniform(-1, 1, (20, 2)), rng.uniform(near, far, 20)]
    uv_gl, z_ndc = gl_pixels(P, x_cv @ FLIP_YZ, width, height)
    uv_cv = project(K, np.eye(3), np.zeros(3), x_cv)
    np.testing.assert_allclose(uv_gl, uv_cv, rtol=1e-9, atol=1e-7)
    # depth: standard GL mapping, which pyrender inverts when it linearises its depth buffer
    z = x_cv[:, 2]
    z_lin = 2 * near * far / (far + near - z_ndc * (far - near))
    np.testing.assert_allclose(z_lin, z, rtol=1e-9)


def test_opengl_projection_pixel_centre():
    # A point on the optical axis of a camera with cx = 10 must hit the *centre* of pixel 10.
    K = np.array([[100.0, 0, 10], [0, 100, 7], [0, 0, 1]])
    P = opengl_projection(K, 32, 24, 0.1, 10)
    uv, z = gl_pixels(P, np.array([[0.0, 0.0, -1.0]]), 32, 24)
    np.testing.assert_allclose(uv, [[10.0, 7.0]], atol=1e-12)
    P_near_far = opengl_projection(K, 32, 24, 0.1, 10)
    for depth, ndc in ((0.1, -1.0), (10.0, 1.0)):
        _, z = gl_pixels(P_near_far, np.array([[0.0, 0.0, -depth]]), 32, 24)
        np.testing.assert_allclose(z, [ndc], atol=1e-12)


def test_cam_to_world_inverts_T_w2c():
    rng = np.random.default_rng(1)
    for _ in range(20):
        R, t = random_pose(rng)
        T_w2c = np.eye(4)
        T_w2c[:3, :3], T_w2c[:3, 3] = R, t
        np.testing.assert_allclose(cam_to_world(R, t) @ T_w2c, np.eye(4), atol=1e-12)


def test_opengl_and_mitsuba_frames():
    rng = np.random.default_rng(2)
    for _ in range(20):
        R, t = random_pose(rng)
        T_cv = cam_to_world(R, t)
        x_cv, y_cv, z_cv = T_cv[:3, 0], T_cv[:3, 1], T_cv[:3, 2]
        for T in (opencv_to_opengl_c2w(T_cv), opencv_to_blender_c2w(T_cv)):
            Rg = T[:3, :3]
            assert abs(np.linalg.det(Rg) - 1) < 1e-12
            np.testing.assert_allclose(Rg @ Rg.T, np.eye(3), atol=1e-12)
            np.testing.assert_allclose(-Rg[:, 2], z_cv, atol=1e-12)  # looks down local -Z
            np.testing.assert_allclose(Rg[:, 1], -y_cv, atol=1e-12)  # +Y up in the image
            np.testing.assert_allclose(Rg[:, 0], x_cv, atol=1e-12)
            np.testing.assert_array_equal(T[:3, 3], T_cv[:3, 3])
        Tm = opencv_to_mitsuba_c2w(T_cv)
        Rm = Tm[:3, :3]
        assert abs(np.linalg.det(Rm) - 1) < 1e-12
        np.testing.assert_allclose(Rm[:, 2], z_cv, atol=1e-12)  # looks down +Z
        np.testing.assert_allclose(Rm[:, 1], -y_cv, atol=1e-12)  # +Y up
        np.testing.assert_allclose(Rm[:, 0], -x_cv, atol=1e-12)  # +X to the image's left
        np.testing.assert_array_equal(Tm[:3, 3], T_cv[:3, 3])
        # the input is not modified
        np.testing.assert_array_equal(T_cv, cam_to_world(R, t))


def test_opengl_pose_and_projection_agree_with_opencv():
    """World point -> pyrender view (inverse GL pose) -> GL projection == K [R|t]."""
    rng = np.random.default_rng(3)
    K = np.array([[500.0, 0, 320.3], [0, 510, 239.8], [0, 0, 1]])
    P = opengl_projection(K, 640, 480, 0.01, 100)
    for _ in range(10):
        R, t = random_pose(rng)
        centre = -R.T @ t
        pts = centre + (R.T @ np.c_[rng.uniform(-0.3, 0.3, (5, 2)), rng.uniform(0.5, 2, 5)].T).T
        V = np.linalg.inv(opencv_to_opengl_c2w(cam_to_world(R, t)))
        x_gl = pts @ V[:3, :3].T + V[:3, 3]
        uv_gl, _ = gl_pixels(P, x_gl, 640, 480)
        np.testing.assert_allclose(uv_gl, project(K, R, t, pts), atol=1e-7)


def test_model_to_camera():
    rng = np.random.default_rng(4)
    R, t = random_pose(rng)
    T_w2c = np.eye(4)
    T_w2c[:3, :3], T_w2c[:3, 3] = R, t
    T_wm = np.eye(4)
    T_wm[:3, :3], _ = random_pose(rng)
    T_wm[:3, 3] = [0.1, 0.2, 0.3]
    R_m2c, t_m2c = model_to_camera(T_w2c, T_wm)
    p_model = np.array([0.01, -0.02, 0.03])
    np.testing.assert_allclose(R_m2c @ p_model + t_m2c, R @ (T_wm[:3, :3] @ p_model + T_wm[:3, 3]) + t, atol=1e-12)


@given(x=st.floats(-1e6, 1e6, allow_nan=False))
def test_m_mm_roundtrip(x):
    assert M_TO_MM == 1000.0
    assert float(m_to_mm(x)) == x * 1000.0
    np.testing.assert_allclose(mm_to_m(m_to_mm(x)), x, rtol=1e-15, atol=0)
    np.testing.assert_array_equal(m_to_mm([[0.5, 1.0]]), [[500.0, 1000.0]])
    assert mm_to_m(1500).item() == 1.5
