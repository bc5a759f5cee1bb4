"""The dataset spec: pydantic models, the single source of truth.

Everything a build reads from the user comes through :class:`DatasetSpec`. The JSON Schema in
``schemas/`` is generated from these models (``specsynth schema``) and a test keeps it in sync.
Units are part of every field description: metres, degrees, pixels.
"""

from __future__ import annotations

import datetime
import functools
import math
from typing import Annotated, Any, ClassVar, Literal, Union

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Discriminator,
    Field,
    SerializeAsAny,
    Tag,
    ValidationInfo,
    create_model,
    field_validator,
    model_validator,
)

SPEC_VERSION = 1


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    @field_validator("*", mode="before")
    @classmethod
    def _no_bool_numbers(cls, value, info):
        """YAML's ``true`` is not a count: pydantic would read ``per_arrangement: true`` as 1."""
        if isinstance(value, bool) and _numeric(cls.model_fields[info.field_name].annotation):
            raise ValueError(f"expected a number, got {str(value).lower()}")
        return value


def _numeric(annotation) -> bool:
    """Whether a field takes numbers and not booleans (int, float, optional or in a union)."""
    import typing

    if annotation in (int, float):
        return True
    args = typing.get_args(annotation)
    return bool(args) and bool not in args and any(a in (int, float) for a in args)


def _range(lo_min: float | None = None, hi_max: float | None = None, positive: bool = False):
    """Validator for a ``[min, max]`` pair: finite, ordered, within optional bounds."""

    def check(v: tuple[float, float]) -> tuple[float, float]:
        lo, hi = v
        if not (math.isfinite(lo) and math.isfinite(hi)):
            raise ValueError("range bounds must be finite")
        if lo > hi:
            raise ValueError(f"min ({lo}) must be <= max ({hi})")
        if lo_min is not None and lo < lo_min:
            raise ValueError(f"min ({lo}) must be >= {lo_min}")
        if hi_max is not None and hi > hi_max:
            raise ValueError(f"max ({hi}) must be <= {hi_max}")
        if positive and lo <= 0:
            raise ValueError(f"min ({lo}) must be > 0")
        return v

    return check


def FloatRange(lo_min: float | None = None, hi_max: float | None = None, positive: bool = False):
    return Annotated[tuple[float, float], AfterValidator(_range(lo_min, hi_max, positive))]


def IntRange(lo_min: int = 0):
    return Annotated[tuple[int, int], AfterValidator(lambda v: _int_range(v, lo_min))]


# --------------------------------------------------------------------------- objects


class Material(Strict):
    """Principled material override (the paper's specular / metallic / roughness)."""

    color: tuple[float, float, float] | None = Field(
        None, description="Linear base colour in [0,1]; replaces vertex colours and texture when set."
    )
    use_vertex_colors: bool = Field(True, description="Use the mesh's vertex colours when it has them.")
    texture: str | None = Field(None, description="Path to a base-colour texture (needs UV coordinates).")
    specular: float = Field(0.5, ge=0, le=1, description="Specular level (dielectric F0 = 0.08 * specular).")
    metallic: float = Field(0.0, ge=0, le=1)
    roughness: float = Field(0.5, ge=0, le=1)
    color_gain: tuple[float, float, float] = Field(
        (1.0, 1.0, 1.0), description="Multiplies the object's colour (vertex colours, texture or 'color') per "
        "channel in linear light: scanned colours are often darker or duller than the object looks to the test "
        "camera. `specsynth fit` sets it per object from real photographs.")

    @field_validator("color_gain")
    @classmethod
    def _gain_range(cls, v):
        if not all(0.1 <= g <= 4.0 for g in v):
            raise ValueError("each colour gain must be in [0.1, 4]")
        return v

    @field_validator("color")
    @classmethod
    def _color_range(cls, v):
        if v is not None and not all(0.0 <= c <= 1.0 for c in v):
            raise ValueError("colour components must be in [0, 1]")
        return v


class MeshObject(Strict):
    path: str = Field(description="Mesh file (PLY/OBJ/GLB/STL), relative to the spec file.")
    unit: Literal["m", "cm", "mm"] = Field(description="Length unit of the mesh file.")
    obj_id: int | None = Field(None, ge=1, description="Object id; default: the lowest id no other model has, in the order listed (after a BOP folder's ids).")
    name: str | None = None


class BuiltinObject(Strict):
    name: str = Field(description="pybullet_data asset, e.g. duck, teddy, mug, random_urdfs/000.")
    obj_id: int | None = Field(None, ge=1, description="Object id; default: the lowest id no other model has, in the order listed (after a BOP folder's ids).")


class Objects(Strict):
    """Which object models are dropped, and how many instances of each."""

    path: str | None = Field(
        None,
        description="BOP models folder (models_info.json + obj_XXXXXX.ply in millimetres). "
        "Supports ${ENV_VAR} expansion.",
    )
    ids: list[int] | None = Field(None, description="Subset of obj ids of the BOP folder; default all.")
    builtin: list[Union[str, BuiltinObject]] = Field(
        default_factory=list, description="Built-in objects from pybullet_data by name."
    )
    meshes: list[MeshObject] = Field(default_factory=list)
    instances: IntRange(0) = Field((1, 1), description="Instances per model per arrangement, [min, max].")
    orientation: Literal["canonical", "random"] = Field(
        "canonical", description="canonical: upright as modelled (LM); random: uniform rotation (RU-APC)."
    )
    models_per_arrangement: IntRange(1) | None = Field(
        None, description="Draw this many distinct models per arrangement; default all."
    )
    materials: dict[str, Material] = Field(
        default_factory=dict,
        description="Material overrides keyed by 'default', an obj id ('5') or a built-in name ('duck'). Only "
        "renders read them: an edit renders again and keeps the arrangements and cameras; bop/models keep each "
        "model's own look.",
    )

    @field_validator("instances")
    @classmethod
    def _instances(cls, v):
        if v[1] > MAX_DROPPED:
            raise ValueError(f"at most {MAX_DROPPED} instances of a model per arrangement")
        return v

    @field_validator("instances")
    @classmethod
    def _some_instances(cls, v):
        if v[1] == 0:  # the build had run physics and cameras for arrangements without an object
            raise ValueError("max 0: no instance of any model would be dropped (at least [0, 1])")
        return v

    @field_validator("materials", mode="before")
    @classmethod
    def _ids_as_keys(cls, v):
        # YAML reads an unquoted obj id key (5:) as an int; ids are written as strings here.
        return {str(k): m for k, m in v.items()} if isinstance(v, dict) else v

    @model_validator(mode="after")
    def _some_objects(self):
        if self.path is None and not self.builtin and not self.meshes:
            raise ValueError("no objects: give a BOP models 'path', 'builtin' names or 'meshes'")
        if self.ids is not None and self.path is None:
            raise ValueError("'ids' selects from a BOP folder: set 'path' too")
        return self


MAX_DROPPED = 1000  # objects or distractors dropped per arrangement (see also the compiler's SPECSYNTH_MAX_OBJECTS)


def _int_range(v: tuple[int, int], lo_min: int) -> tuple[int, int]:
    lo, hi = v
    if lo > hi:
        raise ValueError(f"min ({lo}) must be <= max ({hi})")
    if lo < lo_min:
        raise ValueError(f"min ({lo}) must be >= {lo_min}")
    return v


# --------------------------------------------------------------------------- scenes


class RoomOptions(Strict):
    """Parameters of the procedural ``random_room`` (a new furnished room per arrangement)."""

    kinds: list[Literal["living_room", "kitchen", "office", "bedroom", "workshop", "shop", "office_desk", "lab"]] = Field(
        ["living_room", "kitchen", "office", "bedroom"], min_length=1,
        description="Room kinds to draw from (each picks its furniture from the library's categories).")
    width: FloatRange(2.5, 12.0) = Field((3.6, 6.0), description="Interior width range, metres.")
    depth: FloatRange(2.5, 12.0) = Field((3.2, 5.0), description="Interior depth range, metres.")
    height: FloatRange(2.2, 5.0) = Field((2.5, 2.9), description="Ceiling height range, metres.")
    density: FloatRange(0.0, 3.0) = Field((1.0, 1.0), description="Furniture count multiplier range "
                                          "(1 = 6-10 pieces against the walls and 1-2 in the middle).")
    categories: list[str] | None = Field(None, min_length=1, description="Furniture catalogue categories "
                                         "(see `specsynth furniture`) instead of the kinds' own.")
    clutter: IntRange(0) = Field((1, 3), description="Small catalogue items (books, cups, plants, toys) standing "
                                 "on each furniture top, [min, max]; stages are found around them.")
    pictures: IntRange(0) = Field((1, 3), description="Framed photographs (scikit-image's public-domain and CC0 "
                                     "samples) hung on the walls, [min, max].")
    boards: float = Field(0.35, ge=0, le=1, description="Chance that a dressed desk or bench has a board of square "
                          "fiducial markers under its stage area, lying on magazines, the objects standing on it: 1 for "
                          "test photographs like LM-O's, which show one under every object.")
    islands: float = Field(0.0, ge=0, le=1, description="Chance that an office_desk or lab room's work surface "
                           "stands in the middle of the room (a bench, or two desks back to back), its stage area in "
                           "the middle of the top with things on every side, as on a lab table photographed from all "
                           "round; else it stands against a wall, under the window when it fits.")

    @field_validator("clutter")
    @classmethod
    def _clutter(cls, v):
        if v[1] > 10:
            raise ValueError("at most 10 clutter items per furniture top")
        return v

    @field_validator("pictures")
    @classmethod
    def _pictures(cls, v):
        if v[1] > 6:
            raise ValueError("at most 6 pictures per room")
        return v


class SceneRandomization(Strict):
    """Domain randomisation of a scene, drawn per arrangement from its seed (off by default)."""

    materials: float = Field(0.0, ge=0, le=1, description="Probability that each textured-able scene surface "
                             "(one with UVs) gets a surface texture of the library instead of its own.")
    roughness: float = Field(0.0, ge=0, le=0.5, description="Roughness and specular of every scene surface "
                             "jittered by up to +/- this much (clipped to [0, 1]).")
    light_temperature: FloatRange(1000.0, 15000.0) | None = Field(
        None, description="Each light's colour: a black body drawn in this range, kelvin (e.g. [2700, 6500]).")
    light_strength: FloatRange(0.0, 100.0) = Field((1.0, 1.0), description="Each light's power multiplied by a "
                                                   "factor drawn in this range.")
    light_position: float = Field(0.0, ge=0, le=5.0, description="Each light moved by up to this many metres "
                                  "along each axis.")
    environment_strength: FloatRange(0.0, 100.0) = Field((1.0, 1.0), description="The world/HDRI strength "
                                                         "multiplied by a factor drawn in this range.")

    @property
    def active(self) -> bool:
        return bool(self.materials or self.roughness or self.light_temperature or self.light_position
                    or self.light_strength != (1.0, 1.0) or self.environment_strength != (1.0, 1.0))


class SceneRef(Strict):
    name: str | None = Field(None, description="Built-in scene name (see `specsynth scenes`).")
    file: str | None = Field(None, description="Scene file (YAML/JSON), relative to the spec file.")
    stages: list[str] | None = Field(None, description="Stages to use, by name; default all. 'focus': every stage "
                                     "in the scene's focus areas (the built-in rooms' dressed desks and benches; a generated room without "
                                     "one uses all its stages).")
    weight: float = Field(1.0, gt=0, description="Relative probability of choosing this scene.")
    room: RoomOptions | None = Field(None, description="Parameters of 'random_room' (only).")
    clutter: float = Field(1.0, ge=0, le=3, description="How densely the built-in rooms' work surfaces and floors "
                           "are cluttered (monitors, keyboards, papers, books, mugs, cables, boxes, bins): 0 none, "
                           "1 a lived-in office (the default), up to 3. Built-in generated rooms only.")
    randomize: SceneRandomization = Field(SceneRandomization(), description="Domain randomisation per "
                                          "arrangement: surface materials, light colour, strength, position.")

    @model_validator(mode="after")
    def _one_source(self):
        if (self.name is None) == (self.file is None):
            raise ValueError("give exactly one of 'name' (built-in scene) or 'file'")
        if self.room is not None and self.name != "random_room":
            raise ValueError("'room' parameters are for the scene 'random_room' only")
        return self

    @property
    def ref(self) -> str:
        return self.name if self.name is not None else f"file:{self.file}"


# --------------------------------------------------------------------------- physics / arrangements


class Physics(Strict):
    timestep: float = Field(1 / 240, gt=0, le=0.05, description="Simulation step in seconds.")
    max_time: float = Field(8.0, gt=0, le=120, description="Simulated seconds before giving up settling.")
    linear_threshold: float = Field(
        0.01, gt=0, description="Settled when every object's mean speed (m/s) over a hold_time window is below this ..."
    )
    angular_threshold: float = Field(0.1, gt=0, description="... and its mean angular speed (rad/s) below this.")
    hold_time: float = Field(0.25, ge=0, description="The settling window in simulated seconds (at least one step).")
    penetration_tolerance: float = Field(0.002, gt=0, description="Max allowed penetration depth (m).")
    on_invalid: Literal["redrop", "remove"] = Field(
        "redrop", description="What happens to an object that left the stage or penetrates."
    )
    max_redrops: int = Field(3, ge=0, le=20)
    collision: Literal["convex_hull", "decomposition"] = Field(
        "convex_hull", description="Collision shapes: one convex hull or a convex decomposition (coacd)."
    )
    friction: float = Field(0.6, ge=0, le=5)
    restitution: float = Field(0.1, ge=0, le=1)


class Distractors(Strict):
    """Objects dropped with the dataset objects that are part of the scene: they occlude and are not
    annotated (BlenderProc's BOP recipe's distractors)."""

    count: IntRange(0) = Field((0, 0), description="Distractors per arrangement, [min, max].")
    objects: list[str] = Field(
        ["random_urdfs/*"],
        description="Built-in objects to draw from (see specsynth.assets.resolve.builtin_objects): names, "
        "'random_urdfs/*' for pybullet_data's 1000 random shapes, 'catalogue/*' for the furniture library's 163 "
        "small items (books, cups, plants, toys; `specsynth furniture`), or one of them as 'catalogue/<id>'. "
        "Empty when `paths` is given and this is not.")
    paths: list[Annotated[str, Field(min_length=1)]] = Field(
        [], max_length=16,
        description="BOP models folders (models_info.json and obj_XXXXXX.ply in millimetres, as objects.path; "
        "relative to the spec, or dataset:NAME/models) whose every model may be drawn as a distractor, with "
        "`objects`: the BOP recipes' distractors from other datasets (T-LESS, YCB-V, ...). A drawn model is named "
        "'bop/<k>/obj_XXXXXX' after its folder's place in this list. Not with annotate.")
    paint: float = Field(
        0.0, ge=0.0, le=1.0,
        description="Share of the distractors painted one random plastic colour (a toy's: mostly yellow, red, blue, some "
        "orange, green and pink; HSV saturation paint_saturation, value 0.6-1), replacing the model's own colours and colour "
        "texture (a plastic: neither metal nor glass): 0 keeps every model's own look. Each distractor is "
        "painted or not by its own draw; an annotated one keeps its model's own colours in bop/models.")
    paint_saturation: FloatRange(0.0, 1.0) = Field(
        (0.6, 0.95),
        description="HSV saturation range of the paint (of the encoded sRGB colour), drawn per painted distractor: "
        "lower it where the real images' toys are duller or fill less of the view (lmo_pbr_h uses 0.45-0.8; "
        "docs/realism.md).")
    annotate: bool = Field(
        False, description="Annotate the distractors too (BOP's 'other objects'): each distractor model gets an obj_id "
        "after the dataset's objects, stable across builds (N + 1 + its position in 'objects'; random_urdfs/k after "
        "the named ones), its model in bop/models, masks, boxes and poses like any object.")

    @field_validator("count")
    @classmethod
    def _count(cls, v):
        if v[1] > MAX_DROPPED:
            raise ValueError(f"at most {MAX_DROPPED} distractors per arrangement")
        return v

    @model_validator(mode="before")
    @classmethod
    def _paths_alone(cls, data):
        """A list of folders without objects means those folders' models only."""
        if isinstance(data, dict) and data.get("paths") and "objects" not in data:
            data = {**data, "objects": []}
        return data

    @model_validator(mode="after")
    def _something_to_draw(self):
        if self.count[1] > 0 and not self.objects and not self.paths:
            raise ValueError("distractors to drop need objects or paths to draw them from")
        if self.annotate and self.paths:
            raise ValueError("annotated distractors from BOP folders are not supported: their models keep their own "
                             "datasets' obj_ids; leave annotate off, or add the folder's models to objects")
        return self

    @model_validator(mode="after")
    def _annotated_catalogue(self):
        if self.annotate and "catalogue/*" in self.objects:
            raise ValueError("annotated distractors need stable obj_ids: list the catalogue items by name "
                             "('catalogue/<id>', see `specsynth furniture`) instead of 'catalogue/*'")
        return self

    def obj_id(self, name: str, n_objects: int) -> int:
        """The obj_id an annotated distractor ``name`` gets when the dataset has ``n_objects`` objects."""
        named = [o for o in self.objects if not o.endswith("/*")]
        if name in named:
            return n_objects + 1 + named.index(name)
        return n_objects + 1 + len(named) + int(name.rsplit("/", 1)[1])

    def name_of(self, obj_id: int, n_objects: int) -> str:
        """Inverse of :meth:`obj_id`."""
        named = [o for o in self.objects if not o.endswith("/*")]
        k = obj_id - n_objects - 1
        return named[k] if k < len(named) else f"random_urdfs/{k - len(named):03d}"


class Arrangements(Strict):
    count: int = Field(10, ge=1, le=10_000_000, description="Number of arrangements (physics drops).")
    drop_height: FloatRange(0.0, 10.0) = Field((0.05, 0.5), description="Initial height above the stage, metres "
                                                "(with placement: drop).")
    placement: Literal["drop", "stand"] = Field(
        "drop", description="How objects and distractors start. drop: drop_height above the stage, falling (a tall "
        "object often lands on its side, as in the paper). stand: resting on the stage in their drawn orientation "
        "(with objects.orientation: canonical, upright as the model stands), then settled by the same simulation: "
        "as objects stand on a real desk, the LM-O test scenes' among them. drop_height is not used.")
    physics: Physics = Physics()
    distractors: Distractors = Field(Distractors(), description="Unannotated objects dropped with the targets.")



# --------------------------------------------------------------------------- cameras


MIN_FOV_DEG, MAX_FOV_DEG = 0.5, 170.0


class Intrinsics(Strict):
    """Pinhole camera; defaults are LM-O's (BOP)."""

    width: int = Field(640, ge=8, le=16384, description="Image width, pixels.")
    height: int = Field(480, ge=8, le=16384, description="Image height, pixels.")
    fx: float = Field(572.4114, gt=0, description="Focal length, pixels: the horizontal field of view it gives "
                      f"must lie in [{MIN_FOV_DEG:g}, {MAX_FOV_DEG:g}] degrees.")
    fy: float = Field(573.57043, gt=0, description="Focal length, pixels (vertical field of view, as fx).")
    cx: float = Field(325.2611)
    cy: float = Field(242.04899)
    clip: FloatRange(positive=True) = Field((0.01, 100.0), description="Near and far clip, metres.")
    distortion: tuple[float, float, float, float, float] | None = Field(
        None, description="Lens distortion, OpenCV's Brown-Conrady coefficients [k1, k2, p1, p2, k3] (unitless, on "
        "normalised image coordinates, as cv2.projectPoints takes them). The image is rendered as an ideal pinhole "
        "over the distorted image's rays, then warped: colour bilinear, masks and depth nearest; cam_K stays the "
        "pinhole K and scene_camera.json adds cam_dist. Coefficients that fold the image are refused.")

    @field_validator("fx", "fy")
    @classmethod
    def _field_of_view(cls, v, info: ValidationInfo):
        size = info.data.get("width" if info.field_name == "fx" else "height")
        if size is None:
            return v
        fov = math.degrees(2 * math.atan(size / (2 * v)))
        if not MIN_FOV_DEG <= fov <= MAX_FOV_DEG:
            raise ValueError(f"gives a field of view of {fov:.3g} degrees over {size} pixels; it must lie in "
                             f"[{MIN_FOV_DEG:g}, {MAX_FOV_DEG:g}] (a pinhole sees nothing useful outside)")
        return v

    @field_validator("distortion")
    @classmethod
    def _lens(cls, v, info: ValidationInfo):
        if v is None or not any(v):
            return None
        from ..model.lens import LensError, check

        d = info.data
        if not all(key in d for key in ("width", "height", "fx", "fy", "cx", "cy")):
            return v  # another field is already wrong
        try:
            check(((d["fx"], 0.0, d["cx"]), (0.0, d["fy"], d["cy"]), (0.0, 0.0, 1.0)), d["width"], d["height"], v)
        except LensError as e:
            raise ValueError(str(e)) from None
        return v



class DepthOfField(Strict):
    """A thin lens focused on the camera's focused object (the one it aims at), drawn per image."""

    aperture: FloatRange(0.0, 500.0) = Field((4.0, 4.0), description="Aperture (entrance pupil) diameter, "
                                             "millimetres, drawn per image in this range: a phone ~2, a 50 mm "
                                             "lens at f/2 25. Blur grows with it.")
    focus_jitter: float = Field(0.0, ge=0, le=10, description="Focus distance moved by up to +/- this many metres "
                                "from the focused object's centre.")

    @field_validator("aperture")
    @classmethod
    def _open(cls, v):
        if v[0] <= 0:
            raise ValueError("an aperture of 0 mm has no depth of field: give a diameter > 0, or remove "
                             "depth_of_field for a pinhole")
        return v


class MotionBlur(Strict):
    """The camera moving during the exposure, drawn per image: a random direction of travel and
    axis of turn. Masks and boxes are the sharp geometry at mid-exposure (the record's pose)."""

    shutter: float = Field(1.0 / 30.0, gt=0, le=10, description="Exposure time, seconds.")
    speed: FloatRange(0.0, 100.0) = Field((0.0, 0.5), description="Camera speed, metres per second, drawn per "
                                          "image (a hand-held camera: up to ~0.5).")
    rotation: FloatRange(0.0, 3600.0) = Field((0.0, 20.0), description="Camera turn rate, degrees per second, drawn "
                                              "per image about a random axis.")

    @model_validator(mode="after")
    def _moves(self):
        if self.speed[1] <= 0 and self.rotation[1] <= 0:
            raise ValueError("motion_blur with no speed and no rotation blurs nothing; give a range above 0 or remove it")
        return self


class Stereo(Strict):
    """A stereo rig: every view also rendered from a right camera, the left moved by ``baseline``
    along its own +x (same orientation, intrinsics, seed, lens and motion)."""

    baseline: float = Field(0.065, gt=0, le=10, description="Distance between the eyes, metres (human ~0.065; "
                            "RealSense D435 0.05).")


class Cameras(Strict):
    per_arrangement: int = Field(5, ge=1, le=100_000, description="Cameras per arrangement.")
    azimuth: FloatRange(-720, 720) = Field((0.0, 360.0), description="Azimuth around the focused object, degrees.")
    elevation: FloatRange(-90, 90) = Field((10.0, 80.0), description="Elevation above the stage plane, degrees.")
    elevation_sampling: Literal["angle", "area"] = Field(
        "angle", description="How elevations are drawn in their range: 'angle', uniform in degrees; 'area', camera "
        "positions uniform over the area of the viewing sphere's band, so low elevations come more often (the "
        "band is wider there), as a view sphere is sampled in the BOP toolkit. `specsynth fit` picks the one "
        "nearer a real test set's elevations.")
    distance: FloatRange(0.02, 1e4) = Field((0.4, 1.2), description="Distance to the focused object's centre, metres (at least 2 cm: nearer is inside the object).")
    inplane: FloatRange(-360, 360) = Field((0.0, 0.0), description="In-plane rotation about the optical axis, degrees.")
    aim_offset: FloatRange(0.0, 1.0) = Field(
        (0.0, 0.0), description="Where the focused object's centre appears: 0 at the principal point (the paper's "
        "cameras point at it), 1 on the largest ellipse about the principal point inside the image; drawn per "
        "camera uniform in this range, in a uniform direction. Above 0 the focused object is no longer always in "
        "the middle of the image, as in photographs of a desk.")
    max_tries: int = Field(10, ge=1, le=1000, description="Camera resamples before a view is dropped.")
    depth_of_field: DepthOfField | None = Field(
        None, description="Defocus blur: a thin lens focused on the focused object. Masks and boxes stay those of "
        "the sharp geometry (the pinhole through the lens centre).")
    stereo: Stereo | None = Field(
        None, description="Render every view as a left/right pair; the right eye is written as the split "
        "'<split>_right' (BOP, COCO) and parquet/*_right.parquet, with the same image ids and its own annotations.")
    motion_blur: MotionBlur | None = Field(
        None, description="Camera motion during the exposure (a random translation and turn per image).")
    clearance: float = Field(
        0.05, ge=0, le=10,
        description="Metres of free space a camera needs around it (nearest surface along the six axes); "
        "a camera inside a wall, furniture or an object is resampled. 0 turns the check off.",
    )



class Visibility(Strict):
    threshold: float = Field(0.3, ge=0, le=1, description="Min visible fraction of the focused object.")
    delta: float = Field(0.005, gt=0, le=1, description="Depth tolerance for visibility (BOP), metres.")
    near_share: float = Field(
        1.0, ge=0, le=1,
        description="Most of the image that may lie nearer than near_distance (a wall, a shelf, a chair back "
        "or a bottle filling the view in front of the objects, which a photographer would step around); "
        "a camera over it is drawn again. 1 turns the check off.",
    )
    near_distance: float = Field(
        0.5, gt=0, le=1,
        description="'Near' for near_share, as a fraction of the camera's distance to its target, along the "
        "optical axis.",
    )


# --------------------------------------------------------------------------- quality


class QualityPreset(Strict):
    """The paper's Arnold parameters (supplement table); backends map them to their own settings."""

    aa: int = Field(ge=1, le=4096, description="Camera rays per pixel (Arnold AA samples).")
    diffuse_rays: int = Field(ge=1, le=4096)
    specular_rays: int = Field(ge=1, le=4096)
    diffuse_depth: int = Field(ge=0, le=64)
    specular_depth: int = Field(ge=0, le=64)
    max_depth: int = Field(ge=1, le=128)

    @property
    def samples(self) -> int:
        """Samples per pixel of a path tracer: max(AA, diffuse rays, specular rays), which keeps
        the paper's cost ratio between levels (README, "Backends and quality")."""
        return max(self.aa, self.diffuse_rays, self.specular_rays)


class QualityOverride(Strict):
    aa: int | None = Field(None, ge=1, le=4096)
    diffuse_rays: int | None = Field(None, ge=1, le=4096)
    specular_rays: int | None = Field(None, ge=1, le=4096)
    diffuse_depth: int | None = Field(None, ge=0, le=64)
    specular_depth: int | None = Field(None, ge=0, le=64)
    max_depth: int | None = Field(None, ge=1, le=128)


PAPER_PRESETS: dict[str, QualityPreset] = {
    "low": QualityPreset(aa=1, diffuse_rays=1, specular_rays=1, diffuse_depth=1, specular_depth=1, max_depth=2),
    "medium": QualityPreset(aa=9, diffuse_rays=36, specular_rays=36, diffuse_depth=3, specular_depth=2, max_depth=3),
    "high": QualityPreset(aa=25, diffuse_rays=225, specular_rays=100, diffuse_depth=3, specular_depth=3, max_depth=4),
}


class Quality(Strict):
    level: Literal["low", "medium", "high", "paper_low", "paper_medium", "paper_high"] = Field(
        "low", description="low/medium/high: at least the paper presets' image error at the least cost on the "
        "backend (its calibrated samples, denoising and supersampling, tabled in docs/quality.md); "
        "paper_low/paper_medium/paper_high: the paper's raw settings, for its experiments.")
    presets: dict[Literal["low", "medium", "high"], QualityOverride] = Field(
        default_factory=dict, description="Overrides of the paper's preset numbers, per level."
    )
    clamp: float | None = Field(None, gt=0, description="Clamp indirect sample radiance (fireflies).")
    control: Literal["samples", "error"] = Field(
        "samples", description="samples: every image gets the level's calibrated samples (docs/quality.md). "
        "error: every image is rendered as pairs of independent renders until its estimated error reaches the "
        "paper preset's at that image (docs/quality.md#error-targets); each image records its samples and error.")
    max_samples: int | None = Field(
        None, ge=2, le=65536, description="control: error: the most samples per pixel one image may take "
        "(all its renders together); default twice the paper preset's samples.")

    @property
    def paper_level(self) -> str:
        """low/medium/high: the paper level whose light paths (and error) this level has."""
        return self.level.removeprefix("paper_")

    @property
    def calibrated(self) -> bool:
        return not self.level.startswith("paper_")

    def resolved(self) -> QualityPreset:
        base = PAPER_PRESETS[self.paper_level].model_dump()
        over = self.presets.get(self.paper_level)
        if over is not None:
            base.update({k: v for k, v in over.model_dump().items() if v is not None})
        return QualityPreset(**base)


# --------------------------------------------------------------------------- backends


class BackendOptions(Strict):
    """The options every backend takes. A backend plugin's own options model subclasses this with
    ``name: Literal[<its name>]``; the spec's ``backend`` block is validated by the installed
    plugin's model (see ``plugins.py``), so a backend can be swapped with ``backend.name`` alone."""

    name: str = Field(description="Installed backend plugin (see `specsynth backends`).")
    denoise: bool = Field(
        False, description="Denoise the beauty pass (OpenImageDenoise with albedo and normal passes). "
        "Backends whose renders carry no sampling noise accept it and do nothing.",
    )
    denoise_quality: Literal["fast", "balanced", "high"] = Field(
        "high", description="OpenImageDenoise filter quality: 'balanced' costs about half of 'high' on the CPU.")
    denoise_prefilter: Literal["none", "fast", "accurate"] = Field(
        "none", description="How OpenImageDenoise treats its albedo and normal guides: 'none' takes them as clean "
        "(noise in them stays in the image as grain), 'fast' denoises them with the image, 'accurate' denoises them "
        "first in passes of their own. Backends that take the option say what each costs.")
    samples: int | None = Field(None, ge=1, le=1_000_000, description="Override the preset-derived sample count "
                                "(under quality.control: error, the first pair's samples per render).")
    supersample: int = Field(
        1, ge=1, le=4, description="F: render each image at F times its resolution and average each F x F block "
        "of pixels; `samples` are per pixel of the larger image, F^2 x samples per pixel of the image. A denoiser "
        "then sees every feature over more pixels and keeps more of it (docs/quality.md, 'Supersampling'). "
        "Annotations stay exact. Not under quality.control: error, whose images are rendered at their own "
        "resolution, nor on a backend without sampling noise.")

    def input_folders(self) -> dict[str, str]:
        """Folders (other than assets) whose files change renders, by option name: the compiler
        checks that each exists and holds files, and fingerprints them."""
        return {}

    def relative_to(self, spec_dir) -> "BackendOptions":
        """These options with relative paths resolved against the spec's folder."""
        return self


def _backend_name(v: Any) -> str | None:
    return v.get("name") if isinstance(v, dict) else getattr(v, "name", None)


def _backend_options(v: Any) -> Any:
    from ..plugins import PluginNotFound, backend_plugin

    name = _backend_name(v)
    if not isinstance(name, str):
        return v  # the base model reports the missing or mistyped name
    try:
        plugin = backend_plugin(name)
    except PluginNotFound as e:
        raise ValueError(str(e)) from None
    if isinstance(v, plugin.options):
        return v
    if isinstance(v, BaseModel):
        v = v.model_dump()
    return plugin.options.model_validate(v)


class Augment(Strict):
    brightness: float = Field(0.0, ge=0, le=1, description="Max relative brightness change.")
    contrast: float = Field(0.0, ge=0, le=1)
    hue: float = Field(0.0, ge=0, le=0.5, description="Max hue shift, fraction of the colour wheel.")
    saturation: float = Field(0.0, ge=0, le=1)
    noise_std: float = Field(0.0, ge=0, le=0.5, description="Gaussian noise std, in [0,1] intensity.")
    blur_sigma: FloatRange(0.0, 50.0) = Field((0.0, 0.0), description="Gaussian blur sigma range, pixels.")


# --------------------------------------------------------------------------- sensor


MAX_AXIAL_NOISE = 1.0


class DepthSensor(Strict):
    """An RGB-D depth camera's errors, applied to a copy of the exact depth (written to depth_noisy/)."""

    axial_noise: tuple[float, float] = Field(
        (0.0012, 0.0019), description="Axial noise std = a + b * z^2, metres (z in metres); "
        "the default is a structured-light sensor's (Kinect-like).")
    edge_holes: int = Field(1, ge=0, le=20, description="Pixels next to a depth jump (> 5 % of the depth) left empty, "
                            "as stereo and structured light lose them (shadows, mixed pixels).")
    dropout: float = Field(0.0, ge=0, le=1, description="Fraction of pixels randomly left empty.")
    quantisation: float = Field(0.001, ge=0, le=0.1, description="Depth step, metres (0 = none).")

    @field_validator("axial_noise")
    @classmethod
    def _non_negative(cls, v):
        if min(v) < 0 or not all(math.isfinite(x) for x in v):
            raise ValueError("axial noise coefficients must be finite and >= 0")
        if max(v) > MAX_AXIAL_NOISE:  # past this the noise swamps the depth and overflows float32
            raise ValueError(f"axial noise coefficients above {MAX_AXIAL_NOISE:g} (metres, and per square "
                             "metre) are no sensor's")
        return v


class Sensor(Strict):
    """A camera's sensor and processing, applied to every rendered image; seed-locked, off by default."""

    shot_noise: float = Field(0.0, ge=0, le=1, description="Photon noise: std = shot_noise * sqrt(linear value), "
                              "linear units (0.02 ~ a good phone camera in daylight).")
    read_noise: float = Field(0.0, ge=0, le=0.5, description="Signal-independent Gaussian noise std, linear units.")
    exposure: FloatRange(-5.0, 5.0) = Field((0.0, 0.0), description="Exposure jitter, stops: the image is scaled by "
                                            "2^u, u drawn in this range.")
    white_balance: FloatRange(1500.0, 15000.0) | None = Field(
        None, description="White-balance error: the camera balances for a light drawn in this range (kelvin) while "
        "the scene is lit as rendered; channels scale by 6500 K's colour over it.")
    auto_white_balance: bool = Field(
        False, description="Balance each image for the light in view, as a camera's auto white balance does: the "
        "illuminant is the render over the view's albedo (diffuse colour), so a grey surface comes out grey "
        "under a 2700 K lamp and wood stays wood (gains limited to [0.2, 5]).")
    auto_exposure: bool = Field(
        False, description="Meter each image as a camera's auto exposure does: scale it so the geometric mean of its "
        "luminance over 4x4-pixel zones is middle grey (0.18 linear), by a factor within [1/16, 16]; applied before "
        "'exposure' jitter. Zones, not pixels: a camera meters the light, not a few-sample render's noise.")
    blur: FloatRange(0.0, 20.0) | None = Field(
        None, description="Optical softness (lens, anti-aliasing filter, demosaicking): a Gaussian blur of sigma "
        "pixels, drawn per image in this range, applied to the linear image before noise. `specsynth fit` sets it "
        "from real photographs' edge sharpness.")
    saturation: float = Field(1.0, ge=0.0, le=3.0, description="Colour saturation of the camera's processing: each "
                              "pixel's linear colour moved from its luminance by this factor (1: as rendered), after "
                              "noise. `specsynth fit` sets it from real photographs.")
    contrast: float = Field(1.0, ge=0.5, le=4.0, description="The camera's tone curve, applied to the sRGB-encoded "
                            "image: the S-curve v^k / (v^k + (1 - v)^k) with k = contrast (1: none), which darkens "
                            "shadows and brightens highlights around mid-grey as a camera's image processor does. "
                            "`specsynth fit` sets it from real photographs.")
    sharpening: float = Field(0.0, ge=0.0, le=4.0, description="The camera's sharpening, last in its processing: an "
                              "unsharp mask of this amount on the encoded image's luma (a Gaussian of 1 pixel), "
                              "which draws dark and bright halos along edges as real cameras' image processors do "
                              "(0: none). `specsynth fit` sets it from real photographs' halos.")
    vignetting: float = Field(0.0, ge=0.0, le=0.95, description="Light the lens loses towards the image corners: "
                              "the corners keep 1 - vignetting of the centre's (0: none), falling off as a lens's "
                              "cos^4 law from the image centre. Applied to the linear image after exposure (the exposure "
                              "`specsynth fit` finds is for the vignetted image), before blur and noise. `specsynth fit` sets it from real "
                              "photographs' dark corners.")
    jpeg_quality: IntRange(1) | None = Field(None, description="JPEG quality drawn per image in this range "
                                             "(outputs.image_format jpg); else outputs.jpeg_quality.")
    depth: DepthSensor | None = Field(None, description="Also write a noisy depth map like an RGB-D sensor's.")

    @field_validator("jpeg_quality")
    @classmethod
    def _quality(cls, v):
        if v is not None and v[1] > 100:
            raise ValueError("JPEG quality is at most 100")
        return v

    @property
    def affects_rgb(self) -> bool:
        return bool(self.shot_noise or self.read_noise or self.exposure != (0.0, 0.0) or self.white_balance
                    or self.auto_white_balance or self.auto_exposure or (self.blur and self.blur[1] > 0)
                    or self.saturation != 1.0 or self.contrast != 1.0 or self.sharpening > 0
                    or self.vignetting > 0)


# --------------------------------------------------------------------------- outputs


class Outputs(Strict):
    """What a build writes. Besides the fields below, every installed output has a switch here,
    ``<name>: true | false``: per-view products (depth, masks, normals, ...) and dataset formats
    (bop, coco, parquet, ...), each a plugin (`specsynth outputs` lists them)."""

    # The installed outputs this model has a switch for (set on the model built from them, see
    # ``outputs_model``); the base model has none.
    registered: ClassVar[dict[str, Any]] = {}

    image_format: Literal["jpg", "png"] = "jpg"
    jpeg_quality: int = Field(95, ge=1, le=100)
    depth_scale: float | Literal["auto"] = Field(
        0.1, description="BOP depth scale: uint16 value * depth_scale = millimetres; 'auto' fits the range."
    )
    chunk_size: int = Field(1000, ge=1, le=100_000, description="Images per BOP chunk folder.")

    @field_validator("depth_scale")
    @classmethod
    def _ds(cls, v):
        if v != "auto" and not (1e-3 <= v <= 1000):  # 1e-3: uint16 then holds 65.5 mm, as fine as depth gets
            raise ValueError("depth_scale must be in [0.001, 1000] mm per unit, or 'auto'")
        return v

    @model_validator(mode="after")
    def _needs(self):
        for name, switch in sorted(self.registered.items()):
            missing = [n for n in switch.needs if getattr(self, name, False) and not getattr(self, n, False)]
            if missing:
                raise ValueError(f"{name} reads what {missing[0]} writes: switch on {missing[0]} too, or {name} off")
        return self

    def selected(self, kind: str) -> tuple[str, ...]:
        """The switched-on outputs of ``kind`` ("product" or "writer"), by name."""
        return tuple(n for n, s in sorted(self.registered.items()) if s.kind == kind and getattr(self, n))

    @property
    def products(self) -> tuple[str, ...]:
        """The per-view products switched on: what the render jobs write besides the image."""
        return self.selected("product")

    def __reduce__(self):
        # The model with the switches is made at run time (``outputs_model``): pickle by value and
        # validate again on the other side, against what is installed there.
        return _registered_outputs, (self.model_dump(),)


@functools.cache
def outputs_model(switches: tuple = ()) -> type[Outputs]:
    """``Outputs`` with a boolean field per installed output that has a switch (``switches``:
    ``plugins.output_switches()``): unknown names are unknown fields, and the JSON Schema and the
    reference list what is installed."""
    kind = {"product": "Per-view product", "writer": "Dataset format"}
    fields = {s.name: (bool, Field(s.default, description=f"{kind[s.kind]}. {s.description}"))
              for s in switches if s.switch}
    model = create_model("Outputs", __base__=Outputs, __doc__=Outputs.__doc__, **fields)
    model.registered = {s.name: s for s in switches if s.switch}
    return model


def installed_outputs_model() -> type[Outputs]:
    from ..plugins import output_switches

    return outputs_model(output_switches())


def _registered_outputs(v: Any) -> Any:
    model = installed_outputs_model()
    if not any(s.kind == "writer" for s in model.registered.values()):
        # Without its own entry points a build would write the images and no dataset at all.
        raise ValueError("no dataset writer is installed: specsynth's own entry points are missing or out of "
                         "date; reinstall it (pip install -e . in its repository, or make install)")
    if isinstance(v, model):
        return v
    if isinstance(v, BaseModel):
        v = v.model_dump()
    return model.model_validate({} if v is None else v)


# --------------------------------------------------------------------------- dataset metadata


class License(Strict):
    name: str = Field("unspecified", max_length=200, description="Licence of the dataset's images.")
    url: str = Field("", max_length=500, description="Where the licence text is.")


class Metadata(Strict):
    """What COCO's ``info``/``licenses`` and dataset cards carry. Dates come from here, never from
    the clock, so that two builds of one spec stay byte-identical."""

    version: str = Field("1.0", max_length=100, description="Dataset version (COCO info.version).")
    date_created: datetime.date = Field(
        datetime.date(1970, 1, 1),
        description="Release date (YYYY-MM-DD): COCO info.date_created and every image's date_captured. "
        "The default 1970-01-01 means 'not set'.",
    )
    contributor: str = Field("", max_length=200, description="COCO info.contributor.")
    url: str = Field("", max_length=500, description="COCO info.url.")
    license: License = License()

    @field_validator("version", mode="before")
    @classmethod
    def _version_as_text(cls, v):
        # YAML reads `version: 1.0` as a float; quote it ('1.10') when the digits matter.
        return str(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else v


# --------------------------------------------------------------------------- the spec


class DatasetSpec(Strict):
    """A synthetic dataset: objects dropped with physics onto stages of scenes, seen by cameras."""

    version: Literal[1] = Field(SPEC_VERSION, description="Spec language version.")
    name: str = Field(pattern=r"^[A-Za-z0-9_.\-]+$", max_length=128, description="Dataset name.")
    seed: int = Field(0, ge=0, lt=2**63, description="Root seed; every job seed derives from it.")
    split: str = Field("train_pbr", pattern=r"^[A-Za-z0-9_\-]+$", max_length=64, description="BOP split name.")
    intrinsics: Intrinsics = Intrinsics()
    objects: Objects
    scenes: list[SceneRef] = Field(min_length=1)
    arrangements: Arrangements = Arrangements()
    cameras: Cameras = Cameras()
    visibility: Visibility = Visibility()
    quality: Quality = Quality()
    sensor: Sensor = Field(Sensor(), description="Sensor noise, exposure, white balance, JPEG quality, RGB-D depth errors.")
    backend: SerializeAsAny[BackendOptions] = Field(
        description="Render backend and its options, validated by the installed plugin named by 'name'."
    )
    outputs: SerializeAsAny[Outputs] = Field(
        default_factory=Outputs, validate_default=True,
        description="What a build writes: the files' format, and a switch per installed output.")
    metadata: Metadata = Metadata()

    @field_validator("backend", mode="before")
    @classmethod
    def _plugin_options(cls, v):
        return _backend_options(v)

    @field_validator("outputs", mode="before")
    @classmethod
    def _installed_outputs(cls, v):
        return _registered_outputs(v)


def json_schema(backends: tuple[str, ...] | None = None) -> dict:
    """The spec's schema with the options of every installed backend plugin (or of ``backends``)
    under ``backend``, and a switch per installed output under ``outputs``."""
    from ..plugins import installed_backend_plugins

    plugins = [p for p in installed_backend_plugins() if backends is None or p.name in backends]
    fields: dict[str, Any] = {"outputs": (installed_outputs_model(), Field(
        default_factory=Outputs, description=DatasetSpec.model_fields["outputs"].description))}
    if plugins:
        tagged = tuple(Annotated[p.options, Tag(p.name)] for p in plugins)
        one = plugins[0].options if len(plugins) == 1 else Annotated[Union[tagged], Discriminator(_backend_name)]
        fields["backend"] = (one, Field(description=DatasetSpec.model_fields["backend"].description))
    model = create_model("DatasetSpec", __base__=DatasetSpec, __doc__=DatasetSpec.__doc__, **fields)
    schema = model.model_json_schema()
    schema["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    schema["title"] = "specsynth dataset spec"
    return schema
