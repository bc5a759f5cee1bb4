"""Domain randomisation of any scene, per arrangement: what BlenderProc users script by hand.

A pure function of the scene, the spec's ``randomize`` block, the texture library and a generator
seeded by the arrangement: the same arrangement gets the same variation on every machine, and
nothing here changes geometry, so cameras, poses and annotations do not depend on it.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..model.colour import kelvin_rgb
from ..model.ir import LightIR, MaterialIR, MeshInstance, RenderScene
from ..spec.models import SceneRandomization


def randomize_scene(scene: RenderScene, opts: SceneRandomization, rng: np.random.Generator,
                    library: list, has_uv) -> RenderScene:
    """``scene`` with its surfaces and lights varied; the dataset objects are left as they are.

    ``library``: surface textures (``library.textures.SurfaceTexture``) to swap in;
    ``has_uv(mesh_path) -> bool``: whether a mesh can carry a texture."""
    if not opts.active:
        return scene
    meshes = tuple(m if m.is_object else _surface(m, opts, rng, library, has_uv) for m in scene.meshes)
    lights = tuple(_light(light, opts, rng) for light in scene.lights)
    lo, hi = opts.environment_strength
    world = replace(scene.world, strength=scene.world.strength * float(rng.uniform(lo, hi)))
    return RenderScene(meshes=meshes, lights=lights, world=world)


def _surface(m: MeshInstance, opts: SceneRandomization, rng, library: list, has_uv) -> MeshInstance:
    mat = m.material
    # Draw every number whether or not it is used, so one surface's choice never shifts the next's.
    swap, pick, scale = rng.random(), int(rng.integers(max(1, len(library)))), float(rng.uniform(0.5, 2.0))
    dr, ds = rng.uniform(-1.0, 1.0, size=2) * opts.roughness
    if library and swap < opts.materials and _swappable(mat) and has_uv(m.mesh_path):
        tex = library[pick]
        s = scale / tex.tile  # repeats per metre of UV (scene UVs are in metres)
        mat = MaterialIR(base_color=(1.0, 1.0, 1.0), use_vertex_colors=False, texture=str(tex.path),
                         roughness=mat.roughness, specular=mat.specular, uv_transform=(s, 0.0, 0.0, 0.0, s, 0.0))
    if opts.roughness:
        mat = replace(mat, roughness=float(np.clip(mat.roughness + dr, 0.0, 1.0)),
                      specular=float(np.clip(mat.specular + ds, 0.0, 1.0)))
    return replace(m, material=mat)


def _swappable(mat: MaterialIR) -> bool:
    """A surface whose look a texture may replace: not a light (a screen or a lamp's panel would go
    dark and the room with it), not cut out by its opacity (a leaf would become its whole quad), not
    glass (it would turn opaque)."""
    return (not any(mat.emission) and mat.emission_texture is None and mat.alpha_mode == "opaque"
            and mat.opacity >= 1.0 and mat.transmission == 0.0)


def _light(light: LightIR, opts: SceneRandomization, rng) -> LightIR:
    kelvin = float(rng.uniform(*opts.light_temperature)) if opts.light_temperature else None
    factor = float(rng.uniform(*opts.light_strength))
    offset = rng.uniform(-1.0, 1.0, size=3) * opts.light_position
    pose = np.array(light.pose, dtype=np.float64)
    pose[:3, 3] += offset
    colour = kelvin_rgb(kelvin) if kelvin is not None else light.color
    return replace(light, color=colour, power=light.power * factor,
                   pose=tuple(tuple(float(x) for x in row) for row in pose))
