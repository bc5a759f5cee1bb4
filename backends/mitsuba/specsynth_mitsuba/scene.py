"""RenderScene -> the dict ``mi.load_dict`` takes (meshes built from numpy arrays).

Everything here receives the ``mitsuba`` module as an argument: the variant is chosen by the
backend instance, and importing Mitsuba at module level would set it for the whole process.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Callable

import numpy as np

from specsynth.assets.meshio import MeshData
from specsynth.model.colour import srgb_to_linear
from specsynth.model.ir import IDENTITY_UV, LightIR, MaterialIR, MeshInstance, RenderScene, WorldIR

from . import mapping
from .textures import PRODUCT

VERTEX_COLOR = "vertex_color"  # the mesh attribute the base colour is read from


def _matrix(mi, T: np.ndarray):
    return mi.ScalarTransform4f(np.asarray(T, dtype=np.float64).tolist())


_FLIP_V = np.array([[1.0, 0.0, 0.0], [0.0, -1.0, 1.0], [0.0, 0.0, 1.0]])  # IR v-up <-> Mitsuba rows down


def _sampling(mi, material: MaterialIR, nearest: bool = False) -> dict:
    """How a bitmap is read: the material's UV transform (in Mitsuba's flipped v), wrap, filter."""
    out = {"wrap_mode": material.wrap}
    if nearest:
        out["filter_type"] = "nearest"
    if tuple(material.uv_transform) != IDENTITY_UV:
        M = np.vstack([np.asarray(material.uv_transform, np.float64).reshape(2, 3), [0.0, 0.0, 1.0]])
        out["to_uv"] = mi.ScalarTransform3f((_FLIP_V @ M @ _FLIP_V).tolist())
    return out


# Every 8-bit code's linear value, exactly as srgb_to_linear(code / 255) computes it: a table
# lookup instead of a power per texel (a third of a room's load was this decoding).
_SRGB8_TO_LINEAR = srgb_to_linear(np.arange(256, dtype=np.float32) / np.float32(255.0))


def _linear_rgb(mi, path: str) -> np.ndarray:
    """A colour texture's pixels as linear float RGB (8/16-bit images are sRGB-encoded by convention)."""
    bmp = _read_bitmap(mi, str(path))
    fmt = bmp.component_format()
    arr = np.asarray(bmp, dtype=np.uint8 if fmt == mi.Struct.Type.UInt8 else np.float32)
    if arr.ndim == 2:
        arr = arr[..., None]
    arr = arr[..., :3] if arr.shape[-1] >= 3 else np.repeat(arr[..., :1], 3, axis=-1)
    if fmt == mi.Struct.Type.UInt8:
        return _SRGB8_TO_LINEAR[arr]
    if fmt == mi.Struct.Type.UInt16:
        return srgb_to_linear(arr / 65535.0)
    return arr


class DecodedTextures:
    """Colour textures' linear pixels by path, for one scene and the next: the parts of a scene
    that share a texture (a room's walls) decode it once, and the next arrangement's scene reuses
    what it shares with the last (a library's floors and walls recur from room to room). Nothing
    older is kept, so memory holds at most two scenes' textures. Texture files are named by
    content, so a path always holds the same pixels."""

    def __init__(self) -> None:
        self._last: dict[str, np.ndarray] = {}
        self._now: dict[str, np.ndarray] = {}

    def next_scene(self) -> None:
        self._last, self._now = self._now, {}

    def linear(self, mi, path: str) -> np.ndarray:
        if path not in self._now:
            self._now[path] = self._last[path] if path in self._last else _linear_rgb(mi, path)
        return self._now[path]


def _texture_scaled(mi, path: str, scale, material: MaterialIR, decoded: DecodedTextures | None = None) -> dict:
    """An sRGB colour texture times a constant colour, in linear floats.

    Mitsuba has no 'multiply' texture for constants, so the factor is baked into the pixels once
    per arrangement (cheap next to the render), which keeps the shading exactly factor * texture.
    """
    decoded = DecodedTextures() if decoded is None else decoded
    arr = np.ascontiguousarray(decoded.linear(mi, path) * np.asarray(scale, dtype=np.float32))
    return {"type": "bitmap", "bitmap": mi.Bitmap(arr), "raw": True, **_sampling(mi, material)}


def _texture_base(mi, material: MaterialIR, decoded: DecodedTextures | None = None) -> dict:
    """Base-colour texture premultiplied by base_color."""
    return _texture_scaled(mi, material.texture, material.base_color, material, decoded)


def _grey_map(mi, path: str, material: MaterialIR, nearest: bool = False) -> dict:
    """A linear map read as is (roughness, metallic, coverage, normals)."""
    return {"type": "bitmap", "filename": str(path), "raw": True, **_sampling(mi, material, nearest)}


def emitter_dict(mi, material: MaterialIR, decoded: DecodedTextures | None = None) -> dict:
    if material.emission_texture:
        return {"type": "area", "radiance": _texture_scaled(mi, material.emission_texture, material.emission, material,
                                                            decoded)}
    return {"type": "area", "radiance": {"type": "rgb", "value": list(material.emission)}}


def _read_bitmap(mi, path: str):
    """``mi.Bitmap(path)``. Mitsuba 3.9's OpenEXR reader deadlocks when Dr.Jit's pool has a single
    thread (``dr.set_thread_count(1)``, i.e. the backend with ``threads=1``): read with two."""
    import drjit as dr

    n = dr.thread_count()
    if n >= 2:
        return mi.Bitmap(path)
    dr.set_thread_count(2)
    try:
        return mi.Bitmap(path)
    finally:
        dr.set_thread_count(n)


def uses_principled(material: MaterialIR) -> bool:
    return not (material.specular == 0 and material.metallic == 0 and material.transmission == 0)


def mitsuba_material(material: MaterialIR, calibrate: bool = True) -> MaterialIR:
    """The material as Mitsuba's BSDFs should see it: a dielectric ``principled`` (metallic 0, no
    transmission) gets the base-colour factor and ``specular`` that match Blender's albedo
    (mapping.principled_calibration). Metals, transmission and Lambertian materials are as given."""
    if not calibrate or material.specular == 0 or material.metallic != 0 or material.transmission != 0:
        return material
    k, spec = mapping.principled_calibration(material.roughness, material.specular)
    return dataclasses.replace(material, base_color=tuple(float(c) * k for c in material.base_color), specular=spec)


def bsdf_dict(mi, material: MaterialIR, vertex_colored: bool, decoded: DecodedTextures | None = None) -> dict:
    """Base colour = base_color x vertex colour x texture, as in the Cycles backend; base_color is
    baked into whichever of the other two is present. ``material`` is what ``mitsuba_material``
    returns (build_mesh premultiplies vertex colours by its base_color too)."""
    if material.texture is not None and vertex_colored:
        tex = _texture_base(mi, dataclasses.replace(material, base_color=(1.0, 1.0, 1.0)), decoded)
        base = {"type": PRODUCT, "a": {"type": "mesh_attribute", "name": VERTEX_COLOR}, "b": tex}
    elif material.texture is not None:
        base = _texture_base(mi, material, decoded)
    elif vertex_colored:
        base = {"type": "mesh_attribute", "name": VERTEX_COLOR}
    else:
        base = {"type": "rgb", "value": [float(c) for c in material.base_color]}
    if not uses_principled(material) and not (material.roughness_texture or material.metallic_texture):
        # Mitsuba's principled diffuse is Burley's (retro-reflection, not energy-conserving: a
        # 0.5 albedo renders 0.49-0.52 by roughness); Blender 4+'s Principled diffuse is
        # Lambertian, and so is this.
        return _surface(mi, material, {"type": "diffuse", "reflectance": base})
    bsdf = {
        "type": "principled",
        "base_color": base,
        "roughness": _grey_map(mi, material.roughness_texture, material) if material.roughness_texture else float(material.roughness),
        "metallic": _grey_map(mi, material.metallic_texture, material) if material.metallic_texture else float(material.metallic),
        "specular": float(material.specular),
    }
    if material.transmission > 0:
        # twosided forbids transmission; a transmissive surface must be closed and outward-facing.
        bsdf["spec_trans"] = float(material.transmission)
        return bsdf
    return _surface(mi, material, bsdf)


def _surface(mi, material: MaterialIR, bsdf: dict) -> dict:
    """Normal map, both sides, coverage: the wrappers around a reflecting BSDF."""
    if material.normal_texture:
        bsdf = {"type": "normalmap", "normalmap": _grey_map(mi, material.normal_texture, material), "bsdf": bsdf}
    # Mitsuba BSDFs are black from behind; scanned meshes and thin scene geometry have
    # inconsistent winding, and Cycles shades both sides.
    bsdf = {"type": "twosided", "material": bsdf}
    if material.transparent:
        opacity = (_grey_map(mi, material.opacity_texture, material, nearest=material.alpha_mode == "mask")
                   if material.opacity_texture else float(material.opacity))
        bsdf = {"type": "mask", "opacity": opacity, "material": bsdf}
    return bsdf


def _inverse3(R: np.ndarray) -> np.ndarray:
    """Inverse of a 3x3 matrix by its cofactors (numpy's LAPACK call costs ~2 ms here, per mesh)."""
    C = np.array([np.cross(R[1], R[2]), np.cross(R[2], R[0]), np.cross(R[0], R[1])])
    return C.T / float(np.dot(R[0], C[0]))


def build_mesh(mi, inst: MeshInstance, data: MeshData, calibrate: bool = True,
               decoded: DecodedTextures | None = None, sampling_weight: float = 1.0):
    T = inst.matrix
    R, t = T[:3, :3], T[:3, 3]
    v = data.vertices.astype(np.float64) @ R.T + t
    n = None
    if data.normals is not None:
        n = data.normals.astype(np.float64) @ _inverse3(R)  # (R^-T n) as rows
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-20)
    m = mitsuba_material(inst.material, calibrate)
    if m.textures and data.uv is None:
        raise ValueError(f"mitsuba: material of {inst.name!r} has a texture but its mesh has no UVs")
    vertex_colored = m.use_vertex_colors and data.colors is not None
    props = mi.Properties()
    props["bsdf"] = mi.load_dict(bsdf_dict(mi, m, vertex_colored, decoded))
    if emits(inst):
        props["emitter"] = mi.load_dict({**emitter_dict(mi, m, decoded), "sampling_weight": float(sampling_weight)})
    mesh = mi.Mesh(
        inst.name,
        vertex_count=len(v),
        face_count=len(data.faces),
        props=props,
        has_vertex_normals=n is not None,
        has_vertex_texcoords=data.uv is not None,
    )
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(v.astype(np.float32).ravel())
    params["faces"] = mi.UInt32(data.faces.astype(np.uint32).ravel())
    if n is not None:
        params["vertex_normals"] = mi.Float(n.astype(np.float32).ravel())
    if data.uv is not None:
        uv = data.uv.astype(np.float32).copy()
        uv[:, 1] = 1.0 - uv[:, 1]  # specsynth UVs are OpenGL (v up); Mitsuba's image rows go down
        params["vertex_texcoords"] = mi.Float(uv.ravel())
    params.update()
    if vertex_colored:
        rgb = srgb_to_linear(data.colors[:, :3].astype(np.float32) / 255.0)
        rgb = rgb * np.asarray(m.base_color, dtype=np.float32)  # (the texture then carries none)
        mesh.add_attribute(VERTEX_COLOR, 3, mi.Float(rgb.astype(np.float32).ravel()))
    return mesh


def light_dict(light: LightIR) -> dict:
    T = light.matrix
    if light.kind == "area":
        return {
            "type": "rectangle",
            "to_world": mapping.rectangle_to_world(T, light.size),
            # A Blender area light is no geometry: camera and bounce rays go through it (after
            # picking up its emission from the front). A ``null`` BSDF does that in Mitsuba's path
            # integrator, at the cost of one path vertex; shadow rays are still blocked by it.
            # (A black occluder here showed as a black bar in room2: -5.1 dB against Cycles.)
            "bsdf": {"type": "null"},
            "emitter": {"type": "area", "radiance": {"type": "rgb", "value": mapping.area_radiance(light.power, light.size, light.color)}},
        }
    if light.kind == "point":
        return {
            "type": "point",
            "position": [float(x) for x in T[:3, 3]],
            "intensity": {"type": "rgb", "value": mapping.point_intensity(light.power, light.color)},
        }
    if light.kind == "spot":
        cutoff, beam = mapping.spot_angles(light.spot_angle, light.spot_blend)
        return {
            "type": "spot",
            "to_world": mapping.emitter_to_world(T),
            "intensity": {"type": "rgb", "value": mapping.point_intensity(light.power, light.color)},
            "cutoff_angle": cutoff,
            "beam_width": beam,
        }
    if light.kind == "sun":
        d = -T[:3, 2]
        return {
            "type": "directional",
            "direction": [float(x) for x in d / np.linalg.norm(d)],
            "irradiance": {"type": "rgb", "value": [float(c) * light.power for c in light.color]},
        }
    raise ValueError(f"unknown light kind {light.kind!r}")


def world_dict(world: WorldIR) -> dict | None:
    if world.kind == "color":
        rad = [float(c) * world.strength for c in world.color]
        if not any(rad):
            return None
        return {"type": "constant", "radiance": {"type": "rgb", "value": rad}}
    if world.kind == "envmap":
        if not world.envmap or not Path(world.envmap).is_file():
            raise FileNotFoundError(f"environment map not found: {world.envmap!r}")
        return {
            "type": "envmap",
            "filename": str(world.envmap),
            "scale": float(world.strength),
            "to_world": mapping.envmap_to_world(world.rotation_z),
        }
    if world.kind == "sky":
        # Hosek-Wilkie sky (Cycles uses its multiple-scattering model: shape and colour differ),
        # brightened to Blender's units (mapping.sky_scale). Sky only: the sun is a LightIR sun in
        # the scene, as in the Cycles backend.
        turbidity = float(min(max(world.turbidity, 1.0), 10.0))
        return {
            "type": "sunsky",
            "sun_direction": mapping.sun_direction(world.sun_elevation, world.sun_azimuth),
            "turbidity": turbidity,
            "sky_scale": mapping.sky_scale(world.strength, turbidity, world.sun_elevation),
            "sun_scale": 0.0,
        }
    raise ValueError(f"unknown world kind {world.kind!r}")


def emits(inst: MeshInstance) -> bool:
    return any(c > 0 for c in inst.material.emission)


def emitter_powers(scene: RenderScene, meshes: dict[str, MeshData],
                   texture_mean: Callable[[str], float]) -> tuple[list[float | None], list[float]]:
    """(each light's power, None for a sun; each emissive mesh's), in the order ``scene_dict``
    adds them. A mesh emits its radiance times the mean of its emission texture over its area as
    the scene scales it (``texture_mean``: a texture's mean linear luminance)."""
    lights = [mapping.light_power(x.kind, x.power, x.color, x.spot_angle) for x in scene.lights]
    surfaces = []
    for inst in filter(emits, scene.meshes):
        data = meshes[inst.mesh_key]
        placed = data.vertices.astype(np.float64) @ inst.matrix[:3, :3].T
        texture = texture_mean(inst.material.emission_texture) if inst.material.emission_texture else 1.0
        area = mapping.triangle_area(placed, data.faces)
        surfaces.append(texture * mapping.surface_power(inst.material.emission, area))
    return lights, surfaces


def sampling_weights(scene: RenderScene, meshes: dict[str, MeshData], mode: str,
                     texture_mean: Callable[[str], float]) -> tuple[list[float], list[float]]:
    """Each light's and each emissive mesh's ``sampling_weight`` (``mapping.emitter_weights``); a
    sun keeps 1, as the world does."""
    if mode == "uniform":  # Mitsuba's own weights: no powers needed, no emission texture read for them
        return [1.0] * len(scene.lights), [1.0] * sum(map(emits, scene.meshes))
    lights, surfaces = emitter_powers(scene, meshes, texture_mean)
    finite = [p for p in lights if p is not None] + surfaces
    weights = iter(mapping.emitter_weights(finite, mode))
    light_w = [1.0 if p is None else next(weights) for p in lights]
    return light_w, list(weights)


def _texture_mean(mi, decoded: DecodedTextures) -> Callable[[str], float]:
    def mean(path: str) -> float:
        rgb = decoded.linear(mi, path)
        return mapping.luminance(rgb.reshape(-1, rgb.shape[-1]).mean(axis=0))
    return mean


def scene_dict(mi, scene: RenderScene, meshes: dict[str, MeshData], calibrate: bool = True,
               decoded: DecodedTextures | None = None, emitter_sampling: str = "uniform") -> dict:
    """``meshes`` maps mesh_key -> arrays and ``decoded`` holds textures (the backend's caches)."""
    d: dict = {"type": "scene"}
    decoded = DecodedTextures() if decoded is None else decoded
    decoded.next_scene()
    light_w, surface_w = sampling_weights(scene, meshes, emitter_sampling, _texture_mean(mi, decoded))
    surface_w = iter(surface_w)
    for i, inst in enumerate(scene.meshes):
        weight = next(surface_w) if emits(inst) else 1.0
        d[f"mesh_{i:04d}"] = build_mesh(mi, inst, meshes[inst.mesh_key], calibrate, decoded, weight)
    for i, (light, weight) in enumerate(zip(scene.lights, light_w)):
        ld = light_dict(light)
        (ld["emitter"] if "emitter" in ld else ld)["sampling_weight"] = weight
        for k in ("to_world",):
            if k in ld:
                ld[k] = _matrix(mi, ld[k])
        d[f"light_{i:03d}"] = ld
    w = world_dict(scene.world)
    if w is not None:
        if "filename" in w:
            w["bitmap"] = _read_bitmap(mi, w.pop("filename"))
        if "to_world" in w:
            w["to_world"] = _matrix(mi, w["to_world"])
        d["world"] = w
    return d
