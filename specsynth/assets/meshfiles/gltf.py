"""glTF 2.0 (``.glb``, ``.gltf``) -> parts, one per primitive material.

The file's node hierarchy, transforms and instancing are honoured (trimesh flattens the scene
graph); +Y up is turned into our +Z up. Materials follow the glTF metallic-roughness model:
base colour = ``baseColorFactor`` (linear) x ``baseColorTexture`` (sRGB); roughness and metallic =
factors (glTF's default 1.0 when absent) x the packed map's G and B channels; a tangent-space
normal map with its scale; emission = ``emissiveFactor`` x ``emissiveTexture`` x
``KHR_materials_emissive_strength`` as radiance (Blender's importer reads it the same way); alpha
(opaque, mask with ``alphaCutoff``, blend) from the base colour's alpha; ``KHR_texture_transform``
and the sampler's wrap mode of the base-colour texture; ``doubleSided``. Textures are written once
as PNG into the texture cache, named by their content hash (see :mod:`.bake`).
"""

from __future__ import annotations

import json
import math
import struct
import warnings
from dataclasses import replace
from pathlib import Path
from urllib.parse import unquote

import numpy as np

from ...model.ir import IDENTITY_UV, MaterialIR
from ..meshio import MeshData
from . import bake
from .part import MAX_TRIANGLES, Y_UP_TO_Z_UP, MeshFileError, Part, concatenate, unique_names

# Extensions a file may *require* that this reader renders correctly (or that change nothing here).
SUPPORTED_REQUIRED = {"KHR_materials_emissive_strength", "KHR_mesh_quantization", "KHR_texture_transform"}


def gltf_json(path: Path) -> dict:
    """The JSON document of a .gltf or the JSON chunk of a .glb, with located errors."""
    data = _read(path)
    if path.suffix.lower() == ".glb":
        if len(data) < 20 or data[:4] != b"glTF":
            raise MeshFileError(f"{path}: not a GLB file (no 'glTF' header)")
        _, _, total = struct.unpack_from("<4sII", data, 0)
        if total > len(data):
            raise MeshFileError(f"{path}: truncated GLB ({len(data)} of {total} bytes)")
        chunk_len, chunk_type = struct.unpack_from("<II", data, 12)
        if chunk_type != 0x4E4F534A or 20 + chunk_len > len(data):
            raise MeshFileError(f"{path}: GLB has no readable JSON chunk")
        raw = data[20 : 20 + chunk_len]
    else:
        raw = data
    try:
        doc = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as e:
        raise MeshFileError(f"{path}: glTF JSON is not valid ({type(e).__name__})") from None
    if not isinstance(doc, dict) or not str(doc.get("asset", {}).get("version", "")).startswith("2"):
        raise MeshFileError(f"{path}: not glTF 2.0 (asset.version missing or not 2.x)")
    return doc


def _read(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as e:
        raise MeshFileError(f"{path}: cannot read ({e.strerror})") from None


def check_extensions(path: Path, doc: dict) -> None:
    required = set(doc.get("extensionsRequired", [])) - SUPPORTED_REQUIRED
    if required:
        names = ", ".join(sorted(required))
        hint = " (Draco-compressed geometry: re-export without compression)" if "KHR_draco_mesh_compression" in required else ""
        raise MeshFileError(f"{path}: requires glTF extension(s) specsynth does not support: {names}{hint}")


def source_files(path: Path) -> list[Path]:
    """The file and every external buffer and image it references (data: URIs are inside it)."""
    doc = gltf_json(path)
    out = [path]
    for item in doc.get("buffers", []) + doc.get("images", []):
        uri = item.get("uri")
        if uri and not uri.startswith("data:"):
            ref = (path.parent / unquote(uri))
            if not ref.is_file():
                raise MeshFileError(f"{path}: references {uri!r}, which is missing")
            out.append(ref)
    return out


def read_parts(path: Path, texture_cache: Path) -> list[Part]:
    import trimesh

    doc = gltf_json(path)
    check_extensions(path, doc)
    source_files(path)  # a missing buffer or image is named before trimesh fails on it
    try:
        scene = trimesh.load(str(path), force="scene", process=False)
    except Exception as e:  # trimesh raises many types for broken files
        raise MeshFileError(f"{path}: cannot read glTF ({type(e).__name__})") from None
    # Keyed by the material itself, not its name: exporters often leave several named "default".
    by_material: dict[int, list[MeshData]] = {}
    materials: dict[int, MaterialIR] = {}
    names: dict[int, str] = {}
    triangles = 0
    for node in scene.graph.nodes_geometry:
        transform, geom_name = scene.graph[node]
        geom = scene.geometry[geom_name]
        if not isinstance(geom, trimesh.Trimesh) or len(geom.faces) == 0:
            continue  # points and lines are not surfaces
        triangles += len(geom.faces)
        if triangles > MAX_TRIANGLES:
            raise MeshFileError(f"{path}: more than {MAX_TRIANGLES:,} triangles; decimate it first")
        mat = getattr(geom.visual, "material", None)
        key = id(mat)
        if key not in materials:
            names[key] = str(getattr(mat, "name", None) or "default")
            materials[key] = _material(path, names[key], mat, material_json(doc, names[key]), doc, texture_cache)
        by_material.setdefault(key, []).append(_mesh(geom, transform, materials[key]))
    if not by_material:
        raise MeshFileError(f"{path}: no triangles")
    keys = list(by_material)
    parts = []
    for key, unique in zip(keys, unique_names([names[k] for k in keys])):
        mesh, material = concatenate(by_material[key]), materials[key]
        if material.textures and mesh.uv is None:
            warnings.warn(f"{path}: material {names[key]!r} has textures but its primitives no UVs; using its colours",
                          stacklevel=3)
            material = untextured(material)
        parts.append(Part(name=unique, mesh=mesh, material=material, material_name=names[key]))
    return parts


def untextured(m: MaterialIR) -> MaterialIR:
    return replace(m, texture=None, roughness_texture=None, metallic_texture=None, normal_texture=None,
                   emission_texture=None, opacity_texture=None, alpha_mode="opaque" if m.opacity_texture else m.alpha_mode)


def _mesh(geom, transform: np.ndarray, material: MaterialIR) -> MeshData:
    R = Y_UP_TO_Z_UP @ np.asarray(transform, np.float64)[:3, :3]
    t = Y_UP_TO_Z_UP @ np.asarray(transform, np.float64)[:3, 3]
    v = np.asarray(geom.vertices, np.float64) @ R.T + t
    faces = np.asarray(geom.faces, np.int32)
    if np.linalg.det(R) < 0:  # a mirroring node: keep the faces facing out
        faces = faces[:, ::-1].copy()
    vis = geom.visual
    uv = colors = None
    if getattr(vis, "kind", None) == "texture" and getattr(vis, "uv", None) is not None and len(vis.uv) == len(v):
        uv = np.asarray(vis.uv, np.float32)  # trimesh gives OpenGL's v-up, as MeshData wants
    elif getattr(vis, "kind", None) == "vertex":
        colors = np.asarray(vis.vertex_colors, np.uint8)
    n = np.asarray(geom.vertex_normals, np.float64) @ np.linalg.inv(R)  # inv(R).T @ n, row-wise
    normals = (n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)).astype(np.float32)
    if not material.textures:
        uv = None
    return MeshData(vertices=v.astype(np.float32), faces=faces, normals=normals, uv=uv, colors=colors)


_WRAP = {10497: "repeat", 33071: "clamp", 33648: "mirror"}
_FLIP_V = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 1.0], [0.0, 0.0, 1.0]])  # glTF's v-down <-> our v-up


def uv_transform(info: dict | None) -> tuple[float, ...]:
    """``KHR_texture_transform`` of a texture info, as our v-up affine map (a, b, c, d, e, f)."""
    ext = (info or {}).get("extensions", {}).get("KHR_texture_transform")
    if not ext:
        return IDENTITY_UV
    ox, oy = ext.get("offset", (0.0, 0.0))
    r = float(ext.get("rotation", 0.0))
    sx, sy = ext.get("scale", (1.0, 1.0))
    T = np.array([[1, 0, ox], [0, 1, oy], [0, 0, 1]], np.float64)
    R = np.array([[math.cos(r), math.sin(r), 0], [-math.sin(r), math.cos(r), 0], [0, 0, 1]])
    S = np.diag([sx, sy, 1.0])
    M = _FLIP_V @ (T @ R @ S) @ _FLIP_V
    return tuple(float(x) for x in M[:2].ravel())


def _wrap(doc: dict, info: dict | None) -> str:
    tex = doc.get("textures", [])
    i = (info or {}).get("index")
    if i is None or not 0 <= i < len(tex) or "sampler" not in tex[i]:
        return "repeat"
    sampler = doc.get("samplers", [])[tex[i]["sampler"]] if tex[i]["sampler"] < len(doc.get("samplers", [])) else {}
    modes = {_WRAP.get(sampler.get("wrapS", 10497), "repeat"), _WRAP.get(sampler.get("wrapT", 10497), "repeat")}
    return modes.pop() if len(modes) == 1 else "repeat"  # per-axis modes: one is all backends take


def material_json(doc: dict, name: str) -> dict:
    for m in doc.get("materials", []):
        if m.get("name") == name:
            return m
    return {}


def _material(path: Path, name: str, mat, js: dict, doc: dict, texture_cache: Path) -> MaterialIR:
    if mat is None:
        return MaterialIR(use_vertex_colors=True)
    if not hasattr(mat, "baseColorFactor"):  # a SimpleMaterial from an odd file: diffuse only
        mat = mat.to_pbr()
    what = f"{path}: material {name!r}"
    pbr = js.get("pbrMetallicRoughness", {})
    factor = mat.baseColorFactor
    rgba = np.ones(4) if factor is None else np.asarray(factor, np.float64) / (255.0 if np.asarray(factor).dtype == np.uint8 else 1.0)
    rough = 1.0 if mat.roughnessFactor is None else float(np.clip(mat.roughnessFactor, 0, 1))
    metal = 1.0 if mat.metallicFactor is None else float(np.clip(mat.metallicFactor, 0, 1))
    strength = float(js.get("extensions", {}).get("KHR_materials_emissive_strength", {}).get("emissiveStrength", 1.0))
    emission = np.zeros(3) if mat.emissiveFactor is None else np.asarray(mat.emissiveFactor, np.float64) * strength
    mode = str(js.get("alphaMode", "OPAQUE")).lower()
    fields: dict = dict(
        base_color=tuple(float(c) for c in np.clip(rgba[:3], 0, 1)), use_vertex_colors=True,
        roughness=rough, metallic=metal, emission=tuple(float(c) for c in np.maximum(emission, 0)),
        alpha_mode=mode if mode in ("opaque", "mask", "blend") else "opaque",
        double_sided=bool(js.get("doubleSided", False)),
        uv_transform=uv_transform(pbr.get("baseColorTexture") or js.get("normalTexture")),
        wrap=_wrap(doc, pbr.get("baseColorTexture")),
    )
    store = lambda image: str(bake.store_png(image, texture_cache))  # noqa: E731
    if mat.baseColorTexture is not None:
        fields["texture"] = store(mat.baseColorTexture.convert("RGB"))
    if mat.metallicRoughnessTexture is not None:
        fields["roughness_texture"] = store(bake.channel_map(mat.metallicRoughnessTexture, 1, rough, what))
        fields["metallic_texture"] = store(bake.channel_map(mat.metallicRoughnessTexture, 2, metal, what))
    if mat.normalTexture is not None:
        scale = float(js.get("normalTexture", {}).get("scale", 1.0))
        fields["normal_texture"] = store(bake.scaled_normal_map(mat.normalTexture, scale, what))
    if mat.emissiveTexture is not None and emission.any():
        fields["emission_texture"] = store(mat.emissiveTexture.convert("RGB"))
    if fields["alpha_mode"] != "opaque":
        cutoff = float(js.get("alphaCutoff", 0.5))
        if mat.baseColorTexture is not None and bake.has_alpha(mat.baseColorTexture):
            fields["opacity_texture"] = store(bake.coverage_map(mat.baseColorTexture, rgba[3], fields["alpha_mode"], cutoff, what))
        else:
            fields["opacity"] = float(rgba[3] >= cutoff) if fields["alpha_mode"] == "mask" else float(rgba[3])
        if fields["opacity"] >= 1.0 and "opacity_texture" not in fields:
            fields["alpha_mode"] = "opaque"
    if mat.occlusionTexture is not None:
        warnings.warn(f"{what}: occlusionTexture is ignored (path tracers compute occlusion)", stacklevel=4)
    return MaterialIR(**fields)
