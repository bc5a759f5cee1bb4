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
SMALL_PLANE = 48  # planes of up to this many faces are tested all pairs at once


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


def _overlapping_pairs(tri: np.ndarray, batch: int = 200_000) -> tuple[np.ndarray, np.ndarray]:
    """(i, j) of the coplanar 2D triangles ``tri`` ((N, 3, 2)) that overlap: candidates are the
    pairs whose boxes overlap (a sweep over boxes sorted by x, built without a Python loop), then
    the separating-axis test."""
    lo, hi = tri.min(axis=1), tri.max(axis=1)
    order = np.argsort(lo[:, 0], kind="stable")
    lo_x = lo[order, 0]
    end = np.searchsorted(lo_x, hi[order, 0] - OVERLAP, side="left")  # boxes starting before mine ends
    counts = np.maximum(end - np.arange(len(order)) - 1, 0)
    a = np.repeat(np.arange(len(order)), counts)
    b = a + 1 + np.arange(len(a)) - np.repeat(np.cumsum(counts) - counts, counts)
    i, j = order[a], order[b]
    near = (lo[j, 1] < hi[i, 1] - OVERLAP) & (hi[j, 1] > lo[i, 1] + OVERLAP) & (hi[j, 0] > lo[i, 0] + OVERLAP)
    i, j = i[near], j[near]
    hit = np.zeros(len(i), bool)
    for s in range(0, len(i), batch):
        hit[s : s + batch] = triangles_overlap(tri[i[s : s + batch]], tri[j[s : s + batch]])
    return i[hit], j[hit]


def _first_cover(pairs: tuple[np.ndarray, np.ndarray], area2: np.ndarray) -> np.ndarray:
    """Which faces to drop, given the overlapping ``pairs`` (i, j) of coplanar faces: largest first
    (ties by index), each kept unless it overlaps one already kept. Pairs only join faces of one
    plane, so one pass over all planes' faces gives each plane's own answer."""
    partners: dict[int, list[int]] = {}
    for i, j in zip(*(x.tolist() for x in pairs)):
        partners.setdefault(i, []).append(j)
        partners.setdefault(j, []).append(i)
    involved = np.array(sorted(partners), np.int64)
    kept: dict[int, bool] = {}
    for i in involved[np.argsort(-area2[involved], kind="stable")].tolist():
        kept[i] = not any(kept.get(j, False) for j in partners[i])
    drop = np.zeros(len(area2), bool)
    drop[[i for i, k in kept.items() if not k]] = True
    return drop


def drop_overlapping(mesh: MeshData) -> MeshData:
    """``mesh`` without the faces that overlap a larger face of their plane (see the module's
    docstring); unchanged when it has none."""
    v, f = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces)
    if len(f) == 0:
        return mesh
    canon, key, area2 = _planes(v, f)
    _, group = np.unique(key, axis=0, return_inverse=True)
    group = np.where(area2 > 0, group.ravel(), -1)
    order = np.argsort(group, kind="stable")
    ids, starts, sizes = np.unique(group[order], return_index=True, return_counts=True)
    keep = (ids >= 0) & (sizes > 1) & (sizes <= MAX_PLANE_FACES)
    ids, starts, sizes = ids[keep], starts[keep], sizes[keep]
    rep = np.zeros(group.max() + 2, np.int64)
    rep[ids] = order[starts]  # each plane's basis from its first face's normal
    tri = _in_plane_each(v[f], canon[rep[np.maximum(group, 0)]])
    small = sizes <= SMALL_PLANE
    pairs = [_small_plane_pairs(tri, order, starts[small], sizes[small])]
    for g_start, size in zip(starts[~small], sizes[~small]):
        members = order[g_start : g_start + size]
        i, j = _overlapping_pairs(tri[members])
        pairs.append((members[i], members[j]))
    i, j = (np.concatenate([p[k] for p in pairs]) for k in (0, 1))
    if len(i) == 0:
        return mesh
    return replace(mesh, faces=f[~_first_cover((i, j), area2)].astype(mesh.faces.dtype))


def _in_plane_each(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """(F, 3, 3) triangles and (F, 3) plane normals -> (F, 3, 2) coordinates in each plane's own
    orthonormal basis."""
    helper = np.where((np.abs(normals[:, 0]) < 0.9)[:, None], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    e1 = np.cross(normals, helper)
    e1 /= np.maximum(np.linalg.norm(e1, axis=1, keepdims=True), 1e-30)
    e2 = np.cross(normals, e1)
    return np.stack([np.einsum("fkj,fj->fk", points, e1), np.einsum("fkj,fj->fk", points, e2)], axis=-1)


def _small_plane_pairs(tri: np.ndarray, order: np.ndarray, starts: np.ndarray, sizes: np.ndarray,
                       batch: int = 200_000) -> tuple[np.ndarray, np.ndarray]:
    """The overlapping pairs (i, j) of faces within the small planes (``starts``/``sizes`` into
    ``order``): every pair of every plane tested at once, grouped by plane size."""
    out_i, out_j = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
    for size in np.unique(sizes):
        members = order[starts[sizes == size][:, None] + np.arange(size)]  # (planes, size) face indices
        a, b = np.triu_indices(size, 1)
        i, j = members[:, a].ravel(), members[:, b].ravel()
        hit = np.zeros(len(i), bool)
        for s in range(0, len(i), batch):
            hit[s : s + batch] = triangles_overlap(tri[i[s : s + batch]], tri[j[s : s + batch]])
        out_i.append(i[hit])
        out_j.append(j[hit])
    return np.concatenate(out_i), np.concatenate(out_j)
