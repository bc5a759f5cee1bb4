"""STL, OFF and other single-material formats trimesh reads -> one MeshData in the file's units."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..meshio import MeshData
from .part import MeshFileError


def read_single(path: Path) -> MeshData:
    import trimesh

    try:
        loaded = trimesh.load(str(path), force="mesh", process=False, skip_materials=False)
    except Exception as e:  # trimesh raises a zoo of types for broken files
        raise MeshFileError(f"{path}: cannot read mesh ({type(e).__name__})") from None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.vertices) == 0 or len(loaded.faces) == 0:
        raise MeshFileError(f"{path}: empty mesh (no vertices or triangles)")
    uv = colors = None
    vis = loaded.visual
    if getattr(vis, "kind", None) == "texture" and getattr(vis, "uv", None) is not None:
        if len(vis.uv) == len(loaded.vertices):
            uv = np.asarray(vis.uv, np.float64)
    elif getattr(vis, "kind", None) == "vertex":
        colors = np.asarray(vis.vertex_colors, np.uint8)
    verts = np.asarray(loaded.vertices, np.float64)
    normals = None
    if np.isfinite(verts).all():
        normals = np.asarray(loaded.vertex_normals, np.float64)
    return MeshData(vertices=verts, faces=np.asarray(loaded.faces, np.int32), normals=normals, uv=uv, colors=colors)
