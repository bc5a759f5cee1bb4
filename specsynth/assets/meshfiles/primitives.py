"""Primitive meshes (boxes, planes, cylinders) for scenes and built-in objects, with UVs in metres, and small geometry helpers.

UVs are in metres of surface (1 UV unit = 1 m) so a texture tiles at the same physical scale on
every face and every primitive; a material's ``uv_scale`` then sets repeats per metre.
Pure numpy: no trimesh, so scene loading stays fast and these shapes hash identically everywhere.
"""

from __future__ import annotations

import math

import numpy as np

from ..meshio import MeshData


def _quad_faces(n_quads: int) -> np.ndarray:
    base = np.arange(n_quads)[:, None] * 4
    return np.concatenate([base + [0, 1, 2], base + [0, 2, 3]]).astype(np.int32)


def box(size) -> MeshData:
    """Axis-aligned box centred at the origin; 4 vertices per face so normals stay flat."""
    sx, sy, sz = (float(s) / 2 for s in size)
    verts, norms, uvs = [], [], []
    for ax, sign in ((0, 1), (0, -1), (1, 1), (1, -1), (2, 1), (2, -1)):
        n = np.zeros(3)
        n[ax] = sign
        u_ax, v_ax = [a for a in range(3) if a != ax]
        half = np.array([sx, sy, sz])
        corners = []
        for cu, cv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
            p = np.zeros(3)
            p[ax] = sign * half[ax]
            p[u_ax] = cu * half[u_ax]
            p[v_ax] = cv * half[v_ax]
            corners.append(p)
            uvs.append((p[u_ax] + half[u_ax], p[v_ax] + half[v_ax]))
        verts += corners
        norms += [n] * 4
    mesh = MeshData(
        vertices=np.asarray(verts, np.float32),
        faces=_quad_faces(6),
        normals=np.asarray(norms, np.float32),
        uv=np.asarray(uvs, np.float32),
    )
    return _fix_winding(mesh)  # one rule for all six faces instead of per-face orderings


def plane(size) -> MeshData:
    """Horizontal rectangle at z=0 facing +Z, centred at the origin."""
    sx, sy = float(size[0]) / 2, float(size[1]) / 2
    v = np.array([[-sx, -sy, 0], [sx, -sy, 0], [sx, sy, 0], [-sx, sy, 0]], np.float32)
    return MeshData(
        vertices=v,
        faces=_quad_faces(1),
        normals=np.tile(np.float32([0, 0, 1]), (4, 1)),
        uv=(v[:, :2] + [sx, sy]).astype(np.float32),
    )


def cylinder(radius: float, height: float, segments: int = 48) -> MeshData:
    """Upright cylinder centred at the origin (z in [-h/2, h/2]) with side and cap UVs in metres."""
    r, h = float(radius), float(height)
    a = np.linspace(0.0, 2 * math.pi, segments + 1)  # seam vertex duplicated so UVs don't wrap
    ca, sa = np.cos(a), np.sin(a)
    side_v = np.concatenate([np.stack([r * ca, r * sa, np.full_like(a, -h / 2)], 1),
                             np.stack([r * ca, r * sa, np.full_like(a, h / 2)], 1)])
    side_n = np.concatenate([np.stack([ca, sa, np.zeros_like(a)], 1)] * 2)
    side_uv = np.concatenate([np.stack([a * r, np.zeros_like(a)], 1), np.stack([a * r, np.full_like(a, h)], 1)])
    n1 = segments + 1
    i = np.arange(segments)
    side_f = np.concatenate([np.stack([i, i + 1, i + 1 + n1], 1), np.stack([i, i + 1 + n1, i + n1], 1)])
    parts_v, parts_n, parts_uv, parts_f = [side_v], [side_n], [side_uv], [side_f]
    offset = len(side_v)
    for sign in (1, -1):
        ring = np.stack([r * ca[:-1], r * sa[:-1], np.full(segments, sign * h / 2)], 1)
        centre = np.array([[0, 0, sign * h / 2]])
        v = np.concatenate([centre, ring])
        parts_v.append(v)
        parts_n.append(np.tile([0, 0, sign], (len(v), 1)))
        parts_uv.append(v[:, :2] + r)
        j = np.arange(segments)
        f = np.stack([np.zeros(segments, int), 1 + j, 1 + (j + 1) % segments], 1)
        if sign < 0:
            f = f[:, [0, 2, 1]]
        parts_f.append(f + offset)
        offset += len(v)
    return MeshData(
        vertices=np.concatenate(parts_v).astype(np.float32),
        faces=np.concatenate(parts_f).astype(np.int32),
        normals=np.concatenate(parts_n).astype(np.float32),
        uv=np.concatenate(parts_uv).astype(np.float32),
    )


def catmull_rom(points: np.ndarray, per_segment: int) -> np.ndarray:
    """A centripetal-free (uniform) Catmull-Rom curve through ``points``, ``per_segment`` samples
    between each pair, the end points included."""
    p = np.asarray(points, np.float64)
    if len(p) < 3:
        t = np.linspace(0.0, 1.0, per_segment * (len(p) - 1) + 1)[:, None]
        return p[0] * (1 - t) + p[-1] * t
    ext = np.concatenate([2 * p[:1] - p[1:2], p, 2 * p[-1:] - p[-2:-1]])
    out = []
    t = np.linspace(0.0, 1.0, per_segment, endpoint=False)[:, None]
    for k in range(len(p) - 1):
        p0, p1, p2, p3 = ext[k], ext[k + 1], ext[k + 2], ext[k + 3]
        out.append(0.5 * (2 * p1 + (p2 - p0) * t + (2 * p0 - 5 * p1 + 4 * p2 - p3) * t ** 2
                          + (3 * p1 - p0 - 3 * p2 + p3) * t ** 3))
    out.append(p[-1:])
    return np.concatenate(out)


def tube(points, radius: float, sides: int = 10, per_segment: int = 8) -> MeshData:
    """A tube of ``radius`` swept along a smooth curve through ``points`` (a cable, a hose), capped
    at both ends; UVs in metres (u along the tube, v around it). Frames are carried along the curve
    by parallel transport, so the tube never twists."""
    c = catmull_rom(points, per_segment)
    keep = np.concatenate([[True], np.linalg.norm(np.diff(c, axis=0), axis=1) > 1e-9])
    c = c[keep]
    if len(c) < 2:
        raise ValueError("a tube needs two distinct points")
    tangents = np.gradient(c, axis=0)
    tangents /= np.linalg.norm(tangents, axis=1, keepdims=True)
    a = np.array([0.0, 0.0, 1.0]) if abs(tangents[0, 2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    n = np.cross(tangents[0], a)
    n /= np.linalg.norm(n)
    normals = []
    for t in tangents:
        n = n - t * (n @ t)
        n /= np.linalg.norm(n)
        normals.append(n)
    normals = np.asarray(normals)
    binormals = np.cross(tangents, normals)
    ang = np.linspace(0.0, 2 * math.pi, sides + 1)  # the seam duplicated for UVs
    ring = np.cos(ang)[None, :, None] * normals[:, None] + np.sin(ang)[None, :, None] * binormals[:, None]
    verts = (c[:, None] + radius * ring).reshape(-1, 3)
    norms = ring.reshape(-1, 3)
    length = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(c, axis=0), axis=1))])
    uv = np.stack(np.broadcast_arrays(length[:, None], (ang * radius)[None, :]), -1).reshape(-1, 2)
    m, s1 = len(c), sides + 1
    i, j = np.meshgrid(np.arange(m - 1), np.arange(sides), indexing="ij")
    a0, a1 = i * s1 + j, i * s1 + j + 1
    b0, b1 = a0 + s1, a1 + s1
    faces = np.concatenate([np.stack([a0, b0, b1], -1).reshape(-1, 3), np.stack([a0, b1, a1], -1).reshape(-1, 3)])
    parts_v, parts_n, parts_uv, parts_f = [verts], [norms], [uv], [faces]
    offset = len(verts)
    for end, sign in ((0, -1.0), (m - 1, 1.0)):  # caps
        cap = np.concatenate([c[end][None], c[end] + radius * ring[end, :-1]])
        parts_v.append(cap)
        parts_n.append(np.tile(sign * tangents[end], (len(cap), 1)))
        parts_uv.append(np.zeros((len(cap), 2)))
        k = np.arange(sides)
        f = np.stack([np.zeros(sides, int), 1 + k, 1 + (k + 1) % sides], 1)
        parts_f.append(f + offset)
        offset += len(cap)
    mesh = MeshData(vertices=np.concatenate(parts_v).astype(np.float32), faces=np.concatenate(parts_f).astype(np.int32),
                    normals=np.concatenate(parts_n).astype(np.float32), uv=np.concatenate(parts_uv).astype(np.float32))
    return _fix_winding(mesh)


def with_box_uvs(mesh: MeshData) -> MeshData:
    """``mesh`` with UVs by box projection in metres (as the primitives have), when it has none:
    each face is projected along the axis its normal is closest to, as Blender's generated
    coordinates let a texture show on a model without UVs; a vertex shared by faces projected
    along different axes is split."""
    if mesh.uv is not None or len(mesh.faces) == 0:
        return mesh
    v, f = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces)
    axis = np.argmax(np.abs(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])), axis=1)
    corners, faces = np.unique((f * 3 + axis[:, None]).ravel(), return_inverse=True)
    src, ax = corners // 3, corners % 3
    uv = np.take_along_axis(v[src], np.array([[1, 2], [0, 2], [0, 1]])[ax], axis=1)

    def take(a):
        return None if a is None else np.asarray(a)[src]

    return MeshData(vertices=take(mesh.vertices), faces=faces.reshape(-1, 3).astype(np.int32), normals=take(mesh.normals),
                    uv=uv.astype(np.float32), colors=take(mesh.colors))


def _fix_winding(mesh: MeshData) -> MeshData:
    """Flip any triangle whose geometric normal disagrees with its vertex normals (outward)."""
    v, f = mesh.vertices, mesh.faces.copy()
    n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    flip = (n * mesh.normals[f[:, 0]]).sum(1) < 0
    f[flip] = f[flip][:, [0, 2, 1]]
    return MeshData(vertices=v, faces=f, normals=mesh.normals, uv=mesh.uv, colors=mesh.colors)


def transform_mesh(mesh: MeshData, matrix: np.ndarray) -> MeshData:
    """Apply an affine 4x4 (may scale non-uniformly: normals use the inverse transpose)."""
    A = np.asarray(matrix, dtype=np.float64)
    v = mesh.vertices.astype(np.float64) @ A[:3, :3].T + A[:3, 3]
    normals = None
    if mesh.normals is not None:
        N = np.linalg.inv(A[:3, :3]).T
        normals = mesh.normals.astype(np.float64) @ N.T
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
        normals = normals.astype(np.float32)
    faces = mesh.faces
    if np.linalg.det(A[:3, :3]) < 0:  # a mirror turns the mesh inside out otherwise
        faces = faces[:, [0, 2, 1]]
    return MeshData(vertices=v.astype(np.float32), faces=faces, normals=normals, uv=mesh.uv, colors=mesh.colors)


def concatenate(meshes: list[MeshData]) -> MeshData:
    """Join meshes; optional attributes survive only if every part has them."""
    faces, off = [], 0
    for m in meshes:
        faces.append(m.faces + off)
        off += len(m.vertices)

    def cat(attr):
        arrs = [getattr(m, attr) for m in meshes]
        return None if any(a is None for a in arrs) else np.concatenate(arrs)

    return MeshData(
        vertices=np.concatenate([m.vertices for m in meshes]).astype(np.float32),
        faces=np.concatenate(faces).astype(np.int32),
        normals=cat("normals"),
        uv=cat("uv"),
        colors=cat("colors"),
    )


def ray_down(vertices: np.ndarray, faces: np.ndarray, xy, z_from: float) -> np.ndarray:
    """Height of the first surface hit by a vertical ray cast down from ``z_from`` at each xy.

    NaN where nothing is hit. Plain numpy (trimesh's ray module needs rtree/embree, which we don't
    depend on); fine for the handful of rays stage checks need.
    """
    T = np.asarray(vertices, np.float64)[np.asarray(faces)]
    lo, hi = T[:, :, :2].min(1), T[:, :, :2].max(1)
    xy = np.atleast_2d(np.asarray(xy, np.float64))
    out = np.full(len(xy), np.nan)
    for k, (x, y) in enumerate(xy):
        t = T[(lo[:, 0] <= x) & (hi[:, 0] >= x) & (lo[:, 1] <= y) & (hi[:, 1] >= y)]
        if not len(t):
            continue
        a, b, c = t[:, 0], t[:, 1], t[:, 2]
        d = (b[:, 1] - c[:, 1]) * (a[:, 0] - c[:, 0]) + (c[:, 0] - b[:, 0]) * (a[:, 1] - c[:, 1])
        with np.errstate(divide="ignore", invalid="ignore"):
            l1 = ((b[:, 1] - c[:, 1]) * (x - c[:, 0]) + (c[:, 0] - b[:, 0]) * (y - c[:, 1])) / d
            l2 = ((c[:, 1] - a[:, 1]) * (x - c[:, 0]) + (a[:, 0] - c[:, 0]) * (y - c[:, 1])) / d
            l3 = 1 - l1 - l2
            ok = (np.abs(d) > 1e-18) & (l1 >= -1e-9) & (l2 >= -1e-9) & (l3 >= -1e-9)
            z = l1 * a[:, 2] + l2 * b[:, 2] + l3 * c[:, 2]
            ok &= z <= z_from
        if ok.any():
            out[k] = z[ok].max()
    return out
