"""The one model every mesh-file reader produces."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...model.ir import MaterialIR
from ..meshio import MeshData

# glTF (+Y up) and Y-up OBJ exports -> our world (+Z up): x stays, y -> z, z -> -y.
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])

# A part's triangle budget: past it physics and the annotation engine would stall (issue: guard
# huge input). A scene of 200k triangles is well under it.
MAX_TRIANGLES = 5_000_000


class MeshFileError(ValueError):
    """A mesh file that cannot be used; the message names the file and, where known, the part."""


@dataclass(frozen=True)
class Part:
    name: str  # the material's name in the file (unique per file: '#2' appended on clashes)
    mesh: MeshData  # the file's length unit, +Z up, node transforms applied
    material: MaterialIR
    material_name: str  # as written in the file, for `materials:` overrides


def unique_names(names: list[str]) -> list[str]:
    seen: dict[str, int] = {}
    out = []
    for n in names:
        seen[n] = seen.get(n, 0) + 1
        out.append(n if seen[n] == 1 else f"{n}#{seen[n]}")
    return out


def concatenate(meshes: list[MeshData]) -> MeshData:
    """One mesh of several (attributes kept only when every mesh has them)."""
    if len(meshes) == 1:
        return meshes[0]
    offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])

    def cat(attr):
        arrays = [getattr(m, attr) for m in meshes]
        return None if any(a is None for a in arrays) else np.concatenate(arrays)

    return MeshData(
        vertices=np.concatenate([m.vertices for m in meshes]),
        faces=np.concatenate([m.faces + o for m, o in zip(meshes, offsets)]).astype(np.int32),
        normals=cat("normals"), uv=cat("uv"), colors=cat("colors"),
    )
