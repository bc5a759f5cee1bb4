"""A scene mesh whose source is a glTF or OBJ file: one normalised mesh per material of the file.

Parts are converted once and cached like every scene mesh: ``<cache>/assets/<key>.<i>.ply`` and a
sidecar ``<key>.parts.json`` naming each part and its material. Texture paths in the sidecar are
relative to where they live (the source file's folder, or the texture cache for textures embedded
in a GLB), so a cache entry never points a later build at another folder's files; the key covers
the bytes of the mesh, its material libraries and every texture.

Which material a part gets, most specific first: ``materials: {<name in the file>: ...}`` on the
scene mesh, then an explicit ``material:`` on it (which overrides every part), then the file's own.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, replace
from pathlib import Path
from typing import Callable

from ..assets import meshfiles
from ..assets import resolve as assets
from ..assets.meshfiles.primitives import with_box_uvs
from ..assets.meshio import MeshData
from ..atomic import atomic_write_bytes
from ..model.ir import MaterialIR
from .models import SceneMesh

PARTS_VERSION = 4  # 2: every PBR map, alpha, UV transform, wrap; 3: has_uv; 4: box UVs where none
TEXTURE_FIELDS = ("texture", "roughness_texture", "metallic_texture", "normal_texture", "emission_texture",
                  "opacity_texture")
TEXTURE_DIR = "textures"  # under <cache>/assets: embedded glTF textures by content hash


def is_multi_material(src: Path | None) -> bool:
    return src is not None and src.suffix.lower() in meshfiles.MULTI_MATERIAL_SUFFIXES


def _texture_ref(texture: str | None, src: Path, cache: Path) -> dict | None:
    if texture is None:
        return None
    tex = Path(texture)
    tex_root = cache / "assets" / TEXTURE_DIR
    if tex.parent == tex_root:
        return {"in": "cache", "name": tex.name}
    return {"in": "source", "rel": os.path.relpath(tex, src.parent)}


def _texture_path(ref: dict | None, src: Path, cache: Path) -> str | None:
    if ref is None:
        return None
    if ref["in"] == "cache":
        return str(cache / "assets" / TEXTURE_DIR / ref["name"])
    return str(os.path.normpath(src.parent / ref["rel"]))


def convert_parts(
    m: SceneMesh, src: Path, key: str, cache: Path, finish: Callable[[MeshData], MeshData],
    prepare: Callable[[list], list] | None = None,
) -> list[tuple[str, str, Path, str, MaterialIR, bool]]:
    """-> (part name, material name in the file, PLY path, mesh_key, file material, has UVs) per part.
    ``prepare`` transforms the file's parts as a whole first (library furniture is sized on its
    overall bounding box), ``finish`` each part's mesh after."""
    sidecar = cache / "assets" / f"{key}.parts.json"
    try:
        meta = json.loads(sidecar.read_text())
        if meta.get("v") == PARTS_VERSION and all((cache / "assets" / p["ply"]).is_file() for p in meta["parts"]):
            return [_from_meta(p, src, cache) for p in meta["parts"]]
    except (OSError, ValueError, KeyError):
        pass  # absent, torn or stale: convert again
    parts = meshfiles.read_parts(src, cache / "assets" / TEXTURE_DIR)
    if prepare is not None:
        parts = prepare(parts)
    rows = []
    for i, part in enumerate(parts):
        mesh = with_box_uvs(finish(part.mesh))  # a texture given to a part shows, as in Blender
        ply, mesh_key = assets.store_mesh(mesh, f"{key}.{i}", cache)
        mat = asdict(part.material)
        for k in TEXTURE_FIELDS:
            mat[k] = _texture_ref(mat[k], src, cache)
        rows.append({"name": part.name, "material_name": part.material_name, "ply": ply.name,
                     "mesh_key": mesh_key, "material": mat, "has_uv": mesh.uv is not None})
    atomic_write_bytes(sidecar, json.dumps({"v": PARTS_VERSION, "parts": rows}, sort_keys=True).encode())
    return [_from_meta(p, src, cache) for p in rows]


def _from_meta(p: dict, src: Path, cache: Path) -> tuple[str, str, Path, str, MaterialIR, bool]:
    mat = dict(p["material"])
    for k in TEXTURE_FIELDS:
        mat[k] = _texture_path(mat[k], src, cache)
    for k in ("base_color", "emission", "uv_transform"):
        mat[k] = tuple(mat[k])
    return p["name"], p["material_name"], cache / "assets" / p["ply"], p["mesh_key"], MaterialIR(**mat), p["has_uv"]


def part_material(
    m: SceneMesh, file_material: MaterialIR, material_name: str, yaml_material: Callable[..., MaterialIR],
    has_uv: bool = True,
) -> MaterialIR:
    """The material a part renders with (see the module docstring for the order). A texture given
    to a part without UVs cannot be mapped: it is dropped, keeping the colour."""
    own = Path(file_material.texture) if file_material.texture else None
    if material_name in m.materials:
        chosen = yaml_material(m.materials[material_name], own)
    elif "material" in m.model_fields_set:
        chosen = yaml_material(m.material, own)
    else:
        return file_material
    if chosen.textures and not has_uv:
        return replace(chosen, texture=None, base_color=chosen.base_color if chosen.base_color != (1.0, 1.0, 1.0)
                       else file_material.base_color)
    return chosen
