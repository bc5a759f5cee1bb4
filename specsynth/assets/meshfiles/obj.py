"""Wavefront OBJ with its MTL -> parts, one per ``usemtl`` material.

MTL is read here, not by trimesh, so that every statement is mapped the way Blender's OBJ
importer maps it and every texture keeps its own file:

- ``Kd`` base colour (linear, as Blender reads it), ``map_Kd`` base-colour texture (sRGB);
- ``Pr`` roughness, else from ``Ns``: ``1 - sqrt(Ns / 1000)`` (Blender's rule);
- ``Pm``/``map_Pm`` metallic, ``map_Pr`` roughness (grey maps, first channel);
- ``map_Bump``/``bump``/``norm``: a tangent-space normal map, ``-bm`` its scale (as Blender's
  importer reads them);
- ``Ke`` emission (radiance, strength 1), ``map_Ke`` its texture;
- ``d`` (or ``1 - Tr``) and ``map_d``: coverage, blended.

A texture named by the MTL but missing is a warning, and the part falls back to ``Kd``: scenes
exported from other machines often lose a texture or two, and a grey table beats no dataset. One
that is there must be an image within the pixel limit, and every file the OBJ and its MTL name
must lie in the OBJ's (or MTL's) folder (:func:`.part.referenced_file`); trimesh, which parses the
geometry, is handed only the checked material library and never opens a texture.
"""

from __future__ import annotations

import math
import re
import warnings
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from ...model.ir import MaterialIR
from ..meshio import MeshData
from . import bake
from .part import (
    MAX_TRIANGLES,
    MeshFileError,
    Part,
    checked_resolver,
    concatenate,
    read_file,
    referenced_file,
    unique_names,
)

_MAPS = {"map_Kd": "map_kd", "map_Pr": "map_pr", "map_Pm": "map_pm", "map_Bump": "map_bump", "bump": "map_bump",
         "norm": "map_bump", "map_Ke": "map_ke", "map_d": "map_d"}


@dataclass
class MtlMaterial:
    name: str
    kd: tuple[float, float, float] = (0.8, 0.8, 0.8)
    map_kd: str | None = None
    map_pr: str | None = None
    map_pm: str | None = None
    map_bump: str | None = None
    bump_scale: float = 1.0
    map_ke: str | None = None
    map_d: str | None = None
    ns: float | None = None
    pr: float | None = None
    pm: float = 0.0
    ke: tuple[float, float, float] = (0.0, 0.0, 0.0)
    dissolve: float = 1.0
    lines: dict[str, int] = field(default_factory=dict)  # map attribute -> its line in the MTL


def _text(path: Path) -> str:
    return read_file(path).decode("utf-8", errors="replace")


def _map_file(args: list[str]) -> str | None:
    """The file name of a ``map_*`` statement: the last token after its ``-option value`` pairs."""
    return " ".join(args[-1:]) if args else None


def _floats(args: list[str], n: int, where: str) -> tuple[float, ...]:
    try:
        vals = tuple(float(a) for a in args[:n])
    except ValueError:
        raise MeshFileError(f"{where}: expected {n} number(s)") from None
    if len(vals) == 1 and n == 3:
        vals = vals * 3  # "Kd 0.5" is grey
    if len(vals) != n or not all(math.isfinite(v) for v in vals):
        raise MeshFileError(f"{where}: expected {n} finite number(s)")
    return vals


def parse_mtl(path: Path) -> dict[str, MtlMaterial]:
    mats: dict[str, MtlMaterial] = {}
    cur: MtlMaterial | None = None
    for lineno, line in enumerate(_text(path).splitlines(), 1):
        parts = line.split()
        if not parts or parts[0].startswith("#"):
            continue
        key, args, where = parts[0], parts[1:], f"{path}:{lineno}"
        if key == "newmtl":
            cur = mats[" ".join(args)] = MtlMaterial(name=" ".join(args))
        elif cur is None:
            continue
        elif key == "Kd":
            cur.kd = _floats(args, 3, where)
        elif key in _MAPS:
            setattr(cur, _MAPS[key], _map_file(args))
            cur.lines[_MAPS[key]] = lineno
            if _MAPS[key] == "map_bump" and "-bm" in args[:-1]:
                cur.bump_scale = _floats(args[args.index("-bm") + 1 :], 1, where)[0]
        elif key == "Ns":
            cur.ns = _floats(args, 1, where)[0]
        elif key == "Pr":
            cur.pr = _floats(args, 1, where)[0]
        elif key == "Pm":
            cur.pm = _floats(args, 1, where)[0]
        elif key == "Ke":
            cur.ke = _floats(args, 3, where)
        elif key == "d":
            cur.dissolve = _floats(args, 1, where)[0]
        elif key == "Tr":
            cur.dissolve = 1.0 - _floats(args, 1, where)[0]
    return mats


def mtllib_statements(obj_path: Path) -> list[tuple[int, str]]:
    """(line, name as written) of every ``mtllib`` statement of an OBJ."""
    text = _text(obj_path)
    return [(text.count("\n", 0, m.start()) + 1, m.group(1))
            for m in re.finditer(r"^[ \t]*mtllib[ \t]+(.+?)[ \t]*$", text, re.M)]


def usemtl_names(obj_path: Path) -> set[str]:
    """Every material name an OBJ's ``usemtl`` statements give."""
    return {m.group(1) for m in re.finditer(r"^[ \t]*usemtl[ \t]+(.+?)[ \t]*$", _text(obj_path), re.M)}


def mtl_libraries(obj_path: Path) -> list[tuple[str, Path]]:
    """(name as written, file) of each material library an OBJ names; a missing one is returned
    as the path it would have (its parts then render grey). A named library that is missing while
    the OBJ's own stem ``<name>.mtl`` sits beside it (exporters that renamed the file, e.g. Sweet
    Home 3D's ``kids_shelves_sh3d.mtl`` shipped as ``kids_shelves.mtl``) is read from there instead."""
    libs = []
    for lineno, name in mtllib_statements(obj_path):
        where = f"{obj_path}:{lineno}: mtllib"
        lib = referenced_file(obj_path, name, where)
        if lib is None:
            own = referenced_file(obj_path, obj_path.with_suffix(".mtl").name, where)
            lib = own if own is not None else obj_path.parent / name
        libs.append((name, lib))
    return libs


def map_statements(mtl: Path) -> list[tuple[int, str]]:
    """(line, file name) of every map statement of an MTL (``map_Kd -s 2 2 wood.png`` -> wood.png)."""
    out = []
    for lineno, line in enumerate(_text(mtl).splitlines(), 1):
        parts = line.split()
        if parts and parts[0].startswith(("map_", "bump", "norm")) and len(parts) > 1:
            out.append((lineno, parts[-1]))
    return out


def texture_path(mtl: Path, name: str) -> Path:
    """Where a map statement's file would be, unchecked (whether a library model has a texture)."""
    return mtl.parent / name.replace("\\", "/")


def texture_file(mtl: Path, name: str, lineno: int | str, what: str = "map") -> Path | None:
    """The texture an MTL names at ``lineno``, checked (in the folder, an image within the pixel
    limit); None when it is missing."""
    where = f"{mtl}:{lineno}"
    tex = referenced_file(mtl, name, where)
    if tex is not None:
        bake.check_image(tex, f"{where}: {what}")
    return tex


def source_files(path: Path) -> list[Path]:
    """The OBJ, its material libraries and every texture they name that exists (each checked)."""
    out = [path]
    for _, lib in mtl_libraries(path):
        if not lib.is_file():
            continue
        out.append(lib)
        for lineno, name in map_statements(lib):
            tex = texture_file(lib, name, lineno)
            if tex is not None and tex not in out:
                out.append(tex)
    return out


def checked_references(path: Path) -> dict[str, Path]:
    """Name as written -> file of every material library and texture an OBJ names that exists,
    each checked: what a resolver handed to trimesh may serve (:func:`.part.checked_resolver`)."""
    files = {name: lib for name, lib in mtl_libraries(path) if lib.is_file()}
    for lib in list(files.values()):
        for lineno, name in map_statements(lib):
            tex = texture_file(lib, name, lineno)
            if tex is not None:
                files[name] = tex
    return files


def materials_of(path: Path) -> dict[str, tuple[MtlMaterial, Path]]:
    """Every material of the OBJ's libraries -> (material, the MTL it came from)."""
    out: dict[str, tuple[MtlMaterial, Path]] = {}
    for _, lib in mtl_libraries(path):
        if not lib.is_file():
            warnings.warn(f"{path}: material library {lib.name} is missing; its parts render grey", stacklevel=4)
            continue
        for name, mat in parse_mtl(lib).items():
            out.setdefault(name, (mat, lib))
    return out


def _texture(path: Path, mat: MtlMaterial, lib: Path, attr: str, kind: str, fallback: str = "ignored") -> Path | None:
    name = getattr(mat, attr)
    if not name:
        return None
    tex = texture_file(lib, name, mat.lines.get(attr, "?"), f"material {mat.name!r}: {kind}")
    if tex is None:
        warnings.warn(f"{path}: material {mat.name!r}: {kind} texture {name} is missing; {fallback}", stacklevel=5)
    return tex


def material_ir(path: Path, mat: MtlMaterial | None, lib: Path | None, texture_cache: Path) -> MaterialIR:
    from PIL import Image

    if mat is None:
        return MaterialIR(use_vertex_colors=False)
    what = f"{path}: material {mat.name!r}"
    base = _texture(path, mat, lib, "map_kd", "base colour", "using Kd")

    def baked(attr: str, kind: str, make) -> str | None:
        src = _texture(path, mat, lib, attr, kind)
        if src is None:
            return None
        with Image.open(src) as im:
            return str(bake.store_png(make(im), texture_cache))

    if mat.pr is not None:
        roughness = mat.pr
    elif mat.ns is not None:
        roughness = 1.0 - math.sqrt(min(max(mat.ns, 0.0), 1000.0) / 1000.0)
    else:
        roughness = 0.5
    emission = tuple(float(max(c, 0.0)) for c in mat.ke)
    opacity_tex = baked("map_d", "coverage", lambda im: bake.channel_map(im, 3 if "A" in im.getbands() else 0, mat.dissolve, what))
    return MaterialIR(
        base_color=(1.0, 1.0, 1.0) if base else tuple(float(np.clip(c, 0, 1)) for c in mat.kd),
        use_vertex_colors=False,
        texture=None if base is None else str(base),
        roughness=float(np.clip(roughness, 0, 1)),
        metallic=float(np.clip(mat.pm, 0, 1)),
        emission=emission,
        roughness_texture=baked("map_pr", "roughness", lambda im: bake.channel_map(im, 0, 1.0, what)),
        metallic_texture=baked("map_pm", "metallic", lambda im: bake.channel_map(im, 0, 1.0, what)),
        normal_texture=baked("map_bump", "normal", lambda im: bake.scaled_normal_map(im, mat.bump_scale, what)),
        emission_texture=_str(_texture(path, mat, lib, "map_ke", "emission")) if any(emission) else None,
        alpha_mode="blend" if (mat.dissolve < 1.0 or opacity_tex) else "opaque",
        opacity=float(np.clip(mat.dissolve, 0, 1)),
        opacity_texture=opacity_tex,
    )


def _str(p: Path | None) -> str | None:
    return None if p is None else str(p)


def read_parts(path: Path, texture_cache: Path) -> list[Part]:
    import trimesh

    mats = materials_of(path)
    # trimesh reads the material library (for its usemtl groups) through a resolver that serves
    # only the checked libraries: the textures it would load are read above, checked, instead.
    resolver = checked_resolver(path, {name: lib for name, lib in mtl_libraries(path) if lib.is_file()})
    try:
        loaded = trimesh.load(str(path), force="scene", process=False, group_material=True, skip_materials=False,
                              resolver=resolver)
    except Exception as e:  # trimesh raises many types for broken files
        raise MeshFileError(f"{path}: cannot read OBJ ({type(e).__name__})") from None
    groups: dict[str, list[MeshData]] = {}
    triangles = 0
    for node in loaded.graph.nodes_geometry:
        transform, geom_name = loaded.graph[node]
        geom = loaded.geometry[geom_name]
        if not isinstance(geom, trimesh.Trimesh) or len(geom.faces) == 0:
            continue
        triangles += len(geom.faces)
        if triangles > MAX_TRIANGLES:
            raise MeshFileError(f"{path}: more than {MAX_TRIANGLES:,} triangles; decimate it first")
        name = str(getattr(getattr(geom.visual, "material", None), "name", None) or "default")
        groups.setdefault(name, []).append(_mesh(geom, transform))
    if not groups:
        raise MeshFileError(f"{path}: no triangles")
    names = list(groups)
    parts = []
    for n, unique in zip(names, unique_names(names)):
        mat, lib = mats.get(n, (None, None))
        ir = material_ir(path, mat, lib, texture_cache)
        mesh = concatenate(groups[n])
        if not ir.textures:
            mesh = MeshData(vertices=mesh.vertices, faces=mesh.faces, normals=mesh.normals)
        elif mesh.uv is None:
            warnings.warn(f"{path}: material {n!r} has textures but its faces have no UVs; using its colours", stacklevel=3)
            bare = replace(mat, map_kd=None, map_pr=None, map_pm=None, map_bump=None, map_ke=None, map_d=None)
            ir = material_ir(path, bare, lib, texture_cache)
        parts.append(Part(name=unique, mesh=mesh, material=ir, material_name=n))
    return parts


def _mesh(geom, transform) -> MeshData:
    T = np.asarray(transform, np.float64)
    v = np.asarray(geom.vertices, np.float64) @ T[:3, :3].T + T[:3, 3]
    uv = None
    vis = geom.visual
    if getattr(vis, "kind", None) == "texture" and getattr(vis, "uv", None) is not None and len(vis.uv) == len(v):
        uv = np.asarray(vis.uv, np.float32)
    return MeshData(vertices=v.astype(np.float32), faces=np.asarray(geom.faces, np.int32),
                    normals=np.asarray(geom.vertex_normals, np.float32), uv=uv)
