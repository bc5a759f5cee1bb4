"""Scenes as data: scene files (``models.SceneFile``) -> ``SceneDesc`` with normalised meshes and stages.

Built-in scenes are YAML files in ``builtin/`` made only of offline assets (procedural shapes,
pybullet_data meshes and textures, the HDRIs bundled with bpy). A scene file's meshes are converted
once into the normalised cache (``<cache>/assets/<hash>.ply``, metres, scale and unit baked in,
UVs pre-multiplied by the material's ``uv_scale`` so textures tile) and placed by rigid poses.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml
from pydantic import ValidationError

from ..assets import furnish, meshfiles
from ..assets import resolve as assets
from ..assets.library import furniture, textures
from ..assets.meshfiles import primitives as procedural
from ..assets.meshfiles.part import MeshFileError
from ..assets.meshfiles.sniff import check_mesh_file
from ..assets.meshio import UV_LIMIT, MeshData, read_mesh
from ..assets.resolve import AssetError
from ..files import not_a_file, read_regular
from ..model.conventions import rpy_matrix
from ..model.ir import LightIR, MaterialIR, MeshInstance, WorldIR, as_tuple
from ..spec.yamlio import shape_problem
from . import autostage, filemeshes, gltfscene, random_room, surfaces
from .models import Box, Cylinder, LightDef, Plane, SceneFile, SceneMaterial, SceneMesh, StageDef, World
from .types import SceneDesc, Stage

BUILTIN_DIR = Path(__file__).parent / "builtin"
FOCUS = "focus"  # in a SceneRef's stages: every stage in the scene's focus areas
MAX_SCENE_FILE_BYTES = 16 << 20  # a scene file lists meshes and lights; past this it is not one
SCENE_VERSION = 2  # 2: glTF/OBJ sources keep every material. Bump when load_scene's output changes for the same file

__all__ = ["SceneError", "builtin_scenes", "declares_stages", "load_scene", "read_scene_file", "scene_fingerprint",
           "stage_table"]


class SceneError(AssetError):
    """An invalid or unloadable scene file; the message names the file (and field, line)."""


# Built-in scenes made by code: one variant per seed (each arrangement draws its own), and the
# fixed furnished rooms (one room each, the same in every arrangement).
PROCEDURAL = ("random_room",)
FIXED_ROOMS = tuple(random_room.FIXED_ROOMS)


def builtin_scenes() -> list[str]:
    return sorted([p.stem for p in BUILTIN_DIR.glob("*.yaml")] + list(PROCEDURAL) + list(FIXED_ROOMS))


def _ref_name(ref) -> str | None:
    return getattr(ref, "name", None) if not isinstance(ref, str) else ref


def procedural_name(ref) -> str | None:
    """The name of a scene that is a new room per arrangement (``random_room``), else None."""
    name = _ref_name(ref)
    return name if name in PROCEDURAL else None


def generated_name(ref) -> str | None:
    """The name of any scene made by code (procedural or a fixed furnished room), else None."""
    name = _ref_name(ref)
    return name if name in PROCEDURAL or name in FIXED_ROOMS else None


def room_params(ref) -> random_room.RoomParams:
    """``random_room``'s parameters from a SceneRef's ``room:`` block (defaults without one)."""
    opts = getattr(ref, "room", None)
    density = float(getattr(ref, "clutter", 1.0))
    if opts is None:
        return random_room.RoomParams(density=density)
    d0, d1 = opts.density
    return random_room.RoomParams(density=density,
        kinds=tuple(opts.kinds), width=tuple(opts.width), depth=tuple(opts.depth), height=tuple(opts.height),
        wall_pieces=(round(6 * d0), max(round(6 * d0), round(10 * d1))),
        middle_pieces=(round(1 * d0), max(round(1 * d0), round(2 * d1))),
        categories=tuple(opts.categories) if opts.categories else None, clutter=tuple(opts.clutter),
        pictures=tuple(opts.pictures), boards=float(opts.boards), islands=float(opts.islands))


def _scene_path(ref, spec_dir: Path) -> Path:
    """SceneRef or str -> scene file. A str is a built-in name unless it looks like a file."""
    name = getattr(ref, "name", None)
    file = getattr(ref, "file", None)
    if name is None and file is None:
        s = str(ref)
        if s.endswith((".yaml", ".yml", ".json", ".glb", ".gltf")) or "/" in s or "\\" in s:
            file = s
        else:
            name = s
    if name is not None:
        p = BUILTIN_DIR / f"{name}.yaml"
        if not p.is_file():
            raise SceneError(f"scene {name!r}: unknown built-in scene; built-in scenes are {', '.join(builtin_scenes())}")
        return p
    p = assets.expand_path(file, Path(spec_dir), f"scene file {file!r}")
    problem = not_a_file(p)
    if problem is not None:
        raise SceneError(f"scene file {file!r}: {problem} ({p})")
    return p


# --------------------------------------------------------------------------- reading + validation


def _error_place(e: Exception) -> str:
    mark = getattr(e, "problem_mark", None)
    if mark is not None:
        return f":{mark.line + 1}:{mark.column + 1}"
    if isinstance(e, json.JSONDecodeError):
        return f":{e.lineno}:{e.colno}"
    return ""


def _error_reason(e: Exception) -> str:
    """The parser's reason without the excerpt of the file it quotes (errors never echo contents)."""
    if isinstance(e, json.JSONDecodeError):
        return e.msg
    return str(getattr(e, "problem", None) or type(e).__name__)


def _node_at(node, loc) -> yaml.Node | None:
    """Follow a pydantic error location through a composed YAML tree (for line numbers)."""
    for key in loc:
        if isinstance(node, yaml.MappingNode):
            nxt = next((v for k, v in node.value if k.value == str(key)), None)
        elif isinstance(node, yaml.SequenceNode) and isinstance(key, int) and key < len(node.value):
            nxt = node.value[key]
        else:
            nxt = None
        if nxt is None:
            return node
        node = nxt
    return node


def read_scene_file(path: Path) -> SceneFile:
    path = Path(path)
    if path.suffix.lower() in (".glb", ".gltf"):
        try:
            return gltfscene.scene_from_gltf(path)
        except meshfiles.MeshFileError as e:
            raise SceneError(str(e) if str(e).startswith(str(path)) else f"{path}: {e}") from None
    try:
        text = read_regular(path, MAX_SCENE_FILE_BYTES).decode("utf-8")
    except UnicodeDecodeError:
        raise SceneError(f"{path}: not a text file; a scene is YAML, JSON, or a glTF/GLB file") from None
    except OSError as e:
        raise SceneError(f"{path}: cannot read ({e.strerror or type(e).__name__})") from None
    try:
        shape = None if path.suffix == ".json" else shape_problem(text)
        data = None if shape else json.loads(text) if path.suffix == ".json" else yaml.safe_load(text)
    except (yaml.YAMLError, json.JSONDecodeError) as e:
        raise SceneError(f"{path}{_error_place(e)}: cannot parse ({_error_reason(e)})") from None
    except (RecursionError, ValueError):  # JSON nested past the parser's depth, an integer past Python's digits
        raise SceneError(f"{path}: cannot parse (nested too deeply, or a number too long)") from None
    if shape:
        raise SceneError(f"{path}:{shape[0]}:{shape[1]}: {shape[2]}")
    if not isinstance(data, dict):
        raise SceneError(f"{path}: a scene file is a mapping (name, meshes, lights, world, stages)")
    if not set(map(str, data)) & set(SceneFile.model_fields):  # some other file: its keys are not quoted back
        raise SceneError(f"{path}: not a scene file: none of its top-level keys is a scene field (name, meshes, "
                         "lights, world, stages); its contents are not shown")
    try:
        return SceneFile.model_validate(data)
    except ValidationError as e:
        root = None
        if path.suffix != ".json":
            try:
                root = yaml.compose(text)
            except yaml.YAMLError:
                root = None
        lines = []
        errors = e.errors()
        # `stages: [...] | auto`: a list with a bad stage also fails the 'auto' branch; that says nothing
        literal = [err for err in errors if any(isinstance(x, str) and x.startswith("literal[") for x in err["loc"])]
        if any(err not in literal and any(isinstance(x, int) for x in err["loc"]) for err in errors):
            errors = [err for err in errors if err not in literal]
        for err in errors:
            # Union members add their class name to the location; drop those for readability.
            loc = [x for x in err["loc"] if not (isinstance(x, str) and (x[:1].isupper() or x.startswith(("list[", "literal["))))]
            if "source" in loc:  # drop the discriminator tag: it repeats the key the user wrote
                i = loc.index("source")
                if i + 1 < len(loc) and loc[i + 1] in ("box", "plane", "cylinder", "tube", "file"):
                    loc = loc[: i + 1] + loc[i + 2 :] if loc[i + 1] == "file" or loc[i + 2 : i + 3] == [loc[i + 1]] or i + 2 == len(loc) else loc
            where = ".".join(str(x) for x in loc) or "(top)"
            pos = ""
            node = _node_at(root, loc) if root is not None else None
            if node is not None:
                pos = f":{node.start_mark.line + 1}:{node.start_mark.column + 1}"
            lines.append(f"{path}{pos}: {where}: {err['msg']}")
        raise SceneError("\n".join(dict.fromkeys(lines))) from None


# --------------------------------------------------------------------------- geometry


def _source_kind(m: SceneMesh) -> str:
    return type(m.source).__name__.lower() if not isinstance(m.source, str) else "file"


def _rotation(rot) -> np.ndarray:
    if isinstance(rot[0], (tuple, list)):
        return np.asarray(rot, dtype=np.float64)
    return rpy_matrix(*(math.radians(a) for a in rot))


def _scale3(s) -> np.ndarray:
    return np.full(3, float(s)) if isinstance(s, (int, float)) else np.asarray(s, np.float64)


def _uv2(s) -> np.ndarray:
    return np.full(2, float(s)) if isinstance(s, (int, float)) else np.asarray(s, np.float64)


def _source_files(m: SceneMesh, scene_path: Path) -> tuple[Path | None, list[Path], Path | None]:
    """(source file, every file it reads, its own texture) of a file-based mesh. A library model's
    bytes are those of its archive (fingerprinting never unpacks anything)."""
    if _source_kind(m) == "furniture":
        item = furniture.find(m.source.furniture)
        return None, [furniture.library_dir() / f"{item.archive}.sh3f"], None
    if _source_kind(m) != "file":
        return None, [], None
    what = f"{scene_path}: meshes.{m.name}.source"
    p = assets.resolve_data_ref(m.source, scene_path.parent, what)
    if p.is_file():
        try:
            check_mesh_file(p, what)
        except MeshFileError as e:
            raise AssetError(str(e)) from None
    if p.suffix.lower() == ".urdf":
        files, tex = [p], None
        for vis in assets.parse_urdf(p):
            if vis.mesh is not None:
                files += assets._mesh_and_material_files(vis.mesh, what)
                if tex is None and vis.mesh.suffix.lower() == ".obj":
                    tex = assets._mtl_texture(vis.mesh)[0]
        return p, files, tex
    if filemeshes.is_multi_material(p):
        if not p.is_file():
            raise AssetError(f"{what}: mesh file not found: {p}")
        return p, meshfiles.source_files(p), None
    files = assets._mesh_and_material_files(p, what)
    tex = assets._mtl_texture(p)[0] if p.suffix.lower() == ".obj" else None
    return p, files, tex


def _build_geometry(m: SceneMesh, src: Path | None, what: str) -> MeshData:
    """Mesh in its own frame, metres, scale baked in, UVs multiplied by uv_scale."""
    kind = _source_kind(m)
    if kind == "box":
        mesh = procedural.box(m.source.box)
    elif kind == "plane":
        mesh = procedural.plane(m.source.plane)
    elif kind == "cylinder":
        mesh = procedural.cylinder(m.source.cylinder.radius, m.source.cylinder.height)
    elif kind == "tube":
        mesh = procedural.tube(m.source.tube.points, m.source.tube.radius)
    elif src.suffix.lower() == ".urdf":
        parts = []
        for vis in assets.parse_urdf(src):
            if vis.mesh is not None:
                part = assets.finish_mesh(assets.read_any_mesh(vis.mesh)[0], what)
            else:
                part = assets._primitive_mesh(vis.primitive)
            parts.append(procedural.transform_mesh(part, vis.matrix @ np.diag([*vis.scale, 1.0])))
        if len({p.uv is None for p in parts}) > 1:
            parts = [replace(p, uv=None) for p in parts]
        mesh = procedural.concatenate([replace(p, colors=None) for p in parts])
    else:
        mesh = assets.finish_mesh(assets.read_any_mesh(src)[0], what)
    return _finish_geometry(m, mesh, what)


def _finish_geometry(m: SceneMesh, mesh: MeshData, what: str) -> MeshData:
    """Unit and scale baked in, UVs multiplied by uv_scale, validated."""
    if len(mesh.faces) > meshfiles.MAX_TRIANGLES:
        raise SceneError(f"{what}: {len(mesh.faces):,} triangles, over the {meshfiles.MAX_TRIANGLES:,} limit; decimate it first")
    if _source_kind(m) == "file":
        mesh = procedural.transform_mesh(mesh, np.diag([assets.UNIT_SCALE[m.unit]] * 3 + [1.0]))
    scale = _scale3(m.transform.scale)
    if not np.allclose(scale, 1.0):
        mesh = procedural.transform_mesh(mesh, np.diag([*scale, 1.0]))
    uv_scale = _uv2(m.material.uv_scale)
    if mesh.uv is not None and not np.allclose(uv_scale, 1.0):
        _check_uv_scale(mesh.uv, uv_scale, what)
        mesh = replace(mesh, uv=(mesh.uv.astype(np.float64) * uv_scale).astype(np.float32))
    return assets.finish_mesh(mesh, what)


def _check_uv_scale(uv: np.ndarray, uv_scale, what: str) -> None:
    """A ``uv_scale`` that carries valid texture coordinates beyond ``UV_LIMIT`` repeats is the
    user's mistake, not a broken file: said here, rather than repaired to a flat colour later."""
    valid = np.isfinite(uv).all(axis=1) & (np.abs(uv) <= UV_LIMIT).all(axis=1)
    if valid.any():
        reach = float(np.abs(uv[valid].astype(np.float64) * uv_scale).max())
        if reach > UV_LIMIT:
            raise SceneError(f"{what}.material.uv_scale: {_fmt_uv(uv_scale)} puts texture coordinates at {reach:.3g} "
                             f"repeats, beyond {UV_LIMIT:g} (float32 keeps no position within a texel there); lower it")


def _fmt_uv(s) -> str:
    return f"{s[0]:g}" if s[0] == s[1] else f"[{s[0]:g}, {s[1]:g}]"


def _mesh_cache_key(m: SceneMesh, files: list[Path], what: str) -> str:
    return assets._hash_json({
        "v": [assets.CONVERSION_VERSION, SCENE_VERSION, filemeshes.PARTS_VERSION],
        "source": m.source if isinstance(m.source, str) else m.source.model_dump(),
        "unit": m.unit,
        "scale": list(_scale3(m.transform.scale)),
        "uv_scale": list(_uv2(m.material.uv_scale)),
        "files": [assets.file_digest(f, what) for f in files],
    })


def _material(m: SceneMesh, own_texture: Path | None, scene_path: Path, what: str) -> MaterialIR:
    return _material_ir(m.material, own_texture, scene_path, what)


def _material_ir(mat: SceneMaterial, own_texture: Path | None, scene_path: Path, what: str) -> MaterialIR:
    tex = None
    if mat.texture is not None:
        tex = assets.resolve_data_ref(mat.texture, scene_path.parent, f"{what}.material.texture")
        assets.check_texture(tex, f"{what}.material.texture")
    elif mat.base_color is None and own_texture is not None:
        tex = own_texture
    base = mat.base_color if mat.base_color is not None else ((1.0, 1.0, 1.0) if tex is not None else (0.8, 0.8, 0.8))
    normal = rough = glow = None
    if mat.emission_texture is not None:
        glow = assets.resolve_data_ref(mat.emission_texture, scene_path.parent, f"{what}.material.emission_texture")
        assets.check_texture(glow, f"{what}.material.emission_texture")
    textures_cache = assets.cache_dir() / "assets" / "textures"
    if mat.normal_map is not None:
        src = surfaces.resolve_normal_map(mat.normal_map, scene_path.parent, f"{what}.material.normal_map")
        normal = surfaces.normal_texture(src, mat.normal_strength, textures_cache)
    if mat.roughness_variation and (normal is not None or tex is not None):
        src = Path(normal) if normal is not None else tex
        rough = surfaces.roughness_texture(src, mat.roughness, mat.roughness_variation, textures_cache)
    return MaterialIR(
        base_color=tuple(base), use_vertex_colors=False, texture=None if tex is None else str(tex),
        roughness=mat.roughness, metallic=mat.metallic, specular=mat.specular, emission=tuple(mat.emission),
        normal_texture=normal, roughness_texture=rough, emission_texture=None if glow is None else str(glow),
    )


def _light(ld: LightDef) -> LightIR:
    T = np.eye(4)
    T[:3, 3] = ld.translation
    if ld.look_at is not None:
        z = np.asarray(ld.translation, float) - np.asarray(ld.look_at, float)  # lights emit along -Z
        z /= np.linalg.norm(z)
        up = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.999 else np.array([1.0, 0.0, 0.0])
        x = np.cross(up, z)
        x /= np.linalg.norm(x)
        T[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    else:
        T[:3, :3] = _rotation(ld.rotation)
    return LightIR(
        kind=ld.kind, pose=as_tuple(T), color=tuple(ld.color), power=float(ld.power), size=tuple(ld.size),
        spot_angle=ld.spot_angle, spot_blend=ld.spot_blend, sun_angle=ld.sun_angle,
    )


def _envmap_path(world: World, scene_path: Path) -> Path | None:
    if world.envmap is None:
        return None
    if world.envmap in assets.builtin_hdris():
        return assets.hdri_path(world.envmap)
    if world.envmap.endswith((".exr", ".hdr")) or "/" in world.envmap:
        return assets.resolve_data_ref(world.envmap, scene_path.parent, f"{scene_path}: world.envmap")
    return None  # a built-in name without bpy installed: see _world


def _world(world: World, scene_path: Path) -> WorldIR:
    if world.sky is not None:
        # Scene files measure the azimuth from +X (like every other angle in them), the IR from +Y.
        return WorldIR(kind="sky", strength=world.strength, rotation_z=world.rotation,
                       sun_elevation=world.sky.sun_elevation, sun_azimuth=world.sky.sun_azimuth - 90.0,
                       turbidity=world.sky.turbidity)
    if world.envmap is not None:
        p = _envmap_path(world, scene_path)
        if p is None:
            # Built-in HDRIs ship with the optional bpy wheel; without it a scene still loads
            # (rasterising backends never read envmaps) with a neutral grey world instead.
            warnings.warn(f"{scene_path}: world.envmap {world.envmap!r} is not available (install bpy for the "
                          "built-in HDRIs); using a grey world", stacklevel=3)
            return WorldIR(kind="color", color=(0.3, 0.3, 0.3), strength=world.strength)
        return WorldIR(kind="envmap", envmap=str(p), strength=world.strength, rotation_z=world.rotation)
    return WorldIR(kind="color", color=tuple(world.color), strength=world.strength)


def _stage(sd) -> Stage:
    poly = [tuple(map(float, p)) for p in sd.polygon]
    area2 = sum(x0 * y1 - x1 * y0 for (x0, y0), (x1, y1) in zip(poly, poly[1:] + poly[:1]))
    if area2 < 0:
        poly = poly[::-1]
    return Stage(name=sd.name, polygon=tuple(poly), height=float(sd.height))


def load_scene(ref, spec_dir: Path, cache: Path | None = None, clearance: float | None = None,
               variant: int | None = None) -> SceneDesc:
    """Resolve a scene (built-in name, SceneRef, or file) into a ``SceneDesc``; meshes cached.
    ``variant`` is the seed of a procedural scene (``random_room``): one room per seed.

    ``clearance`` (metres of free space a stage needs above it: the spec's largest drop height plus
    its largest object) only matters to a scene whose stages are found automatically."""
    cache = Path(cache) if cache is not None else assets.cache_dir()
    credits: list[dict] = []
    if generated_name(ref):
        name = generated_name(ref)
        path = Path(random_room.__file__)
        try:
            if name in FIXED_ROOMS:
                sf, credits = random_room.fixed_room(name, cache, density=float(getattr(ref, "clutter", 1.0)))
            else:
                sf, credits = random_room.random_room(int(variant or 0), cache, params=room_params(ref))
        except (furniture.LibraryError, textures.TextureLibraryError) as e:
            raise SceneError(f"scene {name!r}: {e}") from None
    else:
        path = _scene_path(ref, spec_dir)
        sf = read_scene_file(path)
    credits += surfaces.library_credits(sf.meshes)
    meshes, colliders = [], []
    for m in sf.meshes:
        what = f"{path}: meshes.{m.name}"
        try:
            parts = _load_mesh(m, path, cache, what)
        except SceneError:
            raise
        except (AssetError, meshfiles.MeshFileError, furniture.LibraryError) as e:
            raise SceneError(str(e) if str(e).startswith(str(path)) else f"{what}: {e}") from e
        T = np.eye(4)
        T[:3, :3] = _rotation(m.transform.rotation)
        T[:3, 3] = m.transform.translation
        if _source_kind(m) == "furniture":
            credits.append(furniture.find(m.source.furniture).credit)
        for name, ply, mesh_key, material in parts:
            meshes.append(MeshInstance(name=name, mesh_path=str(ply), mesh_key=mesh_key, pose=as_tuple(T),
                                       material=material))
            if m.collide:
                colliders.append(name)
    if sf.auto_stages:
        stages = _auto_stages(path, meshes, colliders, clearance, _focus_windows(ref, sf))
    else:
        stages = {s.name: _stage(s) for s in sf.stages}
    stages = _focus_weights(stages, sf)
    wanted = getattr(ref, "stages", None)
    if wanted:
        focus = [n for n, st in stages.items() if st.focus]
        if FOCUS in wanted and not focus and generated_name(ref):
            focus = list(stages)  # a generated room without a work surface: all its stages
        if FOCUS in wanted and not focus:
            raise SceneError(f"{path}: stages: {FOCUS!r} names the stages in the scene's focus areas, and it has none")
        wanted = list(dict.fromkeys(n for w in wanted for n in (focus if w == FOCUS else [w])))
        unknown = [s for s in wanted if s not in stages]
        if unknown:
            raise SceneError(f"{path}: unknown stage(s) {unknown}; the scene has {', '.join(stages)}")
        stages = {s: stages[s] for s in wanted}
    return SceneDesc(
        name=sf.name,
        meshes=tuple(meshes),
        lights=tuple(_light(ld) for ld in sf.lights),
        world=_world(sf.world, path),
        stages=stages,
        colliders=None if len(colliders) == len(meshes) else tuple(colliders),
        credits=tuple({c["asset"]: c for c in credits}.values()),
    )


def _load_mesh(m: SceneMesh, path: Path, cache: Path, what: str) -> list[tuple[str, Path, str, MaterialIR]]:
    """(instance name, normalised PLY, mesh_key, material) of each part of one scene mesh: one
    part, or one per material of a glTF/OBJ file (named ``<mesh>/<material>``)."""
    src, files, own_tex = _source_files(m, path)
    key = _mesh_cache_key(m, files, what)
    prepare = None
    if _source_kind(m) == "furniture":
        item = furniture.find(m.source.furniture)
        src = furniture.extract(item, cache)
        prepare = functools.partial(furnish.normalise_parts, item=item)
    if not filemeshes.is_multi_material(src):
        if m.materials:
            raise SceneError(f"{what}.materials: only glTF and OBJ files have named materials")
        ply = cache / "assets" / f"{key}.ply"
        if ply.is_file():
            mesh_key = assets.file_digest(ply)
        else:
            ply, mesh_key = assets.store_mesh(_build_geometry(m, src, what), key, cache)
        return [(m.name, ply, mesh_key, _material(m, own_tex, path, what))]
    parts = filemeshes.convert_parts(m, src, key, cache, lambda mesh: _finish_geometry(m, mesh, what), prepare)
    unknown = sorted(set(m.materials) - {p[1] for p in parts})
    if unknown:
        have = ", ".join(sorted({p[1] for p in parts}))
        raise SceneError(f"{what}.materials: {', '.join(map(repr, unknown))} not in {src.name} (it has: {have})")

    def yaml_material(mat: SceneMaterial, own: Path | None) -> MaterialIR:
        return _material_ir(mat, own, path, what)

    return [(f"{m.name}/{name}", ply, mesh_key, filemeshes.part_material(m, mat, mname, yaml_material, has_uv))
            for name, mname, ply, mesh_key, mat, has_uv in parts]


def _focus_weights(stages: dict[str, Stage], sf: SceneFile) -> dict[str, Stage]:
    """Stages in the scene's focus areas share ``focus_share`` of the draws, the others the rest."""
    if not sf.focus:
        return stages
    areas = [(_stage(StageDef(name="focus", polygon=a.polygon, height=a.height)), a.height) for a in sf.focus]
    focus = {n for n, st in stages.items()
             if any(area.contains(st.centroid) and abs(st.height - h) <= 0.03 for area, h in areas)}
    if not focus or len(focus) == len(stages):
        return stages
    w_focus = sf.focus_share / len(focus)
    w_other = (1.0 - sf.focus_share) / (len(stages) - len(focus))
    return {n: replace(st, weight=w_focus if n in focus else w_other, focus=n in focus) for n, st in stages.items()}


def _focus_windows(ref, sf: SceneFile) -> list[tuple[float, float, float, float]] | None:
    """The focus areas' XY boxes when a reference wants only its focus stages (then no stage
    outside them is ever used, and the search stays inside them), else None: the whole scene."""
    if getattr(ref, "stages", None) != [FOCUS] or not sf.focus:
        return None
    boxes = []
    for area in sf.focus:
        xs, ys = [p[0] for p in area.polygon], [p[1] for p in area.polygon]
        boxes.append((min(xs), min(ys), max(xs), max(ys)))
    return boxes


def _meets(vertices: np.ndarray, window: tuple[float, float, float, float]) -> bool:
    """Whether the XY bounding box of ``vertices`` meets ``window`` (x0, y0, x1, y1)."""
    lo, hi = vertices[:, :2].min(0), vertices[:, :2].max(0)
    return bool(hi[0] >= window[0] and lo[0] <= window[2] and hi[1] >= window[1] and lo[1] <= window[3])


def _auto_stages(path: Path, meshes: list[MeshInstance], colliders: list[str], clearance: float | None,
                 windows: list[tuple[float, float, float, float]] | None = None) -> dict[str, Stage]:
    solid = set(colliders)
    world = []  # (vertices, faces) of each collider in world coordinates
    for m in meshes:
        if m.name in solid:
            data = read_mesh(m.mesh_path)
            T = m.matrix
            world.append((data.vertices.astype(np.float64) @ T[:3, :3].T + T[:3, 3], data.faces))
    params = autostage.AutoStageParams() if clearance is None else autostage.AutoStageParams(clearance=clearance)

    def triangles(keep) -> np.ndarray:
        tris = [v[f] for v, f in world if keep(v)]
        return np.concatenate(tris) if tris else np.zeros((0, 3, 3))

    found = []
    if windows is not None:
        near = triangles(lambda v: any(_meets(v, w) for w in windows))
        found = autostage.unique_names([st for w in windows for st in autostage.find_stages(near, params, w)])
    if not found:  # no focus areas, or no room in any: the whole scene's stages
        found = autostage.find_stages(triangles(lambda v: True), params)
    if not found:
        raise SceneError(
            f"{path}: stages: none found automatically (no upward surface of at least "
            f"{params.min_side} x {params.min_side} m with {params.clearance:.2f} m free above it); declare 'stages:'"
        )
    return {s.name: s for s in found}


def declares_stages(ref, spec_dir: Path) -> bool:
    """Whether a scene lists its stages (else they are found in its geometry at load time)."""
    return not generated_name(ref) and not read_scene_file(_scene_path(ref, spec_dir)).auto_stages


def _check_material_names(m: SceneMesh, src: Path | None, scene_path: Path) -> None:
    """In ``validate``, what loading the scene checks against the parts it reads: every name in a
    mesh's ``materials:`` is a material of its file (read here without the geometry)."""
    if not m.materials or src is None or not src.is_file():
        return
    what = f"{scene_path}: meshes.{m.name}"
    if not filemeshes.is_multi_material(src):
        raise SceneError(f"{what}.materials: only glTF and OBJ files have named materials")
    try:
        known = meshfiles.material_names(src)
    except MeshFileError as e:
        raise AssetError(str(e)) from None
    unknown = sorted(set(m.materials) - known)
    if unknown:
        have = ", ".join(sorted(known - {"default"})[:12]) + (", ..." if len(known) > 13 else "")
        raise SceneError(f"{what}.materials: {', '.join(map(repr, unknown))} not in {src.name} (it has: {have})")


def scene_fingerprint(ref, spec_dir: Path) -> str:
    """Content hash of a scene: its file and every file it references (no mesh conversion). A
    procedural scene's: its generator and the asset libraries it draws from."""
    if generated_name(ref):
        from ..assets.library import printed

        h = hashlib.sha256(f"procedural {generated_name(ref)} v{random_room.GENERATOR_VERSION} printed v{printed.VERSION} "
                           f"{assets.CONVERSION_VERSION}.{SCENE_VERSION}.{filemeshes.PARTS_VERSION} "
                           f"stages v{autostage.VERSION}\n".encode())
        for archive in sorted(furniture.library_dir().glob("*.sh3f")):
            h.update(assets.file_digest(archive).encode())
        manifest = textures.folder(assets.cache_dir()) / "manifest.json"
        h.update(manifest.read_bytes() if manifest.is_file() else b"no textures")
        h.update(json.dumps(getattr(ref, "stages", None)).encode())
        room = getattr(ref, "room", None)
        h.update(room.model_dump_json().encode() if room is not None else b"default room")
        h.update(f"clutter {float(getattr(ref, 'clutter', 1.0))!r}".encode())
        h.update(pmndrs_manifest())
        return h.hexdigest()
    path = _scene_path(ref, spec_dir)
    sf = read_scene_file(path)
    files = [path]
    for m in sf.meshes:
        try:
            src, used, _ = _source_files(m, path)
            files += used
            _check_material_names(m, src, path)
            for mat in (m.material, *m.materials.values()):
                for image in (mat.texture, mat.emission_texture):
                    if image is not None:  # an image within the pixel limit, checked from its header
                        files.append(assets.resolve_data_ref(image, path.parent, f"{path}: meshes.{m.name}"))
                        assets.check_texture(files[-1], "material")
                if mat.normal_map is not None:
                    files.append(surfaces.resolve_normal_map(mat.normal_map, path.parent, f"{path}: meshes.{m.name}"))
        except SceneError:
            raise
        except AssetError as e:
            raise SceneError(f"{path}: meshes.{m.name}: {e}") from e
    env = _envmap_path(sf.world, path)
    if env is not None:
        files.append(env)
    h = hashlib.sha256(f"scene v{assets.CONVERSION_VERSION}.{SCENE_VERSION}\n".encode())
    if sf.auto_stages:
        h.update(f"stages v{autostage.VERSION}\n".encode())
    for f in files:
        h.update(assets.file_digest(f).encode())
    # The stage subset is part of what a SceneRef means, so it is part of its key.
    h.update(json.dumps(getattr(ref, "stages", None)).encode())
    return h.hexdigest()


def pmndrs_manifest() -> bytes:
    """The installed normal maps' manifest: what the generated rooms' relief is drawn from."""
    from ..assets.library import pmndrs

    m = pmndrs.folder(assets.cache_dir()) / "manifest.json"
    return m.read_bytes() if m.is_file() else b"no normal maps"


def stage_table(name, spec_dir: Path | None = None) -> list[tuple[Stage, float, float]]:
    """(stage, area m^2, height m) of a scene's stages, from the file alone (no meshes built)."""
    if procedural_name(name):
        return []  # a new room, and new stages, for every arrangement
    if generated_name(name):
        desc = load_scene(name, Path(spec_dir) if spec_dir is not None else Path.cwd())
        return [(st, st.area, st.height) for st in desc.stages.values()]
    path = _scene_path(name, Path(spec_dir) if spec_dir is not None else Path.cwd())
    sf = read_scene_file(path)
    if sf.auto_stages:
        desc = load_scene(name, Path(spec_dir) if spec_dir is not None else Path.cwd())
        return [(st, st.area, st.height) for st in desc.stages.values()]
    return [(st, st.area, st.height) for st in (_stage(s) for s in sf.stages)]
