"""PLY (ASCII or binary; BOP models, our normalised meshes, scanned objects) -> MeshData in the
file's own units, plus the texture a BOP header names."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..meshio import MeshData
from .part import MeshFileError

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}


def read_ply(path: Path) -> tuple[dict[str, np.ndarray], np.ndarray, list[str]]:
    """Any PLY (ASCII or binary) -> (vertex properties, triangles, header comments).

    Our own reader because trimesh's tries to load the texture a BOP header names and logs a
    traceback when it is missing (the normal case for BOP downloads without textures).
    """
    data = path.read_bytes()
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise MeshFileError(f"{path}: not a PLY file (no 'ply' magic or 'end_header')")
    body_start = data.index(b"\n", end) + 1
    header = data[:end].decode("ascii", errors="replace").splitlines()
    fmt, comments, elements = None, [], []
    for line in header[1:]:
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "format":
            fmt = parts[1]
        elif parts[0] in ("comment", "obj_info"):
            comments.append(line.split(None, 1)[1] if len(parts) > 1 else "")
        elif parts[0] == "element":
            elements.append([parts[1], int(parts[2]), []])
        elif parts[0] == "property" and elements:
            if parts[1] == "list":
                elements[-1][2].append((parts[4], "list", _PLY_TYPES[parts[2]], _PLY_TYPES[parts[3]]))
            else:
                elements[-1][2].append((parts[2], _PLY_TYPES[parts[1]], None, None))
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise MeshFileError(f"{path}: unsupported PLY format {fmt!r}")
    vertex, faces = {}, np.zeros((0, 3), np.int64)
    if fmt == "ascii":
        tokens = data[body_start:].split()
        pos = 0
        for name, count, props in elements:
            if all(p[1] != "list" for p in props):
                n = len(props)
                arr = np.asarray(tokens[pos:pos + n * count], dtype=np.float64).reshape(count, n)
                pos += n * count
                if name == "vertex":
                    vertex = {p[0]: arr[:, i] for i, p in enumerate(props)}
            else:
                # Faces: per row, scalar props then one list; vectorised when all lists are triangles.
                polys = []
                for _ in range(count):
                    row = []
                    for p in props:
                        if p[1] == "list":
                            k = int(tokens[pos])
                            row = [int(t) for t in tokens[pos + 1:pos + 1 + k]]
                            pos += 1 + k
                        else:
                            pos += 1
                    polys.append(row)
                if name == "face":
                    faces = _triangulate(polys)
    else:
        endian = "<" if fmt == "binary_little_endian" else ">"
        off = body_start
        for name, count, props in elements:
            if all(p[1] != "list" for p in props):
                dt = np.dtype([(p[0], endian + p[1]) for p in props])
                arr = np.frombuffer(data, dtype=dt, count=count, offset=off)
                off += dt.itemsize * count
                if name == "vertex":
                    vertex = {p[0]: arr[p[0]].astype(np.float64) for p in props}
            else:
                faces_e, off = _binary_lists(data, off, count, props, endian)
                if name == "face":
                    faces = faces_e
    return vertex, faces, comments


def _binary_lists(data: bytes, off: int, count: int, props, endian: str):
    list_props = [p for p in props if p[1] == "list"]
    if len(props) == 1 and len(list_props) == 1:
        cnt_t, idx_t = np.dtype(endian + list_props[0][2]), np.dtype(endian + list_props[0][3])
        # Fast path: every polygon a triangle (true for BOP and most exporters).
        dt = np.dtype([("n", cnt_t), ("i", idx_t, (3,))])
        if len(data) - off >= dt.itemsize * count:
            arr = np.frombuffer(data, dtype=dt, count=count, offset=off)
            if (arr["n"] == 3).all():
                return arr["i"].astype(np.int64), off + dt.itemsize * count
    polys = []
    for _ in range(count):
        row = []
        for p in props:
            if p[1] == "list":
                ct, it = np.dtype(endian + p[2]), np.dtype(endian + p[3])
                k = int(np.frombuffer(data, ct, 1, off)[0])
                off += ct.itemsize
                row = np.frombuffer(data, it, k, off).tolist()
                off += it.itemsize * k
            else:
                off += np.dtype(p[1]).itemsize
        polys.append(row)
    return _triangulate(polys), off


def _triangulate(polys: list[list[int]]) -> np.ndarray:
    if polys and all(len(p) == 3 for p in polys):
        return np.asarray(polys, dtype=np.int64)
    tris = [(p[0], p[i], p[i + 1]) for p in polys for i in range(1, len(p) - 1)]
    return np.asarray(tris, dtype=np.int64).reshape(-1, 3)


def ply_to_mesh(path: Path) -> tuple[MeshData, str | None]:
    """-> (mesh in file units, texture file named in the header or None)."""
    try:
        v, f, comments = read_ply(path)
    except MeshFileError:
        raise
    except (ValueError, IndexError, KeyError, UnicodeDecodeError) as e:
        # The exception's text can quote the file's bytes ("could not convert string to float:
        # b'...'"): an error names what is wrong, never what the file holds.
        raise MeshFileError(f"{path}: corrupt PLY ({type(e).__name__}: its data does not match its header)") from None
    if not {"x", "y", "z"} <= set(v):
        raise MeshFileError(f"{path}: PLY has no vertex x/y/z (empty or corrupt mesh)")
    verts = np.stack([v["x"], v["y"], v["z"]], 1)
    normals = np.stack([v["nx"], v["ny"], v["nz"]], 1) if {"nx", "ny", "nz"} <= set(v) else None
    uv = None
    for ku, kv in (("texture_u", "texture_v"), ("u", "v"), ("s", "t")):
        if ku in v and kv in v:
            uv = np.stack([v[ku], v[kv]], 1)
            break
    colors = None
    if {"red", "green", "blue"} <= set(v):
        c = [v["red"], v["green"], v["blue"], v.get("alpha", np.full(len(verts), 255.0))]
        colors = np.clip(np.stack(c, 1), 0, 255).astype(np.uint8)
    texture = None
    for c in comments:
        parts = c.split()
        if len(parts) >= 2 and parts[0].lower() == "texturefile":
            texture = c.split(None, 1)[1].strip()
    mesh = MeshData(
        vertices=verts, faces=f.astype(np.int32), normals=normals, uv=uv, colors=colors
    )
    return mesh, texture
