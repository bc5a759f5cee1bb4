"""Mesh files with their materials: one reader per format, one model out.

``read_parts(path)`` returns a file's geometry as :class:`Part` s, one per material, in the file's
own length unit but in our frame (+Z up); each part's material is a backend-neutral
:class:`~specsynth.model.ir.MaterialIR`. ``source_files(path)`` lists every file whose bytes the result
depends on (the mesh, its material libraries, buffers and textures), for content keys.

One module per format, all producing :class:`~specsynth.assets.meshio.MeshData` (and, for the
multi-material formats, :class:`~specsynth.model.ir.MaterialIR` per part): glTF 2.0 (``.glb``/``.gltf``,
:mod:`.gltf`) and OBJ with its MTL (:mod:`.obj`) keep every material; PLY (:mod:`.ply`), STL/OFF
(:mod:`.single`) and URDF visuals (:mod:`.urdf`) are single-material, read through
:mod:`specsynth.assets.resolve`. Readers raise :class:`MeshFileError` naming the file; texture maps are
baked once into a content-keyed cache (:mod:`.bake`).
"""

from __future__ import annotations

from pathlib import Path

from . import gltf, obj
from .part import MAX_TRIANGLES, MeshFileError, Part

MULTI_MATERIAL_SUFFIXES = (".glb", ".gltf", ".obj")

__all__ = ["MAX_TRIANGLES", "MULTI_MATERIAL_SUFFIXES", "MeshFileError", "Part", "material_names", "read_parts",
           "source_files"]


def read_parts(path: Path, texture_cache: Path) -> list[Part]:
    """Parts of a glTF or OBJ file; embedded textures are written once into ``texture_cache``."""
    path = Path(path)
    if path.suffix.lower() in (".glb", ".gltf"):
        return gltf.read_parts(path, texture_cache)
    if path.suffix.lower() == ".obj":
        return obj.read_parts(path, texture_cache)
    raise MeshFileError(f"{path}: not a glTF or OBJ file")


def source_files(path: Path) -> list[Path]:
    path = Path(path)
    if path.suffix.lower() in (".glb", ".gltf"):
        return gltf.source_files(path)
    if path.suffix.lower() == ".obj":
        return obj.source_files(path)
    return [path]


def material_names(path: Path) -> set[str]:
    """The names a scene file's ``materials:`` may give for a glTF or OBJ file, read without its
    geometry: a glTF's materials, an OBJ's ``usemtl`` and ``newmtl`` names; and ``default``, what
    a part without a named material is called (:func:`read_parts`)."""
    path = Path(path)
    if path.suffix.lower() in (".glb", ".gltf"):
        return {"default", *(str(m.get("name") or "default") for m in gltf.items(path, gltf.gltf_json(path), "materials"))}
    if path.suffix.lower() == ".obj":
        return {"default", *obj.usemtl_names(path), *obj.materials_of(path)}
    return {"default"}

