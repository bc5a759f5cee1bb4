"""Sweet Home 3D furniture as scene geometry: sized to the catalogue, standing on z = 0.

A library model is a Y-up OBJ in arbitrary units. It is turned by the catalogue's ``modelRotation``
(if any), scaled (non-uniformly, as Sweet Home 3D does) so its bounding box is the catalogue's
width x height x depth, moved so the box's bottom centre is the origin, then turned to +Z up:
the furniture's front (+Z in Sweet Home 3D) faces -Y here. The scene mesh's own ``transform``
then places it (a yaw turns it; translation z = 0 stands it on the floor).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .library.furniture import FurnitureItem
from .meshfiles.part import Y_UP_TO_Z_UP, Part
from .meshio import MeshData


def furniture_matrix(item: FurnitureItem, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """4x4 from the (rotated) model's frame, whose bounds are lo..hi, to the sized +Z-up frame."""
    ext = np.maximum(hi - lo, 1e-9)
    w, d, h = item.size
    S = np.diag([w / ext[0], h / ext[1], d / ext[2]])
    centre_bottom = np.array([(lo[0] + hi[0]) / 2, lo[1], (lo[2] + hi[2]) / 2])
    T = np.eye(4)
    T[:3, :3] = Y_UP_TO_Z_UP @ S
    T[:3, 3] = -(Y_UP_TO_Z_UP @ S @ centre_bottom)
    return T


def normalise_parts(parts: list[Part], item: FurnitureItem) -> list[Part]:
    R = np.eye(3) if item.rotation is None else np.asarray(item.rotation, np.float64).reshape(3, 3)
    rotated = [p.mesh.vertices.astype(np.float64) @ R.T for p in parts]
    allv = np.concatenate(rotated)
    T = furniture_matrix(item, allv.min(0), allv.max(0))
    A = T[:3, :3] @ R  # model -> world linear part
    normal_map = np.linalg.inv(A)  # rows: n' = A^-T n  ->  n @ A^-1
    out = []
    for p, v in zip(parts, rotated):
        verts = v @ T[:3, :3].T + T[:3, 3]
        n = None
        if p.mesh.normals is not None:
            n = p.mesh.normals.astype(np.float64) @ normal_map
            n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
            n = n.astype(np.float32)
        faces = p.mesh.faces if np.linalg.det(A) > 0 else p.mesh.faces[:, ::-1].copy()
        mesh = MeshData(vertices=verts.astype(np.float32), faces=faces, normals=n, uv=p.mesh.uv, colors=p.mesh.colors)
        out.append(replace(p, mesh=mesh))
    return out
