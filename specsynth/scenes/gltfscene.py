"""A glTF/GLB file given directly as a scene: ``scenes: [{file: room.glb}]``.

The file becomes a scene of one mesh (every material kept, see :mod:`specsynth.assets.meshfiles`) with
stages found automatically. ``KHR_lights_punctual`` lights are imported with the photometric
conversion Blender's glTF importer uses (683 lm/W):

- point and spot: ``intensity`` in candela -> watts = cd x 4 pi / 683 (a spot's watts are those of
  the point light it is cut from, Blender's convention); spot cone = 2 x ``outerConeAngle``,
  blend = 1 - inner / outer;
- directional: ``intensity`` in lux -> sun irradiance W/m^2 = lux / 683.

Without lights the scene is lit by the built-in ``interior`` HDRI (strength 1).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from pydantic import ValidationError

from ..assets.meshfiles.gltf import gltf_json, index, items, node_matrices, numbers
from ..assets.meshfiles.part import MeshFileError
from .models import LightDef, SceneFile, SceneMesh, World

LUMENS_PER_WATT = 683.0
DEFAULT_ENVMAP = "interior"


# A glTF light brighter than this (candela, or lux for a sun) is a broken file, not a lamp: the sun
# at noon gives ~1e5 lux, a stadium floodlight ~1e6 cd.
MAX_INTENSITY = 1e7


def scene_from_gltf(path: Path) -> SceneFile:
    doc = gltf_json(path)
    lights = [light_def(path, light, matrix, where) for light, matrix, where in punctual_lights(path, doc)]
    world = World(envmap=DEFAULT_ENVMAP) if not lights else World(color=(0.05, 0.05, 0.05))
    name = "".join(c if c.isalnum() or c in "_.-" else "_" for c in path.stem) or "gltf"
    mesh = SceneMesh(name=name, source=path.name)
    return SceneFile(name=name, description=f"glTF scene {path.name}", meshes=[mesh], lights=lights, world=world)


def punctual_lights(path: Path, doc: dict) -> list[tuple[dict, np.ndarray, str]]:
    """(light definition, world-from-light matrix in our +Z-up frame, where it is named) of every
    light node, in document order (the node hierarchy checked by :func:`node_matrices`)."""
    ext = doc.get("extensions", {})
    lights = ext.get("KHR_lights_punctual", {}) if isinstance(ext, dict) else {}
    defs = items(path, lights, "lights") if isinstance(lights, dict) else []
    nodes = items(path, doc, "nodes")
    out = []
    for i, world in node_matrices(path, doc).items():  # depth first, in document order
        node_ext = nodes[i].get("extensions", {})
        ref = node_ext.get("KHR_lights_punctual", {}) if isinstance(node_ext, dict) else {}
        if not isinstance(ref, dict) or "light" not in ref:
            continue
        k = index(path, ref["light"], len(defs), f"nodes[{i}].extensions.KHR_lights_punctual.light")
        out.append((defs[k], world, f"KHR_lights_punctual.lights[{k}] (on nodes[{i}])"))
    return out


def _intensity(path: Path, light: dict, where: str) -> float:
    value = light.get("intensity", 1.0)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value <= MAX_INTENSITY:
        raise MeshFileError(f"{path}: {where}: intensity must be a number in [0, {MAX_INTENSITY:g}]")
    return max(float(value), 1e-9)


def light_def(path: Path, light: dict, world: np.ndarray, where: str) -> LightDef:
    from scipy.spatial.transform import Rotation

    R = world[:3, :3] / np.linalg.norm(world[:3, :3], axis=0, keepdims=True)  # drop node scale
    rpy = tuple(float(a) for a in Rotation.from_matrix(R).as_euler("xyz", degrees=True))
    colour = tuple(float(min(max(c, 0.0), 1.0)) for c in numbers(path, light.get("color", [1.0, 1.0, 1.0]), 3,
                                                                   f"{where}.color"))
    intensity = _intensity(path, light, where)
    kind = light.get("type")
    common = dict(color=colour, translation=tuple(float(x) for x in world[:3, 3]), rotation=rpy)
    try:
        if kind == "directional":
            return LightDef(kind="sun", power=intensity / LUMENS_PER_WATT, **common)
        watts = intensity * 4 * math.pi / LUMENS_PER_WATT
        if kind == "spot":
            spot = light.get("spot", {}) if isinstance(light.get("spot", {}), dict) else {}
            outer = _angle(path, spot, "outerConeAngle", math.pi / 4, where)
            inner = _angle(path, spot, "innerConeAngle", 0.0, where)
            return LightDef(kind="spot", power=watts, spot_angle=min(math.degrees(2 * outer), 180.0),
                            spot_blend=float(np.clip(1.0 - inner / outer, 0.0, 1.0)) if outer > 0 else 0.0, **common)
        if kind == "point":
            return LightDef(kind="point", power=watts, **common)
    except ValidationError as e:  # named by field, never by the values the file holds
        fields = ", ".join(sorted({".".join(map(str, err["loc"])) for err in e.errors()}))
        raise MeshFileError(f"{path}: {where}: unusable light ({fields})") from None
    raise MeshFileError(f"{path}: {where}: a light of unknown type (point, spot and directional are known)")


def _angle(path: Path, spot: dict, key: str, default: float, where: str) -> float:
    value = spot.get(key, default)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value <= math.pi / 2:
        raise MeshFileError(f"{path}: {where}: spot.{key} must be an angle in [0, pi/2] radians")
    return float(value)
