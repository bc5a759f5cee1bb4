"""The one model every mesh-file reader produces."""

from __future__ import annotations

import functools
import importlib.util
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...files import inside, not_a_file, read_regular
from ...model.ir import MaterialIR
from ..meshio import MeshData

# glTF (+Y up) and Y-up OBJ exports -> our world (+Z up): x stays, y -> z, z -> -y.
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])

# A part's triangle budget: past it physics and the annotation engine would stall (issue: guard
# huge input). A scene of 200k triangles is well under it.
MAX_TRIANGLES = 5_000_000


class MeshFileError(ValueError):
    """A mesh file that cannot be used; the message names the file and, where known, the part."""


def check_face_indices(path: Path, n_vertices: int, faces) -> None:
    """Every triangle's indices name one of the ``n_vertices`` (trimesh reads a glTF's indices as
    given, and its normals then fail with a bare IndexError)."""
    import numpy as np

    f = np.asarray(faces)
    if f.size and (f.min() < 0 or f.max() >= n_vertices):
        raise MeshFileError(f"{path}: face indices out of range (0..{n_vertices - 1}, found {int(f.min())}..{int(f.max())})")


@functools.lru_cache(maxsize=1)
def _package_data() -> tuple[Path, ...]:
    """Installed package data whose files name each other across their own folders (pybullet_data's
    torus: ``map_Kd ../checker_grid.jpg``): trusted, so its root, not the file's folder, bounds them."""
    spec = importlib.util.find_spec("pybullet_data")
    return tuple(Path(p).resolve() for p in (spec.submodule_search_locations or [])) if spec else ()


def reference_root(naming: Path) -> Path:
    """The folder the files that ``naming`` names must stay in: its own folder, or the installed
    package it belongs to."""
    return next((root for root in _package_data() if inside(naming, root)), Path(naming).parent)


def referenced_file(naming: Path, name: str, where: str) -> Path | None:
    """The file ``name`` refers to, written in ``naming`` (an OBJ's ``mtllib`` and maps, a glTF's
    buffers and images, a URDF's meshes, a PLY's texture) at ``where`` ("file:line", "file:
    buffers[0]"). None when nothing is there (each format decides whether that is fatal).

    A downloaded file must not read the user's other files: a reference that exists but leaves
    the folder of the file naming it (``../../photos/me.jpg``, ``/etc/passwd``, or a link whose
    target lies elsewhere) is an error, as is one that is a FIFO, a device or a folder."""
    ref = Path(naming).parent / name.replace("\\", "/")
    problem = not_a_file(ref)
    if problem == "not found":
        return None
    root = reference_root(naming)
    if not inside(ref, root):
        raise MeshFileError(f"{where}: {name!r} is outside the folder of {Path(naming).name} ({root}); a mesh or "
                            "scene file may name only files in its own folder or below (copy the file there, or "
                            "give it in the scene file's 'materials:')")
    if problem is not None:
        raise MeshFileError(f"{where}: {ref} is {problem}")
    return ref


def read_file(path: Path, what: str | None = None) -> bytes:
    """A mesh file's bytes, read only when it is a regular file."""
    try:
        return read_regular(path)
    except OSError as e:
        raise MeshFileError(f"{what or path}: cannot read {path} ({e.strerror or type(e).__name__})") from None


def checked_resolver(naming: Path, files: dict[str, Path]):
    """A trimesh resolver that serves only ``files`` (names as the mesh file writes them -> the
    checked file): whatever else a file names is never opened by trimesh."""
    import trimesh

    class Resolver(trimesh.resolvers.FilePathResolver):
        def get(self, name: str):
            path = files.get(name.strip()) or files.get(name.strip().replace("\\", "/"))
            if path is None:
                raise FileNotFoundError(name)
            return read_file(path)

    return Resolver(str(naming))


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
