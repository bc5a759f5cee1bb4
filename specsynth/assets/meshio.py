"""The normalised mesh form every backend and the annotation engine read: binary PLY in metres.

Properties: x y z (float32, metres), nx ny nz (float32), u v (float32, optional),
red green blue alpha (uint8, optional); faces as triangle lists. Written by our own small writer so
the layout is exact and stable (its bytes feed content hashes), read back with numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..atomic import atomic_write_bytes


class MeshFormatError(ValueError):
    pass


# A face whose vertex normal is more than ~75 degrees off its own normal is drawn flat: smooth
# shading across a real crease stays well inside (a cube corner's shared normal is 55 degrees off).
DISAGREE = 0.25
# A texture coordinate beyond this many repeats of its image is broken, not tiling: of the 12,012
# meshes the library's rooms had normalised, all but one stay within 100, and that one (a Sweet
# Home 3D table) has four corners at u = 3.4e9, which made Mitsuba trace 1e14-bright fireflies.
UV_LIMIT = 1e4


@dataclass(frozen=True, eq=False)
class MeshData:
    vertices: np.ndarray  # (N, 3) float32, metres
    faces: np.ndarray  # (M, 3) int32
    normals: np.ndarray | None = None  # (N, 3) float32, unit
    uv: np.ndarray | None = None  # (N, 2) float32, OpenGL convention (v up)
    colors: np.ndarray | None = None  # (N, 4) uint8, sRGB-encoded vertex colours

    def validate(self, what: str) -> "MeshData":
        v, f = self.vertices, self.faces
        if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
            raise MeshFormatError(f"{what}: mesh has no vertices")
        if f.ndim != 2 or f.shape[1] != 3 or len(f) == 0:
            raise MeshFormatError(f"{what}: mesh has no triangles")
        if not np.isfinite(v).all():
            raise MeshFormatError(f"{what}: mesh has NaN or infinite vertex coordinates")
        if f.min() < 0 or f.max() >= len(v):
            raise MeshFormatError(f"{what}: face indices out of range (0..{len(v) - 1})")
        for name, a, cols in (("normals", self.normals, 3), ("uv", self.uv, 2), ("colors", self.colors, 4)):
            if a is not None and a.shape != (len(v), cols):
                raise MeshFormatError(f"{what}: {name} has shape {a.shape}, expected ({len(v)}, {cols})")
        return self

    def with_usable_normals(self) -> "MeshData":
        """The mesh with faces wound the way its normals point, every zero-length or non-finite
        normal replaced by the area-weighted normal of the faces around its vertex, and every face
        whose own vertex normals disagree with it given its flat normal.

        Library models carry all three: triangles wound against their vertex normals (one Sweet
        Home 3D desk has 394 of 472 such faces in one part), a few zero normals (a laptop has 148),
        and faces whose corners point opposite ways (that desk's top has 44 long slivers with one
        corner's normal pointing down), which a renderer can only interpolate into garbage (Cycles
        drew them as black streaks). A face is turned when its winding normal points against the
        sum of its vertices' normals; valid normals on faces they agree with are kept as they are."""
        if self.normals is None:
            return self
        n = np.asarray(self.normals, np.float64)
        length = np.linalg.norm(n, axis=1)
        bad = ~np.isfinite(length) | (length < 1e-6)
        v, f = np.asarray(self.vertices, np.float64), np.asarray(self.faces)
        face_n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])  # length = 2 x area
        good_n = np.where(bad[:, None], 0.0, n)
        against = np.einsum("fj,fj->f", face_n, good_n[f].sum(axis=1)) < 0
        f = np.where(against[:, None], f[:, [0, 2, 1]], f)
        face_n = np.where(against[:, None], -face_n, face_n)
        acc = np.zeros_like(v)
        for k in range(3):
            np.add.at(acc, f[:, k], face_n)
        acc_len = np.linalg.norm(acc, axis=1, keepdims=True)
        fallback = np.where(acc_len > 0, acc / np.where(acc_len > 0, acc_len, 1.0), [0.0, 0.0, 1.0])
        fixed = np.where(bad[:, None], fallback, n / np.where(bad, 1.0, length)[:, None])
        area2 = np.linalg.norm(face_n, axis=1)
        unit = face_n / np.where(area2 > 0, area2, 1.0)[:, None]
        split = (area2 > 0) & (np.einsum("fkj,fj->fk", fixed[f], unit).min(axis=1) < DISAGREE)
        if not bad.any() and not against.any() and not split.any():
            return self
        normals = np.where(bad[:, None], fixed, n).astype(np.float32)
        if not split.any():
            return replace(self, faces=f.astype(self.faces.dtype), normals=normals)
        return _flat_faces(replace(self, faces=f.astype(self.faces.dtype), normals=normals), split, unit[split])

    def with_usable_uv(self) -> "MeshData":
        """The mesh with every texture coordinate that is not finite or lies beyond ``UV_LIMIT``
        replaced by the mean of the valid ones at the other corners of its faces, each of u and v
        on its own, and repeated outwards (a face of broken corners takes its neighbours'); 0 where
        no valid one is reached. In float32 such a coordinate has no fraction left to place a
        texel, and a renderer that derives a surface frame from the coordinates' gradients
        divides by nearly nothing."""
        if self.uv is None:
            return self
        uv = np.asarray(self.uv, np.float64)
        bad = ~(np.isfinite(uv) & (np.abs(uv) <= UV_LIMIT))
        if not bad.any():
            return self
        f = np.asarray(self.faces)
        fixed = np.where(bad, 0.0, uv)
        while bad.any():
            total, count = np.zeros_like(uv), np.zeros_like(uv)
            for k in range(3):
                for j in (1, 2):
                    np.add.at(total, f[:, k], np.where(bad, 0.0, fixed)[f[:, (k + j) % 3]])
                    np.add.at(count, f[:, k], ~bad[f[:, (k + j) % 3]])
            reached = bad & (count > 0)
            if not reached.any():
                break
            fixed = np.where(reached, total / np.maximum(count, 1), fixed)
            bad = bad & ~reached
        return replace(self, uv=fixed.astype(np.float32))

    @property
    def bounds(self) -> np.ndarray:
        return np.stack([self.vertices.min(0), self.vertices.max(0)])


def _flat_faces(mesh: MeshData, faces: np.ndarray, normals: np.ndarray) -> MeshData:
    """``mesh`` with the ``faces`` (a mask) given three vertices of their own carrying ``normals``
    (their flat normals); UVs and colours copied with their corners."""
    f = np.asarray(mesh.faces).copy()
    corners = f[faces].reshape(-1)
    start = len(mesh.vertices)
    f[faces] = (start + np.arange(len(corners))).reshape(-1, 3)

    def extended(a):
        return None if a is None else np.concatenate([a, a[corners]])

    return replace(mesh, vertices=extended(mesh.vertices), faces=f.astype(mesh.faces.dtype),
                   normals=np.concatenate([mesh.normals, np.repeat(normals, 3, axis=0).astype(np.float32)]),
                   uv=extended(mesh.uv), colors=extended(mesh.colors))


def _vertex_dtype(mesh: MeshData, uv_names: tuple[str, str] = ("u", "v"), colors_first: bool = False) -> np.dtype:
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if mesh.normals is not None:
        fields += [("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
    uv = [(uv_names[0], "<f4"), (uv_names[1], "<f4")] if mesh.uv is not None else []
    colors = [("red", "u1"), ("green", "u1"), ("blue", "u1"), ("alpha", "u1")] if mesh.colors is not None else []
    return np.dtype(fields + (colors + uv if colors_first else uv + colors))


def mesh_bytes(mesh: MeshData, comments: tuple[str, ...] = (), *, scale: float = 1.0,
               uv_names: tuple[str, str] = ("u", "v"), colors_first: bool = False) -> bytes:
    """Binary little-endian PLY: the one PLY writer (normalised meshes here, BOP models with
    ``scale=1000``, ``uv_names=("texture_u", "texture_v")``, ``colors_first=True``)."""
    dt = _vertex_dtype(mesh, uv_names, colors_first)
    n = len(mesh.vertices)
    vert = np.empty(n, dtype=dt)
    v = mesh.vertices if scale == 1.0 else mesh.vertices.astype(np.float64) * scale
    vert["x"], vert["y"], vert["z"] = v.astype(np.float32).T
    if mesh.normals is not None:
        vert["nx"], vert["ny"], vert["nz"] = mesh.normals.astype(np.float32).T
    if mesh.uv is not None:
        vert[uv_names[0]], vert[uv_names[1]] = mesh.uv.astype(np.float32).T
    if mesh.colors is not None:
        c = mesh.colors.astype(np.uint8)
        vert["red"], vert["green"], vert["blue"], vert["alpha"] = c.T
    faces = np.empty(len(mesh.faces), dtype=[("n", "u1"), ("i", "<i4", (3,))])
    faces["n"] = 3
    faces["i"] = mesh.faces.astype(np.int32)
    type_names = {"<f4": "float", "|u1": "uchar"}
    header = ["ply", "format binary_little_endian 1.0"]
    header += [f"comment {c}" for c in comments]
    header.append(f"element vertex {n}")
    header += [f"property {type_names[dt.fields[k][0].str]} {k}" for k in dt.names]
    header += [f"element face {len(mesh.faces)}", "property list uchar int vertex_indices", "end_header"]
    return ("\n".join(header) + "\n").encode("ascii") + vert.tobytes() + faces.tobytes()


def write_mesh(path: Path, mesh: MeshData, comments: tuple[str, ...] = ()) -> None:
    atomic_write_bytes(path, mesh_bytes(mesh, comments))


def read_mesh(path: str | Path) -> MeshData:
    """Read a PLY written by :func:`write_mesh`."""
    path = Path(path)
    data = path.read_bytes()
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply") or end < 0:
        raise MeshFormatError(f"{path}: not a PLY file")
    lines = data[:end].decode("ascii").splitlines()
    n_vert = n_face = 0
    props: list[tuple[str, str]] = []
    current = None
    for line in lines:
        parts = line.split()
        if parts[:1] == ["element"]:
            current = parts[1]
            if current == "vertex":
                n_vert = int(parts[2])
            elif current == "face":
                n_face = int(parts[2])
        elif parts[:1] == ["property"] and current == "vertex":
            props.append((parts[2], {"float": "<f4", "uchar": "u1"}[parts[1]]))
    if "binary_little_endian" not in lines[1]:
        raise MeshFormatError(f"{path}: expected binary_little_endian PLY")
    body = data[end + len(b"end_header\n") :]
    vdt = np.dtype(props)
    vert = np.frombuffer(body, dtype=vdt, count=n_vert)
    fdt = np.dtype([("n", "u1"), ("i", "<i4", (3,))])
    faces = np.frombuffer(body, dtype=fdt, count=n_face, offset=vdt.itemsize * n_vert)
    names = vdt.names

    def stack(*keys, dtype=np.float32):
        return np.stack([vert[k] for k in keys], axis=1).astype(dtype) if keys[0] in names else None

    return MeshData(
        vertices=stack("x", "y", "z"),
        faces=faces["i"].astype(np.int32),
        normals=stack("nx", "ny", "nz"),
        uv=stack("u", "v"),
        colors=stack("red", "green", "blue", "alpha", dtype=np.uint8),
    )
