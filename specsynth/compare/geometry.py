"""Geometry statistics of annotated instances: pure math on poses, boxes and visible fractions.

Frames: OpenCV camera (x right, y down, z forward), ``t_m2c`` in metres. The scene's *up* in the
camera frame is known for a synthetic image (world +Z through ``cam_R_w2c``) and for real
datasets whose ``scene_camera.json`` carries ``cam_R_w2c`` of a Z-up world; otherwise it is
estimated from the annotated objects, which stand upright in test scenes such as LM-O's
(:func:`up_from_objects`).
"""

from __future__ import annotations

import numpy as np

OUTLIER_DEG = 30.0  # objects whose +Z is farther than this from the first estimate are left out


def up_from_world(R_w2c) -> np.ndarray:
    """World +Z in the camera frame."""
    return np.asarray(R_w2c, np.float64).reshape(3, 3)[:, 2].copy()


def up_from_objects(rotations) -> np.ndarray | None:
    """The scene's up in the camera frame from its objects' model +Z axes (upright objects): their
    normalised mean, then the mean of those within ``OUTLIER_DEG`` of it (a toppled object does
    not tilt the estimate). None without objects."""
    zs = np.array([np.asarray(R, np.float64).reshape(3, 3)[:, 2] for R in rotations]).reshape(-1, 3)
    if not len(zs):
        return None
    m = zs.mean(0)
    if np.linalg.norm(m) < 1e-9:
        return None
    m /= np.linalg.norm(m)
    keep = zs @ m >= np.cos(np.radians(OUTLIER_DEG))
    if keep.any():
        m = zs[keep].mean(0)
        m /= np.linalg.norm(m)
    return m


def centre_offset(t_m2c, K) -> float:
    """Pixels from the principal point to the projection of the model's origin: the object a
    camera aims at is the one nearest the centre (inf behind the camera)."""
    t = np.asarray(t_m2c, np.float64)
    if t[2] <= 0:
        return float("inf")
    K = np.asarray(K, np.float64)
    u, v = K[0, 0] * t[0] / t[2] + K[0, 2], K[1, 1] * t[1] / t[2] + K[1, 2]
    return float(np.hypot(u - K[0, 2], v - K[1, 2]))


def aim_fraction(t_m2c, K, width: int, height: int) -> float:
    """Where the model's origin projects, as the spec's ``cameras.aim_offset`` measures it: 0 at
    the principal point, 1 on the largest ellipse about it inside the image (inf behind the
    camera; above 1 outside that ellipse)."""
    t = np.asarray(t_m2c, np.float64)
    if t[2] <= 0:
        return float("inf")
    K = np.asarray(K, np.float64)
    cx, cy = K[0, 2], K[1, 2]
    a, b = min(cx, width - 1 - cx), min(cy, height - 1 - cy)
    if a <= 0 or b <= 0:
        return float("nan")
    du, dv = K[0, 0] * t[0] / t[2] / a, K[1, 1] * t[1] / t[2] / b
    return float(np.hypot(du, dv))


def distance(t_m2c) -> float:
    """Distance from the camera centre to the model's origin (BOP: its bounding-box centre), m."""
    return float(np.linalg.norm(np.asarray(t_m2c, np.float64)))


def elevation(t_m2c, up) -> float:
    """Degrees of the camera above the plane through the object perpendicular to ``up``: the
    spec's ``cameras.elevation`` for the object a camera aims at."""
    t = np.asarray(t_m2c, np.float64)
    n = np.linalg.norm(t)
    if n <= 0:
        return float("nan")
    s = float(np.dot(-t / n, np.asarray(up, np.float64)))
    return float(np.degrees(np.arcsin(np.clip(s, -1.0, 1.0))))


def inplane(up) -> float:
    """Degrees the image is turned about the optical axis: the angle from the image's up (-y) to
    the projection of the scene's up, positive clockwise on screen (the spec's ``cameras.inplane``).
    NaN when the camera looks along ``up`` (within 10 degrees), where no roll is defined."""
    u = np.asarray(up, np.float64)
    if np.hypot(u[0], u[1]) < np.sin(np.radians(10.0)) * np.linalg.norm(u):
        return float("nan")
    return float(np.degrees(np.arctan2(u[0], -u[1])))


def box_size(bbox) -> float:
    """Square root of the area of a BOP box ``[x, y, w, h]`` (w = xmax - xmin), pixels."""
    w, h = bbox[2] + 1, bbox[3] + 1
    return float(np.sqrt(max(w, 0) * max(h, 0)))


def truncation(bbox, width: int, height: int) -> float:
    """Share of the amodal box (``bbox_obj``, unclipped) that lies outside the image."""
    x, y, w, h = bbox
    x1, y1 = x + w + 1, y + h + 1  # exclusive ends
    area = (w + 1) * (h + 1)
    if area <= 0:
        return float("nan")
    ix = max(0, min(x1, width) - max(x, 0))
    iy = max(0, min(y1, height) - max(y, 0))
    return float(1.0 - ix * iy / area)
