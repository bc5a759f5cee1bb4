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

Before trimesh sees a file, :func:`source_files` checks what it names and what its nodes do (it
runs in ``validate``): every buffer and image is in the file's folder (:func:`.part.referenced_file`)
and every image decodes within the pixel limit; nodes form a tree of finite, invertible transforms
that keep geometry within :data:`MAX_COORDINATE` of the origin. Errors name the file and the node.
"""

from __future__ import annotations

import base64
import binascii
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
from .part import (
    MAX_TRIANGLES,
    Y_UP_TO_Z_UP,
    MeshFileError,
    Part,
    check_face_indices,
    checked_resolver,
    concatenate,
    read_file,
    referenced_file,
    unique_names,
)

# Extensions a file may *require* that this reader renders correctly (or that change nothing here).
SUPPORTED_REQUIRED = {"KHR_materials_emissive_strength", "KHR_mesh_quantization", "KHR_texture_transform"}

# Metres from the origin past which a node's geometry is refused: scenes are rooms and yards, and
# float32 vertices out there lose the centimetres (a translation of 1e30 asked for 204 PiB).
MAX_COORDINATE = 10_000.0
# A node whose scale is below this on an axis flattens its geometry to nothing (a singular matrix).
MIN_SCALE = 1e-6


def gltf_json(path: Path) -> dict:
    """The JSON document of a .gltf or the JSON chunk of a .glb, with located errors."""
    return _document(path)[0]


def _document(path: Path) -> tuple[dict, bytes | None]:
    """(JSON document, GLB binary chunk or None)."""
    data = read_file(path)
    binary = None
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
        rest = 20 + chunk_len
        if rest + 8 <= len(data):
            bin_len, bin_type = struct.unpack_from("<II", data, rest)
            if bin_type == 0x004E4942:
                binary = data[rest + 8 : rest + 8 + bin_len]
    else:
        raw = data
    try:
        doc = json.loads(raw.decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as e:
        raise MeshFileError(f"{path}: glTF JSON is not valid ({type(e).__name__})") from None
    asset = doc.get("asset") if isinstance(doc, dict) else None
    if not isinstance(asset, dict) or not str(asset.get("version", "")).startswith("2"):
        raise MeshFileError(f"{path}: not glTF 2.0 (asset.version missing or not 2.x)")
    return doc, binary


def items(path: Path, doc: dict, key: str) -> list[dict]:
    """A top-level array of the document (``nodes``, ``buffers``...), every entry an object."""
    value = doc.get(key, [])
    if not isinstance(value, list) or not all(isinstance(x, dict) for x in value):
        raise MeshFileError(f"{path}: {key} must be an array of objects")
    return value


def index(path: Path, value, n: int, where: str) -> int:
    """An index into an array of ``n`` entries; anything else is named, never quoted."""
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < n:
        raise MeshFileError(f"{path}: {where} must be an index in 0..{n - 1}")
    return value


def numbers(path: Path, value, n: int, where: str) -> np.ndarray:
    if not isinstance(value, list) or len(value) != n or not all(
            isinstance(x, (int, float)) and not isinstance(x, bool) for x in value):
        raise MeshFileError(f"{path}: {where} must be {n} numbers")
    a = np.asarray(value, np.float64)
    if not np.isfinite(a).all():
        raise MeshFileError(f"{path}: {where} holds NaN or infinite numbers")
    return a


def check_extensions(path: Path, doc: dict) -> None:
    required = set(doc.get("extensionsRequired", [])) - SUPPORTED_REQUIRED
    if required:
        names = ", ".join(sorted(required))
        hint = " (Draco-compressed geometry: re-export without compression)" if "KHR_draco_mesh_compression" in required else ""
        raise MeshFileError(f"{path}: requires glTF extension(s) specsynth does not support: {names}{hint}")


def _uri(path: Path, item: dict, where: str) -> str | None:
    uri = item.get("uri")
    if uri is not None and not isinstance(uri, str):
        raise MeshFileError(f"{path}: {where}.uri must be a string")
    return uri


def _referenced(path: Path, doc: dict) -> dict[str, Path]:
    """uri as written -> file, for every external buffer and image (data: URIs are inside the file)."""
    out: dict[str, Path] = {}
    for key in ("buffers", "images"):
        for i, item in enumerate(items(path, doc, key)):
            uri = _uri(path, item, f"{key}[{i}]")
            if not uri or uri.startswith("data:"):
                continue
            ref = referenced_file(path, unquote(uri), f"{path}: {key}[{i}]")
            if ref is None:
                raise MeshFileError(f"{path}: {key}[{i}] references {uri!r}, which is missing")
            out[uri] = out[unquote(uri)] = ref
    return out


def _data_uri(path: Path, uri: str, where: str) -> bytes:
    try:
        return base64.b64decode(uri[uri.index("base64,") + 7:], validate=True)
    except (ValueError, binascii.Error):
        raise MeshFileError(f"{path}: {where} is a data: URI that is not base64") from None


def _buffer(path: Path, doc: dict, binary: bytes | None, refs: dict[str, Path], i: int) -> bytes:
    buf = items(path, doc, "buffers")[i]
    uri = _uri(path, buf, f"buffers[{i}]")
    if uri is None:
        if binary is None:
            raise MeshFileError(f"{path}: buffers[{i}] has no uri and the file no binary chunk")
        return binary
    return _data_uri(path, uri, f"buffers[{i}]") if uri.startswith("data:") else read_file(refs[uri])


def _image_bytes(path: Path, doc: dict, binary: bytes | None, refs: dict[str, Path], i: int) -> bytes | Path:
    image = items(path, doc, "images")[i]
    uri = _uri(path, image, f"images[{i}]")
    if uri is not None:
        return _data_uri(path, uri, f"images[{i}]") if uri.startswith("data:") else refs[uri]
    views = items(path, doc, "bufferViews")
    view = views[index(path, image.get("bufferView"), len(views), f"images[{i}].bufferView")]
    data = _buffer(path, doc, binary, refs, index(path, view.get("buffer"), len(items(path, doc, "buffers")),
                                                  f"images[{i}]'s bufferView.buffer"))
    start = view.get("byteOffset", 0)
    length = view.get("byteLength", 0)
    if not all(isinstance(x, int) and x >= 0 for x in (start, length)) or start + length > len(data):
        raise MeshFileError(f"{path}: images[{i}]'s bufferView lies outside its buffer")
    return data[start:start + length]


def check_images(path: Path, doc: dict, binary: bytes | None, refs: dict[str, Path]) -> None:
    """Every image decodes within the pixel limit (a file, a data: URI or a buffer view)."""
    for i in range(len(items(path, doc, "images"))):
        bake.check_image(_image_bytes(path, doc, binary, refs, i), f"{path}: images[{i}]")


def _checked(path: Path) -> tuple[dict, dict[str, Path]]:
    """(document, uri -> file) once nodes, references and images have been checked."""
    doc, binary = _document(path)
    check_extensions(path, doc)
    node_matrices(path, doc)
    refs = _referenced(path, doc)
    check_images(path, doc, binary, refs)
    return doc, refs


def checked_references(path: Path) -> dict[str, Path]:
    """uri -> file of every external buffer and image, once the document is checked: what a
    resolver handed to trimesh may serve (:func:`.part.checked_resolver`)."""
    return _checked(path)[1]


def source_files(path: Path) -> list[Path]:
    """The file and every external buffer and image it references, each checked (see the module
    docstring): what ``validate`` reads of a glTF file."""
    return [path, *dict.fromkeys(_checked(path)[1].values())]


def node_matrix(path: Path, node: dict, where: str) -> np.ndarray:
    """A node's local transform (glTF's frame), its numbers checked."""
    if "matrix" in node:
        return numbers(path, node["matrix"], 16, f"{where}.matrix").reshape(4, 4).T  # column-major
    T = np.eye(4)
    x, y, z, w = numbers(path, node.get("rotation", [0.0, 0.0, 0.0, 1.0]), 4, f"{where}.rotation")
    T[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    T[:3, :3] *= numbers(path, node.get("scale", [1.0, 1.0, 1.0]), 3, f"{where}.scale")[None, :]
    T[:3, 3] = numbers(path, node.get("translation", [0.0, 0.0, 0.0]), 3, f"{where}.translation")
    return T


def _node_name(nodes: list[dict], i: int) -> str:
    name = nodes[i].get("name")
    return f"nodes[{i}]" + (f" {name!r}" if isinstance(name, str) and len(name) <= 64 else "")


def _roots(path: Path, doc: dict, nodes: list[dict]) -> list[int]:
    scenes = items(path, doc, "scenes")
    if not scenes:
        return list(range(len(nodes)))
    k = index(path, doc.get("scene", 0), len(scenes), "scene")
    roots = scenes[k].get("nodes", [])
    if not isinstance(roots, list):
        raise MeshFileError(f"{path}: scenes[{k}].nodes must be an array")
    return [index(path, r, len(nodes), f"scenes[{k}].nodes") for r in roots]


def node_matrices(path: Path, doc: dict) -> dict[int, np.ndarray]:
    """World matrix (our +Z-up frame) of every node the scene reaches. Refused, naming the node:
    a child that is its own ancestor or has two parents, a transform that is not finite numbers,
    one that flattens a mesh to nothing, and geometry beyond MAX_COORDINATE metres."""
    nodes = items(path, doc, "nodes")
    up = np.eye(4)
    up[:3, :3] = Y_UP_TO_Z_UP
    world: dict[int, np.ndarray] = {}
    stack = [(i, up, f"{path}: scene root") for i in reversed(_roots(path, doc, nodes))]
    while stack:
        i, parent, via = stack.pop()
        if i in world:
            raise MeshFileError(f"{via}: {_node_name(nodes, i)} is reached twice (the node hierarchy has a cycle "
                                "or a node with two parents)")
        where = _node_name(nodes, i)
        world[i] = parent @ node_matrix(path, nodes[i], where)
        _check_placement(path, doc, nodes[i], world[i], where)
        children = nodes[i].get("children", [])
        if not isinstance(children, list):
            raise MeshFileError(f"{path}: {where}.children must be an array")
        stack += [(index(path, c, len(nodes), f"{where}.children"), world[i], f"{path}: {where}")
                  for c in reversed(children)]
    return world


def _check_placement(path: Path, doc: dict, node: dict, world: np.ndarray, where: str) -> None:
    if "mesh" not in node:
        return
    scale = np.linalg.norm(world[:3, :3], axis=0)
    if scale.min() < MIN_SCALE or abs(np.linalg.det(world[:3, :3])) < MIN_SCALE ** 3:
        raise MeshFileError(f"{path}: {where}: its transform flattens its mesh (a scale of {scale.min():.3g} on "
                            "some axis); remove the node or give it a scale")
    corners = _mesh_box(path, doc, node)
    pts = corners @ world[:3, :3].T + world[:3, 3]
    far = float(np.abs(pts).max())
    if far > MAX_COORDINATE:
        raise MeshFileError(f"{path}: {where}: places geometry {far:.3g} m from the origin, beyond the "
                            f"{MAX_COORDINATE:,.0f} m a scene may span; check its translation and scale")


def _mesh_box(path: Path, doc: dict, node: dict) -> np.ndarray:
    """Corners of the node's mesh's box, from its POSITION accessors' min/max (no buffer read);
    the origin alone when a sloppy exporter left them out."""
    meshes = items(path, doc, "meshes")
    mesh = meshes[index(path, node["mesh"], len(meshes), "a node's mesh")]
    accessors = items(path, doc, "accessors")
    lo, hi = [], []
    prims = mesh.get("primitives", [])
    for prim in prims if isinstance(prims, list) else []:
        attrs = prim.get("attributes", {}) if isinstance(prim, dict) else {}
        k = attrs.get("POSITION") if isinstance(attrs, dict) else None
        if isinstance(k, int) and 0 <= k < len(accessors) and "min" in accessors[k] and "max" in accessors[k]:
            lo.append(numbers(path, accessors[k]["min"], 3, f"accessors[{k}].min"))
            hi.append(numbers(path, accessors[k]["max"], 3, f"accessors[{k}].max"))
    if not lo:
        return np.zeros((1, 3))
    a, b = np.min(lo, axis=0), np.max(hi, axis=0)
    return np.array([[x, y, z] for x in (a[0], b[0]) for y in (a[1], b[1]) for z in (a[2], b[2])])


def read_parts(path: Path, texture_cache: Path) -> list[Part]:
    import trimesh

    doc, refs = _checked(path)  # before trimesh reads anything; it is then handed only the checked files
    try:
        scene = trimesh.load(str(path), force="scene", process=False, resolver=checked_resolver(path, refs))
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
        check_face_indices(path, len(geom.vertices), geom.faces)
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
