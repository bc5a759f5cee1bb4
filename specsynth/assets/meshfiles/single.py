"""A mesh file trimesh reads -> one MeshData in the file's units: STL, OFF, and a spec's own OBJ or
glTF as one mesh (its materials are the spec's). An OBJ's or glTF's references are checked first
and trimesh is handed only those files (:func:`.part.checked_resolver`): a FIFO or a file outside
the mesh's folder is an error, never opened."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from ..meshio import MeshData
from . import gltf, obj
from .part import MeshFileError, check_face_indices, checked_resolver


FORMATS = {".stl": "STL", ".off": "OFF", ".obj": "Wavefront OBJ", ".gltf": "glTF", ".glb": "glTF binary (GLB)"}


def _resolver(path: Path):
    suffix = path.suffix.lower()
    if suffix == ".obj":
        return checked_resolver(path, obj.checked_references(path))
    if suffix in (".gltf", ".glb"):
        return checked_resolver(path, gltf.checked_references(path))
    return None


def read_single(path: Path) -> MeshData:
    import trimesh

    resolver = _resolver(path)
    try:
        loaded = trimesh.load(str(path), force="mesh", process=False, skip_materials=False, resolver=resolver)
    except Exception as e:  # trimesh raises a zoo of types for broken files; their messages may quote the file
        fmt = FORMATS.get(path.suffix.lower(), path.suffix or "a mesh")
        raise MeshFileError(f"{path}: not a readable {fmt} file (trimesh raised {type(e).__name__}): "
                            f"truncated, or another format under this name?") from None
    if not isinstance(loaded, trimesh.Trimesh) or len(loaded.vertices) == 0 or len(loaded.faces) == 0:
        raise MeshFileError(f"{path}: empty mesh (no vertices or triangles)")
    check_face_indices(path, len(loaded.vertices), loaded.faces)
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
