"""Lens distortion: OpenCV's Brown-Conrady model, ``[k1, k2, p1, p2, k3]``, as pure numpy.

A normalised image point (x, y) = ((u - cx) / fx, (v - cy) / fy) of the ideal pinhole is seen at

    r2 = x^2 + y^2,  s = 1 + k1 r2 + k2 r2^2 + k3 r2^3
    x_d = x s + 2 p1 x y + p2 (r2 + 2 x^2)
    y_d = y s + p1 (r2 + 2 y^2) + 2 p2 x y

(``cv2.projectPoints``). An image with distortion is made by rendering the ideal pinhole over
the window of pixels that the distorted image's rays cross, then looking every distorted pixel
up in it at its undistorted position (:func:`undistort_map`): bilinear for colour, nearest for
labels and depth, so every output is the same warp of one render.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

MAX_ITERATIONS = 50
TOLERANCE_PX = 1e-4  # an undistorted point must reproduce its pixel within this


class LensError(ValueError):
    """The coefficients fold the image or cannot be inverted over it."""


def distort(xy: np.ndarray, k) -> np.ndarray:
    """Normalised pinhole points (..., 2) -> normalised distorted points."""
    k1, k2, p1, p2, k3 = (float(c) for c in k)
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    s = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * s + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * s + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([xd, yd], axis=-1)


def jacobian_det(xy: np.ndarray, k, h: float = 1e-6) -> np.ndarray:
    """det of d(distort)/d(xy) at each point (central differences): the local area scale, and
    where it is <= 0 the distortion folds."""
    dx = (distort(xy + [h, 0.0], k) - distort(xy - [h, 0.0], k)) / (2 * h)
    dy = (distort(xy + [0.0, h], k) - distort(xy - [0.0, h], k)) / (2 * h)
    return dx[..., 0] * dy[..., 1] - dx[..., 1] * dy[..., 0]


def undistort(xy_d: np.ndarray, k) -> tuple[np.ndarray, np.ndarray]:
    """Normalised distorted points -> pinhole points (Newton's method on the 2x2 system, from the
    distorted point itself) and each point's residual (normalised units)."""
    xy = np.array(xy_d, dtype=np.float64, copy=True)
    h = 1e-7
    for _ in range(MAX_ITERATIONS):
        f = distort(xy, k) - xy_d
        jx = (distort(xy + [h, 0.0], k) - distort(xy - [h, 0.0], k)) / (2 * h)
        jy = (distort(xy + [0.0, h], k) - distort(xy - [0.0, h], k)) / (2 * h)
        det = jx[..., 0] * jy[..., 1] - jy[..., 0] * jx[..., 1]
        det = np.where(np.abs(det) < 1e-12, 1e-12, det)
        step_x = (jy[..., 1] * f[..., 0] - jy[..., 0] * f[..., 1]) / det
        step_y = (-jx[..., 1] * f[..., 0] + jx[..., 0] * f[..., 1]) / det
        xy[..., 0] -= step_x
        xy[..., 1] -= step_y
        if np.nanmax(np.abs(f)) < 1e-12:
            break
    return xy, np.linalg.norm(distort(xy, k) - xy_d, axis=-1)


@dataclass(frozen=True)
class Warp:
    """Where each pixel of the distorted image looks in the pinhole render window.

    The pinhole render has intrinsics ``K`` with the principal point moved by (-x0, -y0) and size
    ``width`` x ``height``; ``map_u``/``map_v`` (H x W of the distorted image) are coordinates in it.
    ``rays`` are the distorted pixels' undistorted normalised coordinates (H x W x 2).
    """

    x0: int
    y0: int
    width: int
    height: int
    map_u: np.ndarray
    map_v: np.ndarray
    rays: np.ndarray


def _normalised(K: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]], axis=-1)


def warp_for(K, width: int, height: int, k) -> Warp:
    """The pinhole window and lookup maps of a ``width`` x ``height`` image with distortion ``k``;
    LensError when ``k`` folds the image or cannot be inverted over it."""
    check(K, width, height, k)
    K = np.asarray(K, np.float64)
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    rays, _ = undistort(_normalised(K, u, v), k)
    mu = rays[..., 0] * K[0, 0] + K[0, 2]
    mv = rays[..., 1] * K[1, 1] + K[1, 2]
    x0, y0 = int(math.floor(mu.min())) - 1, int(math.floor(mv.min())) - 1
    x1, y1 = int(math.ceil(mu.max())) + 2, int(math.ceil(mv.max())) + 2
    return Warp(x0, y0, x1 - x0, y1 - y0, mu - x0, mv - y0, rays)


def check(K, width: int, height: int, k, max_window: float = 4.0) -> None:
    """Refuse coefficients that fold the image (the map from pinhole to distorted points turns
    over somewhere in view), that cannot be inverted at some pixel, or that would need a pinhole
    render more than ``max_window`` times the image's size on a side."""
    K = np.asarray(K, np.float64)
    if len(k) != 5 or not all(math.isfinite(float(c)) for c in k):
        raise LensError("distortion needs five finite coefficients [k1, k2, p1, p2, k3]")
    step = max(1, min(width, height) // 64)
    v, u = np.mgrid[0:height + step:step, 0:width + step:step].astype(np.float64)
    u, v = np.minimum(u, width - 1), np.minimum(v, height - 1)
    xy_d = _normalised(K, u, v)
    xy, residual = undistort(xy_d, k)
    worst = float(np.nanmax(residual * max(K[0, 0], K[1, 1]))) if np.isfinite(residual).all() else math.inf
    if not worst < TOLERANCE_PX:
        raise LensError(f"the distortion cannot be inverted over the image (residual {worst:.3g} px): it folds the "
                        "image or is too strong")
    # Every point between the centre and each seen point must distort monotonically (no fold on the way).
    t = np.linspace(0.0, 1.0, 33)[:, None, None, None]
    if float(jacobian_det(t * xy[None], k).min()) <= 0.0:
        raise LensError("the distortion folds the image (its Jacobian turns negative inside the field of view)")
    mu, mv = xy[..., 0] * K[0, 0] + K[0, 2], xy[..., 1] * K[1, 1] + K[1, 2]
    if np.ptp(mu) > max_window * width or np.ptp(mv) > max_window * height:
        raise LensError(f"the distortion spreads the image's rays over more than {max_window:g}x its size")
    if np.ptp(mu) * max_window < width or np.ptp(mv) * max_window < height:
        raise LensError(f"the distortion squeezes the image's rays into less than 1/{max_window:g} of its size "
                        "(every pixel would see the few pixels at the centre)")


def remap_bilinear(img: np.ndarray, warp: Warp) -> np.ndarray:
    """Colour: each distorted pixel interpolated from the pinhole render (float output)."""
    a = np.asarray(img, np.float64)
    u, v = warp.map_u, warp.map_v
    u0 = np.clip(np.floor(u).astype(np.int64), 0, a.shape[1] - 2)
    v0 = np.clip(np.floor(v).astype(np.int64), 0, a.shape[0] - 2)
    fu, fv = np.clip(u - u0, 0.0, 1.0), np.clip(v - v0, 0.0, 1.0)
    if a.ndim == 3:
        fu, fv = fu[..., None], fv[..., None]
    top = a[v0, u0] * (1 - fu) + a[v0, u0 + 1] * fu
    bottom = a[v0 + 1, u0] * (1 - fu) + a[v0 + 1, u0 + 1] * fu
    return top * (1 - fv) + bottom * fv


def remap_nearest(img: np.ndarray, warp: Warp) -> np.ndarray:
    """Labels, masks and depth: each distorted pixel takes the nearest render pixel's value."""
    a = np.asarray(img)
    u = np.clip(np.rint(warp.map_u).astype(np.int64), 0, a.shape[1] - 1)
    v = np.clip(np.rint(warp.map_v).astype(np.int64), 0, a.shape[0] - 1)
    return a[v, u]


def distorted_pixels(K, uv: np.ndarray, k) -> np.ndarray:
    """Pinhole pixel coordinates (..., 2) -> where the distorted image shows them."""
    K = np.asarray(K, np.float64)
    d = distort(_normalised(K, uv[..., 0], uv[..., 1]), k)
    return np.stack([d[..., 0] * K[0, 0] + K[0, 2], d[..., 1] * K[1, 1] + K[1, 2]], axis=-1)


def monotonic_radius(k, r_view: float, directions: int = 16, samples: int = 400) -> float:
    """The largest normalised radius (at least ``r_view``, at most 3x it) up to which the
    distortion keeps a positive Jacobian in every direction: beyond the field of view the lens
    model is an extrapolation, and where it turns over it says nothing."""
    a = np.linspace(0.0, 2 * np.pi, directions, endpoint=False)
    r = np.linspace(0.0, 3.0 * r_view, samples)
    pts = r[:, None, None] * np.stack([np.cos(a), np.sin(a)], axis=-1)[None]
    bad = (jacobian_det(pts, k) <= 0).any(axis=1)
    if not bad.any():
        return float(r[-1])
    return float(max(r_view, r[max(int(np.argmax(bad)) - 1, 0)]))


def distorted_silhouette(K, uv: np.ndarray, k, r_limit: float) -> tuple[np.ndarray, np.ndarray]:
    """Pinhole pixels (N, 2) of an object's amodal silhouette -> their distorted positions and the
    area (in distorted pixels) each pixel becomes. Points beyond ``r_limit`` (normalised) are
    pulled in to it, so an object reaching far outside the view gets a box that ends there."""
    K = np.asarray(K, np.float64)
    xy = _normalised(K, uv[..., 0], uv[..., 1])
    r = np.linalg.norm(xy, axis=-1, keepdims=True)
    xy = np.where(r > r_limit, xy * (r_limit / np.maximum(r, 1e-12)), xy)
    d = distort(xy, k)
    pix = np.stack([d[..., 0] * K[0, 0] + K[0, 2], d[..., 1] * K[1, 1] + K[1, 2]], axis=-1)
    return pix, np.maximum(jacobian_det(xy, k), 0.0)


def render_camera(camera, warp: Warp):
    """The pinhole camera a backend renders for a distorted ``camera``: its window of ``warp``."""
    K = np.asarray(camera.K, np.float64).copy()
    K[0, 2] -= warp.x0
    K[1, 2] -= warp.y0
    return replace(camera, K=tuple(tuple(float(c) for c in row) for row in K), width=warp.width, height=warp.height)


def sample_nearest(img: np.ndarray, u: np.ndarray, v: np.ndarray, fill=0):
    """img at the nearest pixels of (u, v), ``fill`` outside it."""
    iu, iv = np.rint(u).astype(np.int64), np.rint(v).astype(np.int64)
    inside = (iu >= 0) & (iv >= 0) & (iu < img.shape[1]) & (iv < img.shape[0])
    out = np.full(u.shape + img.shape[2:], fill, dtype=img.dtype)
    out[inside] = img[iv[inside], iu[inside]]
    return out
