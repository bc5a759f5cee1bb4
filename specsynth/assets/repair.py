"""Repairs of mesh geometry that renderers cannot draw right (pure numpy).

Faces that overlap in one plane are a modelling slip in library furniture: a Sweet Home 3D desk's
top is one large triangle with a fan of smaller ones lying on it, some facing up, some down, over
two long wedges. A ray tracer's shadow ray leaving one of them hits the other at once: Cycles drew
the wedges black, Mitsuba as faint lines. A surface needs to be there once (every backend draws
both sides of a face), so in every plane the faces are kept largest first, each unless it overlaps
one already kept; a proper triangulation (faces meeting at their edges) is left as it is.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .meshio import MeshData

PLANE_ANGLE = 1e-3  # unit-normal components, rounded: faces within ~0.06 degrees share a plane
PLANE_OFFSET = 1e-4  # metres: faces within 0.1 mm of one plane share it
OVERLAP = 1e-4  # metres: faces must overlap by more than this (touching edges do not count)
MAX_PLANE_FACES = 4000  # larger planar tessellations (terrain, scans) are not searched: O(n^2) worst case


def _planes(v: np.ndarray, f: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per face: its plane's unit normal (of either orientation, made canonical), the plane's
    rounded key (normal, offset), and twice the face's area."""
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    area2 = np.linalg.norm(n, axis=1)
    unit = n / np.where(area2 > 0, area2, 1.0)[:, None]
    first = np.argmax(np.abs(unit) > 0.5773, axis=1)  # a component of at least 1/sqrt(3) exists
    sign = np.where(unit[np.arange(len(f)), first] < 0, -1.0, 1.0)
    canon = unit * sign[:, None]
    offset = np.einsum("fj,fj->f", canon, v[f[:, 0]])
    key = np.column_stack([np.round(canon / PLANE_ANGLE), np.round(offset / PLANE_OFFSET)]).astype(np.int64)
    return canon, key, area2


def _in_plane(points: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """(..., 3, 3) triangle corners -> (..., 3, 2) coordinates in a basis of the plane."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(normal, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    return np.stack([points @ e1, points @ e2], axis=-1)


def triangles_overlap(a: np.ndarray, b: np.ndarray, margin: float = OVERLAP) -> np.ndarray:
    """Whether 2D triangles ``a[i]`` and ``b[i]`` ((N, 3, 2) each) overlap by more than ``margin``
    along every separating-axis candidate (their six edge normals)."""
    out = np.ones(len(a), bool)
    for tri in (a, b):
        for k in range(3):
            edge = tri[:, (k + 1) % 3] - tri[:, k]
            axis = np.stack([-edge[:, 1], edge[:, 0]], axis=1)
            axis /= np.maximum(np.linalg.norm(axis, axis=1, keepdims=True), 1e-30)
            pa, pb = np.einsum("nkj,nj->nk", a, axis), np.einsum("nkj,nj->nk", b, axis)
            depth = np.minimum(pa.max(1), pb.max(1)) - np.maximum(pa.min(1), pb.min(1))
            out &= depth > margin
    return out


def _first_cover(tri: np.ndarray, area2: np.ndarray) -> np.ndarray:
    """Of coplanar 2D triangles ``tri`` ((N, 3, 2)), which to keep: largest first, each unless it
    overlaps one already kept."""
    order = np.argsort(-area2, kind="stable")
    kept = np.zeros(len(tri), bool)
    lo, hi = tri.min(axis=1), tri.max(axis=1)
    for i in order:
        k = np.flatnonzero(kept)
        near = k[((lo[k] < hi[i] - OVERLAP) & (hi[k] > lo[i] + OVERLAP)).all(axis=1)]
        if len(near) == 0 or not triangles_overlap(np.repeat(tri[i : i + 1], len(near), axis=0), tri[near]).any():
            kept[i] = True
    return kept


def drop_overlapping(mesh: MeshData) -> MeshData:
    """``mesh`` without the faces that overlap a larger face of their plane (see the module's
    docstring); unchanged when it has none."""
    v, f = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces)
    if len(f) == 0:
        return mesh
    canon, key, area2 = _planes(v, f)
    _, group = np.unique(key, axis=0, return_inverse=True)
    group = np.where(area2 > 0, group.ravel(), -1)
    sizes = np.bincount(group[group >= 0]) if (group >= 0).any() else np.zeros(0, int)
    drop = np.zeros(len(f), bool)
    for g in np.flatnonzero((sizes > 1) & (sizes <= MAX_PLANE_FACES)):
        members = np.flatnonzero(group == g)
        tri = _in_plane(v[f[members]], canon[members[0]])
        quick = tri.min(axis=1), tri.max(axis=1)
        if not _any_bbox_overlap(*quick):
            continue
        drop[members[~_first_cover(tri, area2[members])]] = True
    if not drop.any():
        return mesh
    return replace(mesh, faces=f[~drop].astype(mesh.faces.dtype))


def _any_bbox_overlap(lo: np.ndarray, hi: np.ndarray) -> bool:
    """Whether any two of the 2D boxes overlap by more than OVERLAP (a cheap first test)."""
    order = np.argsort(lo[:, 0])
    lo, hi = lo[order], hi[order]
    for i in range(len(lo) - 1):
        j = i + 1 + np.flatnonzero(lo[i + 1 :, 0] < hi[i, 0] - OVERLAP)
        if len(j) and ((lo[j, 1] < hi[i, 1] - OVERLAP) & (hi[j, 1] > lo[i, 1] + OVERLAP)).any():
            return True
    return False
