"""Backend-neutral description of what is rendered: the contract between the core and every backend.

Conventions (one everywhere, see ``specsynth.model.conventions``):
- world frame: metres, Z up;
- camera: OpenCV (x right, y down, z forward); ``R_w2c``/``t_w2c`` map world points into the camera
  frame, ``x_c = R_w2c @ x_w + t_w2c`` (metres);
- ``pose`` of a mesh instance: 4x4 world-from-model transform, metres;
- colours: linear RGB in [0, 1]; light power in watts (area/point/spot), sun irradiance in W/m^2,
  environment strength as a plain radiance multiplier.

Meshes are referenced by the path of their *normalised* file (see ``specsynth.assets.resolve``): a binary
PLY in metres, read back into numpy arrays with ``specsynth.assets.resolve.read_mesh``. Backends build their
own meshes from those arrays and may cache them by ``mesh_key`` (a content hash).
These are plain frozen dataclasses so that they pickle cheaply to worker processes.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

IDENTITY_UV = (1.0, 0.0, 0.0, 0.0, 1.0, 0.0)


@dataclass(frozen=True)
class MaterialIR:
    """A metallic-roughness material. Every texture is an image file read through the mesh's UVs
    (OpenGL convention, v up), after ``uv_transform``, with ``wrap`` at the borders. Importers bake
    factors into the grey-level maps, so each map *is* the value it drives."""

    base_color: tuple[float, float, float] = (0.8, 0.8, 0.8)
    use_vertex_colors: bool = True  # multiply by the mesh's vertex colours when it has them
    texture: str | None = None  # base-colour image (sRGB-encoded file), needs UVs
    roughness: float = 0.5
    metallic: float = 0.0
    specular: float = 0.5
    transmission: float = 0.0
    emission: tuple[float, float, float] = (0.0, 0.0, 0.0)  # radiance, W/(sr m^2), linear RGB
    roughness_texture: str | None = None  # grey, linear: the roughness itself (replaces `roughness`)
    metallic_texture: str | None = None  # grey, linear: the metallic value itself
    normal_texture: str | None = None  # tangent-space normal map, linear RGB, OpenGL's +Y (green = +v)
    emission_texture: str | None = None  # sRGB image multiplying `emission`
    alpha_mode: Literal["opaque", "mask", "blend"] = "opaque"
    opacity: float = 1.0  # without opacity_texture: constant coverage in [0, 1]
    opacity_texture: str | None = None  # grey, linear coverage; for "mask" already 0 or 1
    uv_transform: tuple[float, float, float, float, float, float] = IDENTITY_UV  # u' = a u + b v + c, v' = d u + e v + f
    wrap: Literal["repeat", "clamp", "mirror"] = "repeat"
    double_sided: bool = True  # informational: Cycles and Mitsuba shade both sides of every surface

    def painted(self, color) -> "MaterialIR":
        """This material painted one plastic colour (linear RGB): its base colour, vertex colours and
        colour texture replaced, neither metal nor glass any more, its surface (roughness, relief,
        specular) kept. ``None``: unchanged."""
        if color is None:
            return self
        return replace(self, base_color=tuple(float(c) for c in color), use_vertex_colors=False, texture=None,
                       metallic=0.0, transmission=0.0, metallic_texture=None)

    @property
    def textures(self) -> tuple[str, ...]:
        """Every image file the material reads."""
        maps = (self.texture, self.roughness_texture, self.metallic_texture, self.normal_texture,
                self.emission_texture, self.opacity_texture)
        return tuple(t for t in maps if t is not None)

    @property
    def transparent(self) -> bool:
        return self.alpha_mode != "opaque" and (self.opacity < 1.0 or self.opacity_texture is not None)

    @property
    def glossy(self) -> bool:
        """Whether a path tracer needs glossy bounces for this material to look right."""
        if self.metallic > 0.0 or self.metallic_texture is not None:
            return True
        return self.specular > 0.0 and (self.roughness < 0.6 or self.roughness_texture is not None)


@dataclass(frozen=True)
class MeshInstance:
    name: str  # unique within the scene
    mesh_path: str  # normalised PLY, metres
    mesh_key: str  # content hash of the normalised mesh
    pose: tuple[tuple[float, ...], ...]  # 4x4 world-from-model, row-major, metres
    material: MaterialIR = MaterialIR()
    obj_id: int | None = None  # dataset object id; None for scene geometry
    inst: int | None = None  # index of this instance among the dataset objects (gt order)

    @property
    def matrix(self) -> np.ndarray:
        return np.asarray(self.pose, dtype=np.float64)

    @property
    def is_object(self) -> bool:
        return self.obj_id is not None


@dataclass(frozen=True)
class LightIR:
    kind: Literal["area", "point", "spot", "sun"]
    pose: tuple[tuple[float, ...], ...]  # 4x4 world-from-light; lights emit along their local -Z
    color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    power: float = 100.0  # W for area/point/spot; W/m^2 irradiance for sun
    size: tuple[float, float] = (0.5, 0.5)  # area light extent (m), local X and Y
    spot_angle: float = 45.0  # full cone angle, degrees
    spot_blend: float = 0.15
    sun_angle: float = 0.526  # angular diameter, degrees

    @property
    def matrix(self) -> np.ndarray:
        return np.asarray(self.pose, dtype=np.float64)


@dataclass(frozen=True)
class WorldIR:
    kind: Literal["color", "envmap", "sky"] = "color"
    color: tuple[float, float, float] = (0.05, 0.05, 0.05)
    strength: float = 1.0
    envmap: str | None = None  # equirectangular HDR/EXR file
    rotation_z: float = 0.0  # degrees, rotation of the environment about world Z
    # sky: a physical daylight model of the sky dome only (no sun disc: put the sun in the scene as
    # a LightIR of kind "sun" pointing the same way); sun direction in degrees, azimuth 0 = +Y,
    # counter-clockwise seen from above (Blender's own sky turns clockwise: its backend negates it).
    sun_elevation: float = 45.0
    sun_azimuth: float = 0.0
    turbidity: float = 3.0


@dataclass(frozen=True)
class RenderScene:
    meshes: tuple[MeshInstance, ...]
    lights: tuple[LightIR, ...] = ()
    world: WorldIR = WorldIR()

    def objects(self) -> tuple[MeshInstance, ...]:
        """Dataset object instances in gt order."""
        return tuple(sorted((m for m in self.meshes if m.is_object), key=lambda m: m.inst))

    def objects_only(self) -> "RenderScene":
        return RenderScene(meshes=self.objects(), lights=self.lights, world=self.world)

    def translated(self, offset) -> "RenderScene":
        """The scene moved by ``-offset`` (metres). Renderers work in float32: re-centring an
        arrangement 1 km from the origin keeps sub-millimetre precision in their transforms."""
        o = np.asarray(offset, dtype=np.float64)
        if not o.any():
            return self

        def move(pose):
            T = np.array(pose, dtype=np.float64)
            T[:3, 3] -= o
            return as_tuple(T)

        meshes = tuple(replace(m, pose=move(m.pose)) for m in self.meshes)
        lights = tuple(replace(light, pose=move(light.pose)) for light in self.lights)
        return RenderScene(meshes=meshes, lights=lights, world=self.world)

    @property
    def has_glossy(self) -> bool:
        return any(m.material.glossy for m in self.meshes)

    @property
    def has_transmission(self) -> bool:
        return any(m.material.transmission > 0 for m in self.meshes)


@dataclass(frozen=True)
class CameraIR:
    K: tuple[tuple[float, ...], ...]  # 3x3 intrinsics, pixels
    width: int
    height: int
    R_w2c: tuple[tuple[float, ...], ...]  # 3x3, OpenCV camera
    t_w2c: tuple[float, float, float]  # metres
    near: float = 0.01
    far: float = 100.0
    aperture: float = 0.0  # thin-lens aperture diameter, metres (0: pinhole)
    focus_distance: float = 0.0  # metres along the optical axis to the plane in focus
    # Camera motion over the exposure, in the OpenCV camera frame at mid-exposure: (tx, ty, tz)
    # metres of travel and (rx, ry, rz) a rotation vector (radians), from shutter open to close.
    # At exposure fraction s in [-1/2, 1/2]: x_world = T_c2w (Exp(s r) x_cam + s t). () = still.
    motion: tuple[float, ...] = ()

    def translated(self, offset) -> "CameraIR":
        """The same view of a scene moved by ``-offset``: ``t' = t + R @ offset``."""
        t = np.asarray(self.t_w2c, dtype=np.float64) + np.asarray(self.R_w2c) @ np.asarray(offset, dtype=np.float64)
        return replace(self, t_w2c=as_tuple(t))

    def scaled(self, factor: int) -> "CameraIR":
        """The same view at ``factor`` times the resolution: each pixel split into factor x factor
        whose mean is the pixel (OpenCV's pixel centres at integers: ``c' = (c + 0.5) f - 0.5``)."""
        if not isinstance(factor, int) or isinstance(factor, bool) or factor < 1:
            raise ValueError(f"a camera is scaled by a whole factor of at least 1, got {factor!r}")
        K = self.K_array.copy()
        K[:2, :3] *= factor
        K[:2, 2] += 0.5 * factor - 0.5
        return replace(self, K=as_tuple(K), width=self.width * factor, height=self.height * factor)

    def cropped(self, x0: int, y0: int, width: int, height: int) -> "CameraIR":
        """The window of ``width`` x ``height`` pixels from pixel ``(x0, y0)`` as a camera of its own:
        its pixel (u, v) is this camera's (x0 + u, y0 + v)."""
        ints = (x0, y0, width, height)
        if any(not isinstance(v, int) or isinstance(v, bool) for v in ints):
            raise ValueError(f"a camera is cropped to whole pixels, got {ints!r}")
        if x0 < 0 or y0 < 0 or width < 1 or height < 1 or x0 + width > self.width or y0 + height > self.height:
            raise ValueError(f"window {width}x{height} at ({x0}, {y0}) is not inside the {self.width}x{self.height} image")
        K = self.K_array.copy()
        K[0, 2] -= x0
        K[1, 2] -= y0
        return replace(self, K=as_tuple(K), width=width, height=height)

    @property
    def K_array(self) -> np.ndarray:
        return np.asarray(self.K, dtype=np.float64)

    @property
    def T_w2c(self) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = np.asarray(self.R_w2c, dtype=np.float64)
        T[:3, 3] = self.t_w2c
        return T

    @property
    def T_c2w(self) -> np.ndarray:
        return np.linalg.inv(self.T_w2c)


def as_tuple(a: np.ndarray) -> tuple:
    """Numpy array -> nested tuples of Python floats (hashable, picklable, JSON-able)."""
    a = np.asarray(a, dtype=np.float64)
    if a.ndim == 1:
        return tuple(float(x) for x in a)
    return tuple(as_tuple(r) for r in a)


@dataclass(frozen=True)
class RenderResult:
    rgb: np.ndarray  # HxWx3 uint8, sRGB-encoded
    linear: np.ndarray | None = None  # HxWx3 float32 linear radiance (PBR backends)
    stats: dict = field(default_factory=dict)  # e.g. samples, variant, seconds
    # HxWx3 float32 linear radiance before the denoiser, when the backend denoised ``linear``: what
    # the error estimates of specsynth.model.error need from a denoising backend.
    noisy: np.ndarray | None = None
    # HxWx6 float32, the denoiser's guides beside ``noisy`` (albedo, then normal): with them the
    # core denoises several renders' samples together (RenderBackend.denoise, quality.control: error).
    guides: np.ndarray | None = None
