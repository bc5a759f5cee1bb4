"""Scene files (YAML or JSON) as pydantic models: geometry, materials, lights, world, stages.

Units: metres, degrees, linear RGB in [0, 1]. Light power follows Blender/Cycles semantics, which
every backend maps to its own: area/point/spot lights in watts of emitted power, sun in W/m^2 of
irradiance ('strength'). As a guide, a room is well lit at exposure 1 by a 50-300 W area light;
a sun through a window by 3-5 W/m^2; an environment map by strength 0.2-1.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal, Union

from pydantic import BaseModel, ConfigDict, Discriminator, Field, Tag, field_validator, model_validator


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


Vec3 = tuple[float, float, float]
Color = tuple[float, float, float]

# Metres: no size, point or height of a scene file lies further out (a glTF's geometry is held to
# the same, assets.meshfiles.gltf.MAX_COORDINATE); past it float32 renderers and physics lose the
# millimetres a scene needs, and 1e300 overflows.
MAX_EXTENT = 10_000.0


def _within(values, what: str):
    if any(abs(x) > MAX_EXTENT for x in values):
        raise ValueError(f"{what} beyond {MAX_EXTENT:g} m")
    return values


def _polygon(v: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """A polygon of positive area within MAX_EXTENT (a degenerate one has no inside to drop on)."""
    _within([c for p in v for c in p], "a polygon's corner")
    area2 = sum(x0 * y1 - x1 * y0 for (x0, y0), (x1, y1) in zip(v, v[1:] + v[:1]))
    if abs(area2) < 1e-8:
        raise ValueError("polygon has zero area")
    return v


def _check_color(v):
    if v is not None and not all(0.0 <= c <= 1.0 for c in v):
        raise ValueError("colour components must be linear RGB in [0, 1]")
    return v


class Box(_Strict):
    box: Vec3 = Field(description="Box size x, y, z (metres), centred at the mesh origin.")

    @field_validator("box")
    @classmethod
    def _pos(cls, v):
        if min(v) <= 0:
            raise ValueError("box sizes must be > 0")
        return _within(v, "a box size")


class Plane(_Strict):
    plane: tuple[float, float] = Field(description="Horizontal rectangle size x, y (metres), facing +Z at z=0.")

    @field_validator("plane")
    @classmethod
    def _pos(cls, v):
        if min(v) <= 0:
            raise ValueError("plane sizes must be > 0")
        return _within(v, "a plane size")


class CylinderSize(_Strict):
    radius: float = Field(gt=0, le=MAX_EXTENT, description="Metres.")
    height: float = Field(gt=0, le=MAX_EXTENT, description="Metres; centred at the mesh origin, axis +Z.")


class Cylinder(_Strict):
    cylinder: CylinderSize


class TubeSpec(_Strict):
    points: list[Vec3] = Field(min_length=2, max_length=256, description="Points the tube's axis passes "
                               "through (metres, mesh frame); a smooth curve is drawn through them.")
    radius: float = Field(gt=0, le=1, description="Metres.")

    @field_validator("points")
    @classmethod
    def _a_curve(cls, v):
        _within([c for p in v for c in p], "a point")
        if len(set(v)) < 2:
            raise ValueError("a tube needs two distinct points")
        return v


class Tube(_Strict):
    tube: TubeSpec = Field(description="A tube swept along a curve: a cable, a hose.")


class Furniture(_Strict):
    furniture: str = Field(
        description="A Sweet Home 3D library model by id, e.g. 'Blend Swap CC-0#armchair' (specsynth furniture "
        "lists them): sized to its catalogue dimensions, standing on z = 0, front facing -Y."
    )


def _source_tag(v) -> str | None:
    if isinstance(v, str):
        return "file"
    if isinstance(v, dict) and len(v) == 1:
        key = next(iter(v))
        return key if key in ("box", "plane", "cylinder", "tube", "furniture") else None
    for cls, tag in ((Box, "box"), (Plane, "plane"), (Cylinder, "cylinder"), (Tube, "tube"), (Furniture, "furniture")):
        if isinstance(v, cls):
            return tag
    return None


# A callable discriminator so a bad source gives one error for the shape it names, not one per
# union member; None (unknown shape) reports the allowed forms via the error message below.
Source = Annotated[
    Union[
        Annotated[Box, Tag("box")],
        Annotated[Plane, Tag("plane")],
        Annotated[Cylinder, Tag("cylinder")],
        Annotated[Tube, Tag("tube")],
        Annotated[Furniture, Tag("furniture")],
        Annotated[str, Tag("file")],
    ],
    Discriminator(
        _source_tag,
        custom_error_type="invalid_source",
        custom_error_message="source must be {box: [sx, sy, sz]}, {plane: [sx, sy]}, "
        "{cylinder: {radius, height}}, {tube: {points, radius}}, {furniture: <library id>} or a mesh file "
        "('pybullet_data:...' or a relative path)",
    ),
]


MIN_SCALE, MAX_SCALE = 1e-6, 1e6
MAX_LIGHT_POWER = 1e7  # W (W/m^2 for a sun): far past any lamp (a stadium floodlight draws ~2 kW)


class Transform(_Strict):
    """Mesh placement: vertices are scaled, then rotated, then translated (world = T R S model)."""

    translation: Vec3 = Field((0.0, 0.0, 0.0), description="Metres.")
    rotation: Union[Vec3, tuple[Vec3, Vec3, Vec3]] = Field(
        (0.0, 0.0, 0.0),
        description="Roll, pitch, yaw in degrees (fixed axes X, Y, Z: R = Rz Ry Rx), or a 3x3 rotation matrix.",
    )
    scale: Union[float, Vec3] = Field(1.0, description="Uniform or per-axis scale (applied in the model frame).")

    @field_validator("translation")
    @classmethod
    def _near(cls, v):
        return _within(v, "a translation")

    @field_validator("rotation")
    @classmethod
    def _rotation(cls, v):
        if isinstance(v[0], (tuple, list)):
            import numpy as np

            R = np.asarray(v, dtype=float)
            if not np.allclose(R @ R.T, np.eye(3), atol=1e-4) or np.linalg.det(R) < 0:
                raise ValueError("3x3 rotation must be orthonormal with determinant +1")
        return v

    @field_validator("scale")
    @classmethod
    def _scale(cls, v):
        s = (v,) * 3 if isinstance(v, (int, float)) else v
        if min(s) <= 0:
            raise ValueError("scale must be > 0 (mirroring is not supported)")
        if min(s) < MIN_SCALE or max(s) > MAX_SCALE:  # past these a mesh is a speck or a world, not furniture
            raise ValueError(f"scale must be within {MIN_SCALE:g}..{MAX_SCALE:g}")
        return v


class SceneMaterial(_Strict):
    """Principled BSDF parameters."""

    base_color: Color | None = Field(None, description="Linear RGB; default white with a texture, else 0.8 grey.")
    texture: str | None = Field(
        None, description="Base-colour image: 'pybullet_data:<path>' or a path relative to the scene file. "
        "Default: the source mesh's own texture, if it has one.",
    )
    uv_scale: Union[float, tuple[float, float]] = Field(
        1.0, description="UV multiplier. Primitive UVs are in metres, so this is texture repeats per metre.",
    )
    roughness: float = Field(0.5, ge=0, le=1)
    metallic: float = Field(0.0, ge=0, le=1)
    specular: float = Field(0.5, ge=0, le=1, description="Dielectric F0 = 0.08 * specular.")
    emission: Color = Field((0.0, 0.0, 0.0), description="Emitted radiance, W/(sr m^2), linear RGB.")
    emission_texture: str | None = Field(
        None, description="An image multiplying 'emission' (sRGB-encoded), tiled like the texture: what a "
        "screen shows. A path relative to the scene file.")
    normal_map: str | None = Field(
        None, description="Tangent-space normal map (OpenGL convention: green = +v), tiled like the texture: "
        "'normals:0012' from the installed CC0 set (`specsynth assets list`) or an image path relative to the "
        "scene file.")
    normal_strength: float = Field(1.0, ge=0, le=4, description="Relief of the normal map: its tilt scaled by "
                                   "this (glTF's normal scale).")
    roughness_variation: float = Field(0.0, ge=0, le=0.5, description="Roughness varies across the surface by up "
                                       "to +/- this much: rougher where the normal map is deeper (or, without "
                                       "one, the texture darker), as wear and grime do.")

    @field_validator("base_color")
    @classmethod
    def _color(cls, v):
        return _check_color(v)

    @field_validator("uv_scale")
    @classmethod
    def _uv(cls, v):
        s = (v, v) if isinstance(v, (int, float)) else v
        if min(s) <= 0:
            raise ValueError("uv_scale must be > 0")
        return v

    @field_validator("emission")
    @classmethod
    def _emission(cls, v):
        if min(v) < 0:
            raise ValueError("emission must be >= 0")
        return v

    @model_validator(mode="after")
    def _variation_source(self):
        if self.roughness_variation and self.normal_map is None and self.texture is None:
            raise ValueError("roughness_variation needs a texture or a normal_map to vary with")
        return self


class SceneMesh(_Strict):
    name: str = Field(pattern=r"^[A-Za-z0-9_.\-]+$", description="Unique within the scene.")
    source: Source = Field(
        description="{box: [sx, sy, sz]}, {plane: [sx, sy]}, {cylinder: {radius, height}}, {tube: {points, "
        "radius}}, 'pybullet_data:table/table.obj' or a path relative to the scene file: glTF/GLB and OBJ+MTL "
        "(every material kept), PLY, STL, URDF."
    )
    unit: Literal["m", "cm", "mm"] = Field("m", description="Length unit of a mesh file.")
    transform: Transform = Transform()
    material: SceneMaterial = SceneMaterial()
    materials: dict[str, SceneMaterial] = Field(
        default_factory=dict,
        description="Overrides for single materials of a glTF/OBJ file, by their name in the file.",
    )
    collide: bool = Field(True, description="Whether dropped objects collide with it (physics).")


class LightDef(_Strict):
    kind: Literal["area", "point", "spot", "sun"]
    power: float = Field(
        gt=0, le=MAX_LIGHT_POWER, description="Watts for area/point/spot (Blender semantics); W/m^2 irradiance for sun."
    )
    color: Color = Field((1.0, 1.0, 1.0), description="Linear RGB.")
    translation: Vec3 = Field((0.0, 0.0, 0.0), description="Metres (irrelevant for sun).")
    rotation: Vec3 = Field((0.0, 0.0, 0.0), description="Roll, pitch, yaw, degrees. Lights emit along local -Z.")
    look_at: Vec3 | None = Field(None, description="Aim the light at this world point instead of 'rotation'.")
    size: tuple[float, float] = Field((0.5, 0.5), description="Area light extent, metres.")
    spot_angle: float = Field(45.0, gt=0, le=180, description="Full cone angle, degrees.")
    spot_blend: float = Field(0.15, ge=0, le=1)
    sun_angle: float = Field(0.526, ge=0, le=90, description="Angular diameter of the sun, degrees.")

    @field_validator("color")
    @classmethod
    def _color(cls, v):
        return _check_color(v)

    @field_validator("translation", "look_at", "size")
    @classmethod
    def _near(cls, v, info):
        return v if v is None else _within(v, f"light {info.field_name}")

    @model_validator(mode="after")
    def _aim(self):
        if self.look_at is not None and math.dist(self.look_at, self.translation) < 1e-9:
            raise ValueError("look_at coincides with translation")
        return self


class Sky(_Strict):
    sun_elevation: float = Field(45.0, ge=-10, le=90, description="Degrees above the horizon.")
    sun_azimuth: float = Field(0.0, description="Degrees, counter-clockwise from +X about +Z.")
    turbidity: float = Field(3.0, ge=1, le=10)


class World(_Strict):
    """Background and ambient light: exactly one of color, envmap, sky."""

    color: Color | None = Field(None, description="Uniform linear RGB background radiance.")
    envmap: str | None = Field(
        None, description="Built-in HDRI name (see specsynth.assets.resolve.builtin_hdris) or an HDR/EXR path."
    )
    sky: Sky | None = None
    strength: float = Field(1.0, ge=0, description="Radiance multiplier.")
    rotation: float = Field(0.0, description="Environment rotation about world Z, degrees.")

    @field_validator("color")
    @classmethod
    def _color(cls, v):
        return _check_color(v)

    @model_validator(mode="after")
    def _one(self):
        if sum(x is not None for x in (self.color, self.envmap, self.sky)) != 1:
            raise ValueError("give exactly one of 'color', 'envmap' or 'sky'")
        return self


class StageDef(_Strict):
    name: str = Field(pattern=r"^[A-Za-z0-9_.\-]+$")
    polygon: list[tuple[float, float]] = Field(
        min_length=3, description="Support area, [[x, y], ...] world metres; any winding (stored CCW)."
    )
    height: float = Field(ge=-MAX_EXTENT, le=MAX_EXTENT, description="World Z of the support surface, metres.")

    @field_validator("polygon")
    @classmethod
    def _area(cls, v):
        return _polygon(v)


class FocusArea(_Strict):
    polygon: list[tuple[float, float]] = Field(min_length=3, description="[[x, y], ...] world metres.")
    height: float = Field(ge=-MAX_EXTENT, le=MAX_EXTENT, description="World Z of the surface, metres.")

    @field_validator("polygon")
    @classmethod
    def _area(cls, v):  # converted to a stage's polygon in the arrange jobs: checked as one here
        return _polygon(v)


class SceneFile(_Strict):
    version: Literal[1] = 1
    name: str = Field(pattern=r"^[A-Za-z0-9_.\-]+$")
    description: str = ""
    meshes: list[SceneMesh] = Field(default_factory=list)
    lights: list[LightDef] = Field(default_factory=list)
    world: World = World(color=(0.05, 0.05, 0.05))
    stages: Union[Annotated[list[StageDef], Field(min_length=1)], Literal["auto"]] = Field(
        "auto",
        description="Support polygons to drop objects on; 'auto' (the default) finds them in the geometry: "
        "upward surfaces with room above them (specsynth.scenes.autostage).",
    )

    focus: list[FocusArea] = Field(
        default_factory=list, description="Where objects should mostly land: stages (declared or found) whose "
        "centre lies in one of these areas, within 3 cm of its height, are drawn 'focus_share' of the time "
        "together (the built-in rooms put their dressed desks and benches here).")
    focus_share: float = Field(0.8, gt=0, le=1, description="The share of arrangements on the focus stages.")

    @property
    def auto_stages(self) -> bool:
        return self.stages == "auto"

    @model_validator(mode="after")
    def _unique(self):
        if self.auto_stages and not self.meshes:
            raise ValueError("stages: auto finds stages in the meshes, and this scene has none; add meshes or declare stages")
        for what, items in (("mesh", self.meshes), ("stage", [] if self.auto_stages else self.stages)):
            seen = set()
            for it in items:
                if it.name in seen:
                    raise ValueError(f"{what} name {it.name!r} is used twice")
                seen.add(it.name)
        return self
