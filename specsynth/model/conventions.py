"""Frame and unit conversions: the one place where OpenCV, OpenGL, Blender and Mitsuba meet.

specsynth's camera is OpenCV's (x right, y down, z forward); world is metres, Z up.
- OpenGL / pyrender / Blender camera objects look down their local -Z with +Y up: flip Y and Z.
- Mitsuba's ``perspective`` sensor looks down +Z with +Y up and +X to the *left* in the image
  (it is a right-handed look-at): flip X and Y.
"""

from __future__ import annotations

import math

import numpy as np

M_TO_MM = 1000.0

_FLIP_YZ = np.diag([1.0, -1.0, -1.0])
_FLIP_XY = np.diag([-1.0, -1.0, 1.0])


def cam_to_world(R_w2c: np.ndarray, t_w2c: np.ndarray) -> np.ndarray:
    """4x4 world-from-camera (OpenCV axes) from a world-to-camera rotation and translation."""
    R = np.asarray(R_w2c, dtype=np.float64)
    T = np.eye(4)
    T[:3, :3] = R.T
    T[:3, 3] = -R.T @ np.asarray(t_w2c, dtype=np.float64)
    return T


def opencv_to_opengl_c2w(T_c2w_cv: np.ndarray) -> np.ndarray:
    """Camera pose for OpenGL-style cameras (pyrender, Blender camera objects)."""
    T = np.array(T_c2w_cv, dtype=np.float64, copy=True)
    T[:3, :3] = T[:3, :3] @ _FLIP_YZ
    return T


opencv_to_blender_c2w = opencv_to_opengl_c2w


def opencv_to_mitsuba_c2w(T_c2w_cv: np.ndarray) -> np.ndarray:
    """Sensor ``to_world`` for Mitsuba's perspective camera."""
    T = np.array(T_c2w_cv, dtype=np.float64, copy=True)
    T[:3, :3] = T[:3, :3] @ _FLIP_XY
    return T


def m_to_mm(x):
    return np.asarray(x, dtype=np.float64) * M_TO_MM


def mm_to_m(x):
    return np.asarray(x, dtype=np.float64) / M_TO_MM


def model_to_camera(T_w2c: np.ndarray, T_world_model: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """BOP ``cam_R_m2c`` and ``cam_t_m2c`` (metres) of a model placed at ``T_world_model``."""
    T = np.asarray(T_w2c) @ np.asarray(T_world_model)
    return T[:3, :3], T[:3, 3]


def opengl_projection(K: np.ndarray, width: int, height: int, near: float, far: float) -> np.ndarray:
    """OpenGL projection matrix reproducing pinhole ``K`` exactly (pixel centres at +0.5).

    With it, a point projecting to OpenCV pixel (u, v) lands in the pixel whose centre is (u, v)
    after the viewport transform, so rasterised masks match ``K @ x`` projections.
    """
    K = np.asarray(K, dtype=np.float64)
    fx, fy, cx, cy, s = K[0, 0], K[1, 1], K[0, 2], K[1, 2], K[0, 1]
    P = np.zeros((4, 4))
    P[0, 0] = 2 * fx / width
    P[0, 1] = -2 * s / width
    P[0, 2] = 1 - 2 * (cx + 0.5) / width
    P[1, 1] = 2 * fy / height
    P[1, 2] = 2 * (cy + 0.5) / height - 1
    P[2, 2] = -(far + near) / (far - near)
    P[2, 3] = -2 * far * near / (far - near)
    P[3, 2] = -1
    return P


def rpy_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """URDF/ROS fixed-axis convention (radians): R = Rz(yaw) @ Ry(pitch) @ Rx(roll)."""
    cr, sr, cp, sp, cy, sy = (math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch),
                              math.cos(yaw), math.sin(yaw))
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


def rotation_vector_matrix(r) -> np.ndarray:
    """Rodrigues: the rotation by angle |r| (radians) about the axis r / |r|."""
    r = np.asarray(r, dtype=np.float64)
    theta = float(np.linalg.norm(r))
    if theta < 1e-15:
        return np.eye(3)
    k = r / theta
    Kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + math.sin(theta) * Kx + (1.0 - math.cos(theta)) * (Kx @ Kx)


def c2w_during_exposure(T_c2w: np.ndarray, motion, s: float) -> np.ndarray:
    """Camera-to-world (OpenCV camera) at exposure fraction ``s`` in [-1/2, 1/2] of a camera whose
    mid-exposure pose is ``T_c2w`` and which travels ``motion[:3]`` metres and turns by the rotation
    vector ``motion[3:]`` (its own frame at mid-exposure) from shutter open to close."""
    if not motion:
        return np.asarray(T_c2w, dtype=np.float64)
    delta = np.eye(4)
    delta[:3, :3] = rotation_vector_matrix(s * np.asarray(motion[3:6], dtype=np.float64))
    delta[:3, 3] = s * np.asarray(motion[:3], dtype=np.float64)
    return np.asarray(T_c2w, dtype=np.float64) @ delta
