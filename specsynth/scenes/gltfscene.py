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

from ..assets.meshfiles.gltf import gltf_json
from ..assets.meshfiles.part import Y_UP_TO_Z_UP, MeshFileError
from .models import LightDef, SceneFile, SceneMesh, World

LUMENS_PER_WATT = 683.0
DEFAULT_ENVMAP = "interior"


def scene_from_gltf(path: Path) -> SceneFile:
    doc = gltf_json(path)
    lights = [light_def(kind, matrix) for kind, matrix in punctual_lights(doc)]
    world = World(envmap=DEFAULT_ENVMAP) if not lights else World(color=(0.05, 0.05, 0.05))
    name = "".join(c if c.isalnum() or c in "_.-" else "_" for c in path.stem) or "gltf"
    mesh = SceneMesh(name=name, source=path.name)
    return SceneFile(name=name, description=f"glTF scene {path.name}", meshes=[mesh], lights=lights, world=world)


def _node_matrix(node: dict) -> np.ndarray:
    if "matrix" in node:
        return np.asarray(node["matrix"], np.float64).reshape(4, 4).T  # glTF stores column-major
    T = np.eye(4)
    x, y, z, w = node.get("rotation", (0.0, 0.0, 0.0, 1.0))
    T[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]
    T[:3, :3] *= np.asarray(node.get("scale", (1.0, 1.0, 1.0)))[None, :]
    T[:3, 3] = node.get("translation", (0.0, 0.0, 0.0))
    return T


def punctual_lights(doc: dict) -> list[tuple[dict, np.ndarray]]:
    """(light definition, world-from-light matrix in our +Z-up frame) of every light node."""
    defs = doc.get("extensions", {}).get("KHR_lights_punctual", {}).get("lights", [])
    nodes = doc.get("nodes", [])
    scenes = doc.get("scenes", [])
    roots = scenes[doc.get("scene", 0)].get("nodes", []) if scenes else range(len(nodes))
    up = np.eye(4)
    up[:3, :3] = Y_UP_TO_Z_UP
    out = []
    stack = [(int(i), up) for i in reversed(list(roots))]  # depth first, in document order
    seen = 0
    while stack:
        i, parent = stack.pop()
        seen += 1
        if seen > 1_000_000 or not 0 <= i < len(nodes):
            raise MeshFileError("glTF node hierarchy is cyclic or refers to a missing node")
        node = nodes[i]
        world = parent @ _node_matrix(node)
        ref = node.get("extensions", {}).get("KHR_lights_punctual", {}).get("light")
        if ref is not None and 0 <= int(ref) < len(defs):
            out.append((defs[int(ref)], world))
        stack += [(int(c), world) for c in reversed(node.get("children", []))]
    return out


def light_def(light: dict, world: np.ndarray) -> LightDef:
    from scipy.spatial.transform import Rotation

    R = world[:3, :3] / np.linalg.norm(world[:3, :3], axis=0, keepdims=True)  # drop node scale
    rpy = tuple(float(a) for a in Rotation.from_matrix(R).as_euler("xyz", degrees=True))
    colour = tuple(float(min(max(c, 0.0), 1.0)) for c in light.get("color", (1.0, 1.0, 1.0)))
    intensity = max(float(light.get("intensity", 1.0)), 1e-9)
    kind = light.get("type")
    common = dict(color=colour, translation=tuple(float(x) for x in world[:3, 3]), rotation=rpy)
    if kind == "directional":
        return LightDef(kind="sun", power=intensity / LUMENS_PER_WATT, **common)
    watts = intensity * 4 * math.pi / LUMENS_PER_WATT
    if kind == "spot":
        spot = light.get("spot", {})
        outer = float(spot.get("outerConeAngle", math.pi / 4))
        inner = float(spot.get("innerConeAngle", 0.0))
        return LightDef(kind="spot", power=watts, spot_angle=min(math.degrees(2 * outer), 180.0),
                        spot_blend=float(np.clip(1.0 - inner / outer, 0.0, 1.0)) if outer > 0 else 0.0, **common)
    if kind == "point":
        return LightDef(kind="point", power=watts, **common)
    raise MeshFileError(f"KHR_lights_punctual light of unknown type {kind!r}")
