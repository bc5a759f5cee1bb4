"""Camera sampling and look-at: pure math, no I/O, no renderer.

Conventions (see ``specsynth.model.conventions``): world metres with Z up; cameras are OpenCV's
(x right, y down, z forward) and are described by ``R_w2c``/``t_w2c`` with
``x_c = R_w2c @ x_w + t_w2c``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from specsynth.model.ir import CameraIR, as_tuple

if TYPE_CHECKING:  # spec is pydantic-heavy; cameras only reads attributes from it
    from specsynth.spec.models import Cameras, Intrinsics

_WORLD_AXES = np.eye(3)
# Below this |sin| between the view direction and `up`, `up` no longer defines a roll; the
# re-orthogonalisation in `look_at` keeps the result orthonormal to ~1e-15 well above it.
_PARALLEL_EPS = 1e-6


def _unit(v: np.ndarray) -> tuple[np.ndarray, float]:
    n = float(np.linalg.norm(v))
    return (v / n if n > 0 else v), n


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> tuple[np.ndarray, np.ndarray]:
    """World-to-camera rotation and translation of an OpenCV camera at ``eye`` looking at ``target``.

    The image's "up" (-y) is the projection of ``up`` onto the image plane. When ``up`` is
    (nearly) parallel to the view direction, zero or not finite, the world axis least aligned
    with the view direction is used instead (first of X, Y, Z on ties) so the pose stays finite,
    orthonormal and deterministic.
    """
    eye = np.asarray(eye, dtype=np.float64).reshape(3)
    target = np.asarray(target, dtype=np.float64).reshape(3)
    z, dist = _unit(target - eye)
    if not np.isfinite(dist) or dist <= 0.0:
        raise ValueError(f"look_at: eye {eye} and target {target} must be distinct finite points")

    up = np.asarray(up, dtype=np.float64).reshape(3)
    up, up_norm = _unit(up) if np.isfinite(up).all() else (up, 0.0)
    x = np.cross(z, up) if up_norm > 0 else np.zeros(3)
    x, sin_angle = _unit(x)
    if sin_angle < _PARALLEL_EPS:
        fallback = _WORLD_AXES[int(np.argmin(np.abs(_WORLD_AXES @ z)))]
        x, _ = _unit(np.cross(z, fallback))
    # One Gram-Schmidt step removes the rounding left by the cross product of nearly parallel
    # vectors, so orthonormality holds to machine precision for any `up`.
    x, _ = _unit(x - (x @ z) * z)
    y = np.cross(z, x)  # down in the image; right-handed: x × y = z
    R = np.stack([x, y, z])
    t = -R @ eye
    return R, t


def spherical_offset(azimuth_deg: float, elevation_deg: float, distance: float) -> np.ndarray:
    """Offset from a target to a camera: azimuth about world +Z from +X, elevation above XY."""
    az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
    return distance * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])


def _elevation_tangent(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """Unit direction of increasing elevation at (azimuth, elevation) on the viewing sphere.

    For |elevation| < 90 it is the component of world +Z perpendicular to the view direction, so
    using it as ``up`` gives exactly the Z-up look-at; unlike +Z it never becomes parallel to the
    view direction, so poses stay continuous in azimuth through the poles.
    """
    az, el = np.radians(azimuth_deg), np.radians(elevation_deg)
    return np.array([-np.sin(el) * np.cos(az), -np.sin(el) * np.sin(az), np.cos(el)])


def rotate_inplane(R_w2c: np.ndarray, t_w2c: np.ndarray, angle_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Rotate a camera about its own optical axis; positive turns image content clockwise.

    The camera centre and the optical axis are unchanged, so whatever projected to the principal
    point still does.
    """
    a = np.radians(angle_deg)
    c, s = np.cos(a), np.sin(a)
    Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return Rz @ np.asarray(R_w2c, dtype=np.float64), Rz @ np.asarray(t_w2c, dtype=np.float64)


@dataclass(frozen=True, eq=False)
class CameraSample:
    R_w2c: np.ndarray  # (3, 3)
    t_w2c: np.ndarray  # (3,), metres
    azimuth: float  # degrees
    elevation: float  # degrees
    distance: float  # metres
    inplane: float  # degrees

    @property
    def center(self) -> np.ndarray:
        """Camera centre in world coordinates, metres."""
        return -self.R_w2c.T @ self.t_w2c


def camera_pose(target, azimuth: float, elevation: float, distance: float, inplane: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Pose of a camera on the viewing sphere around ``target``, looking at it."""
    target = np.asarray(target, dtype=np.float64).reshape(3)
    eye = target + spherical_offset(azimuth, elevation, distance)
    R, t = look_at(eye, target, up=_elevation_tangent(azimuth, elevation))
    return rotate_inplane(R, t, inplane)


def elevation_on_area(u: float, lo: float, hi: float) -> float:
    """The elevation (degrees) at quantile ``u`` of positions uniform over the area of the viewing
    sphere's band between ``lo`` and ``hi``: the band's area up to elevation e grows as sin(e)."""
    s_lo, s_hi = math.sin(math.radians(lo)), math.sin(math.radians(hi))
    el = math.degrees(math.asin(min(1.0, max(-1.0, s_lo + u * (s_hi - s_lo)))))
    return min(max(el, lo), hi)


def sample_camera(rng: np.random.Generator, target, cams: "Cameras", intr: "Intrinsics | None" = None) -> CameraSample:
    """One camera around ``target`` with parameters uniform in the spec's ranges, the elevation in
    angle or over the sphere's area (``cams``: the spec's cameras or the view step's cut of them,
    ``specsynth.plan.inputs.CameraDraws``), turned so that ``target`` appears ``aim_offset`` away
    from the principal point of ``intr`` (``aim_off``).

    Consumes exactly one ``rng.random(4)`` draw (azimuth, elevation, distance, in-plane, in that
    order), degenerate ranges included, and with an ``aim_offset`` above 0 one ``rng.random(2)``
    more (its size, its direction): a job's seed fixes the whole camera sequence, and a spec
    without an offset draws the cameras it drew before there was one.
    """
    u = rng.random(4)
    ranges = (cams.azimuth, cams.elevation, cams.distance, cams.inplane)
    az, el, dist, inplane = (float(lo + ui * (hi - lo)) for ui, (lo, hi) in zip(u, ranges))
    if cams.elevation_sampling == "area":
        el = elevation_on_area(float(u[1]), *cams.elevation)
    R, t = camera_pose(target, az, el, dist, inplane)
    lo, hi = cams.aim_offset
    if hi > 0:
        if intr is None:
            raise ValueError("cameras.aim_offset needs the intrinsics to place the target in the image")
        f_u, phi_u = rng.random(2)
        R, t = aim_off(R, t, intr, lo + float(f_u) * (hi - lo), 2.0 * math.pi * float(phi_u))
    return CameraSample(R_w2c=R, t_w2c=t, azimuth=az, elevation=el, distance=dist, inplane=inplane)


def aim_off(R_w2c: np.ndarray, t_w2c: np.ndarray, intr: "Intrinsics", fraction: float,
            angle: float) -> tuple[np.ndarray, np.ndarray]:
    """A camera turned about its centre so that what lay on its optical axis appears at
    ``fraction`` of the way from the principal point to the largest ellipse about it inside the
    image, in the image direction ``angle`` (radians from +x towards +y)."""
    a = min(intr.cx, intr.width - 1 - intr.cx)
    b = min(intr.cy, intr.height - 1 - intr.cy)
    du, dv = fraction * a * math.cos(angle), fraction * b * math.sin(angle)
    ray = np.array([du / intr.fx, dv / intr.fy, 1.0])
    ray /= np.linalg.norm(ray)
    Q = _rotation_between(np.array([0.0, 0.0, 1.0]), ray)
    return Q @ np.asarray(R_w2c, np.float64), Q @ np.asarray(t_w2c, np.float64)


def _rotation_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The least rotation taking unit vector ``a`` to unit vector ``b`` (not opposite to ``a``)."""
    axis = np.cross(a, b)
    s, c = float(np.linalg.norm(axis)), float(a @ b)
    if s < 1e-15:
        return np.eye(3)
    k = axis / s
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + s * K + (1.0 - c) * (K @ K)


def intrinsics_matrix(intr: "Intrinsics") -> np.ndarray:
    return np.array([[intr.fx, 0.0, intr.cx], [0.0, intr.fy, intr.cy], [0.0, 0.0, 1.0]])


def camera_ir(intr: "Intrinsics", R_w2c, t_w2c) -> CameraIR:
    near, far = intr.clip
    return CameraIR(
        K=as_tuple(intrinsics_matrix(intr)),
        width=int(intr.width),
        height=int(intr.height),
        R_w2c=as_tuple(np.asarray(R_w2c).reshape(3, 3)),
        t_w2c=as_tuple(np.asarray(t_w2c).reshape(3)),
        near=float(near),
        far=float(far),
    )


def project(K, R, t, points) -> np.ndarray:
    """Pixel coordinates (N, 2) of world points; pixel (u, v) has its centre at integer (u, v)."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    x_c = pts @ np.asarray(R, dtype=np.float64).T + np.asarray(t, dtype=np.float64).reshape(3)
    uvw = x_c @ np.asarray(K, dtype=np.float64).T
    return uvw[:, :2] / uvw[:, 2:3]
