"""Per-pixel geometry maps from the annotation engine's depth: camera-space normals and NOCS.

Pure numpy, no renderer: every backend gets the same maps, exact to the depth pass's float32
precision. Conventions: OpenCV camera (x right, y down, z forward), pixel centres at integer
coordinates, metres. NOCS (Wang et al., CVPR 2019): a pixel of an object holds its model-frame
point scaled by the model's bounding-box diagonal and shifted into the unit cube,
``p / diagonal + 0.5`` (the BOP model origin is the box centre, so values lie in [0, 1]).
"""

from __future__ import annotations

import numpy as np


def backproject(depth: np.ndarray, K: np.ndarray, rays: np.ndarray | None = None) -> np.ndarray:
    """HxWx3 camera-frame points of a z-depth map (metres); 0 where the depth is 0. ``rays``
    (HxWx2 normalised x/z, y/z per pixel) replace K for an image seen through lens distortion."""
    if rays is not None:
        z = depth.astype(np.float64)
        return np.stack([rays[..., 0] * z, rays[..., 1] * z, z], axis=-1)
    h, w = depth.shape
    K = np.asarray(K, dtype=np.float64)
    u = np.arange(w, dtype=np.float64)[None, :]
    v = np.arange(h, dtype=np.float64)[:, None]
    z = depth.astype(np.float64)
    x = (u - K[0, 2] - K[0, 1] * (v - K[1, 2]) / K[1, 1]) / K[0, 0] * z
    y = (v - K[1, 2]) / K[1, 1] * z
    return np.stack([x, y, z], axis=-1)


def normals_from_depth(depth: np.ndarray, K: np.ndarray, rays: np.ndarray | None = None) -> np.ndarray:
    """HxWx3 unit surface normals in the camera frame, facing the camera; 0 where no depth.

    Tangents are differences to the neighbour whose depth is closer (left or right, up or down),
    so a pixel on an object's edge takes its slope from its own surface, not across the jump."""
    p = backproject(depth, K, rays)
    valid = depth > 0

    def tangent(axis: int) -> np.ndarray:
        fwd = np.roll(p, -1, axis=axis) - p
        bwd = p - np.roll(p, 1, axis=axis)
        dz_f, dz_b = np.abs(fwd[..., 2]), np.abs(bwd[..., 2])
        n = p.shape[axis]
        idx = np.arange(n)
        at_end = (idx == n - 1) if axis == 1 else (idx == n - 1)[:, None]
        at_start = (idx == 0) if axis == 1 else (idx == 0)[:, None]
        ok_f = ~at_end & np.roll(valid, -1, axis=axis)
        ok_b = ~at_start & np.roll(valid, 1, axis=axis)
        use_f = ok_f & (~ok_b | (dz_f <= dz_b))
        return np.where(use_f[..., None], fwd, np.where(ok_b[..., None], bwd, 0.0))

    n = np.cross(tangent(0), tangent(1))  # d/dv x d/du: toward the camera for a visible surface
    length = np.linalg.norm(n, axis=-1, keepdims=True)
    n = np.where(length > 0, n / np.where(length > 0, length, 1.0), 0.0)
    flip = np.sum(n * p, axis=-1, keepdims=True) > 0  # facing away from the camera: turn it round
    n = np.where(flip, -n, n)
    return np.where(valid[..., None], n, 0.0).astype(np.float32)


def nocs_map(depth: np.ndarray, K: np.ndarray, masks_visib: list[np.ndarray], poses: list[tuple],
             diagonals: list[float], rays: np.ndarray | None = None) -> np.ndarray:
    """HxWx3 NOCS of the visible pixels of each instance (0 elsewhere); ``poses`` are
    (R_m2c, t_m2c) in metres, ``diagonals`` the models' bounding-box diagonals in metres."""
    p = backproject(depth, K, rays)
    out = np.zeros(depth.shape + (3,), dtype=np.float32)
    for mask, (R, t), diag in zip(masks_visib, poses, diagonals):
        sel = mask & (depth > 0)
        if not sel.any():
            continue
        R = np.asarray(R, dtype=np.float64)
        # R^T (p - t) as row vectors; einsum, not BLAS, so the bytes depend on the inputs only.
        model = np.einsum("ni,ij->nj", p[sel] - np.asarray(t, dtype=np.float64), R)
        out[sel] = np.clip(model / diag + 0.5, 0.0, 1.0)
    return out
