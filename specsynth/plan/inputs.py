"""What each stage's jobs read, cut out of the spec: ``ArrangeInputs``, ``ViewInputs``, ``RenderInputs``.

A stage's workers get its inputs model and nothing else of the spec, and its cache key is the
digest of that model (``compiler.compile_spec``). A field a stage's code reads is therefore in its
key by construction: there is no list of field names to keep in step with the code.

Each field names where it is cut from (``From``), relative to the value its model is cut from
(the spec for a stage's inputs). A field whose type is itself a ``Cut`` model is cut recursively:
``RenderInputs.outputs`` takes only the output switches that change rendered bytes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated, Any, Iterator, Literal, Mapping, Union, get_args, get_origin

from pydantic import BaseModel, ConfigDict, SerializeAsAny

from ..spec.models import (
    BackendOptions,
    BuiltinObject,
    DatasetSpec,
    DepthOfField,
    Distractors,
    Intrinsics,
    Material,
    MeshObject,
    MotionBlur,
    Objects,
    Physics,
    Quality,
    SceneRef,
    Sensor,
    Stereo,
    Visibility,
    installed_outputs_model,
)


@dataclass(frozen=True)
class From:
    """Where a field is cut from: a dotted path into the value its model is cut from ('' for the
    value itself)."""

    path: str


class Cut(BaseModel):
    """A frozen model whose fields are cut out of a larger one (see ``From``)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    @classmethod
    def sources(cls) -> dict[str, str]:
        """Field name -> the path it is cut from."""
        out = {}
        for name, info in cls.model_fields.items():
            found = [m for m in info.metadata if isinstance(m, From)]
            if len(found) != 1:
                raise TypeError(f"{cls.__name__}.{name} says where it is cut from with one From(...)")
            out[name] = found[0].path
        return out

    @classmethod
    def cut(cls, source: Any) -> "Cut":
        values = {}
        for name, path in cls.sources().items():
            value = _get(source, path)
            sub = _cut_type(cls.model_fields[name].annotation)
            values[name] = sub.cut(value) if sub is not None else value
        return cls(**values)

    @classmethod
    def spec_paths(cls, prefix: str = "", nested: bool = True) -> Iterator[tuple[str, str]]:
        """(field name, spec path) of every leaf this model takes; ``nested=False`` leaves out the
        fields that are another stage's whole inputs (``ViewInputs.arrange``)."""
        for name, path in cls.sources().items():
            full = ".".join(p for p in (prefix, path) if p)
            sub = _cut_type(cls.model_fields[name].annotation)
            if sub is None:
                yield name, full
            elif issubclass(sub, StageInputs):
                if nested:
                    yield from sub.spec_paths(full)
            else:
                yield from ((f"{name}.{n}", p) for n, p in sub.spec_paths(full))


class StageInputs(Cut):
    """Everything one stage's jobs read of the spec."""

    def digest_parts(self) -> dict[str, Any]:
        """Spec path -> this stage's own value there (not its upstream stage's), for telling which
        inputs changed between two builds."""
        dumped = self.model_dump(mode="json")
        return {f"spec:{path}": _get(dumped, name) for name, path in self.spec_paths(nested=False)}


def _get(source: Any, path: str) -> Any:
    for part in path.split(".") if path else ():
        source = source[part] if isinstance(source, dict) else getattr(source, part)
    return source


def _cut_type(annotation) -> type[Cut] | None:
    """The Cut model a field holds, if it holds one."""
    if get_origin(annotation) is Annotated:
        annotation = get_args(annotation)[0]
    return annotation if isinstance(annotation, type) and issubclass(annotation, Cut) else None


class ArrangementDraws(Cut):
    """How each arrangement is dropped (how many there are is the plan's, ``PLANNED``)."""

    drop_height: Annotated[tuple[float, float], From("drop_height")]
    placement: Annotated[Literal["drop", "stand"], From("placement")]
    physics: Annotated[Physics, From("physics")]
    distractors: Annotated[Distractors, From("distractors")]


class ObjectDraws(Cut):
    """Which object models an arrangement drops and how many; not their materials, which only
    renders read (``RenderInputs.materials``): a new colour gain renders again and settles nothing."""

    path: Annotated[str | None, From("path")]
    ids: Annotated[list[int] | None, From("ids")]
    builtin: Annotated[list[Union[str, BuiltinObject]], From("builtin")]
    meshes: Annotated[list[MeshObject], From("meshes")]
    instances: Annotated[tuple[int, int], From("instances")]
    orientation: Annotated[Literal["canonical", "random"], From("orientation")]
    models_per_arrangement: Annotated[tuple[int, int] | None, From("models_per_arrangement")]

    def with_materials(self, materials: Mapping[str, Material]) -> Objects:
        """The spec's objects with ``materials`` as their overrides (none: each model's own look)."""
        return Objects(**dict(self), materials=dict(materials))


class ArrangeInputs(StageInputs):
    """The arrange step's: what is dropped, where, how. Views and renders rebuild an arrangement's
    scene from its record with these too (its key is their upstream key)."""

    seed: Annotated[int, From("seed")]
    objects: Annotated[ObjectDraws, From("objects")]
    scenes: Annotated[tuple[SceneRef, ...], From("scenes")]
    arrangements: Annotated[ArrangementDraws, From("arrangements")]


class CameraDraws(Cut):
    """How cameras are drawn around an arrangement (their optics are the render's)."""

    per_arrangement: Annotated[int, From("per_arrangement")]
    azimuth: Annotated[tuple[float, float], From("azimuth")]
    elevation: Annotated[tuple[float, float], From("elevation")]
    elevation_sampling: Annotated[str, From("elevation_sampling")]
    distance: Annotated[tuple[float, float], From("distance")]
    inplane: Annotated[tuple[float, float], From("inplane")]
    aim_offset: Annotated[tuple[float, float], From("aim_offset")]
    max_tries: Annotated[int, From("max_tries")]
    clearance: Annotated[float, From("clearance")]


class ViewInputs(StageInputs):
    """The view step's: how cameras are drawn and accepted."""

    arrange: Annotated[ArrangeInputs, From("")]
    cameras: Annotated[CameraDraws, From("cameras")]
    visibility: Annotated[Visibility, From("visibility")]
    intrinsics: Annotated[Intrinsics, From("intrinsics")]


class RenderedFiles(Cut):
    """The output settings that decide which files a render writes and their bytes: the image's
    format and the per-view products switched on (the dataset formats, written by the merge, are
    not among them)."""

    image_format: Annotated[Literal["jpg", "png"], From("image_format")]
    jpeg_quality: Annotated[int, From("jpeg_quality")]
    depth_scale: Annotated[float | Literal["auto"], From("depth_scale")]
    products: Annotated[tuple[str, ...], From("products")]


class RenderInputs(StageInputs):
    """The render step's: the objects' materials, the renderer and its quality, the camera's optics,
    the sensor, the files."""

    arrange: Annotated[ArrangeInputs, From("")]
    materials: Annotated[dict[str, Material], From("objects.materials")]
    intrinsics: Annotated[Intrinsics, From("intrinsics")]
    stereo: Annotated[Stereo | None, From("cameras.stereo")]
    depth_of_field: Annotated[DepthOfField | None, From("cameras.depth_of_field")]
    motion_blur: Annotated[MotionBlur | None, From("cameras.motion_blur")]
    visibility_delta: Annotated[float, From("visibility.delta")]
    quality: Annotated[Quality, From("quality")]
    # SerializeAsAny: the plugin's own options (a subclass) are part of the key.
    backend: Annotated[SerializeAsAny[BackendOptions], From("backend")]
    sensor: Annotated[Sensor, From("sensor")]
    outputs: Annotated[RenderedFiles, From("outputs")]


STAGE_INPUTS: dict[str, type[StageInputs]] = {"arrange": ArrangeInputs, "view": ViewInputs, "render": RenderInputs}

# Spec fields that decide how many jobs there are but not what any job makes: changing one adds or
# drops jobs and re-runs none.
PLANNED = {
    "arrangements.count": "how many arrangements: each one's objects, cameras and images depend on its "
                          "own index and seed, not on how many others there are",
}

# Spec fields no job reads, and why: changing one re-runs nothing (the merge rewrites the dataset).
WRITTEN_ONLY = {
    "version": "the spec language's version, checked when the spec is read",
    "name": "the dataset's name, in the files the merge writes",
    "split": "the BOP split's folder name, chosen by the merge",
    "metadata": "COCO info and dataset cards, written by the merge",
    "outputs.chunk_size": "how the merge groups images into BOP chunk folders",
}
# Besides these, every ``outputs.<name>`` switch of a dataset writer (bop, coco, ...) is read by no
# job: the merge runs the writers. A per-view product's switch is the renders' (``products``).


class BuildInputs(BaseModel):
    """The three stages' inputs of one spec: what a build hands its workers instead of the spec."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    arrange: ArrangeInputs
    view: ViewInputs
    render: RenderInputs

    @classmethod
    def of(cls, spec: DatasetSpec) -> "BuildInputs":
        return cls(**{stage: model.cut(spec) for stage, model in STAGE_INPUTS.items()})


def stage_of_field(dotted: str) -> str | None:
    """The first stage whose jobs read a spec field (every later stage re-runs with it); None for
    fields no job reads (``PLANNED``, ``WRITTEN_ONLY``, a dataset writer's switch)."""
    head, _, name = dotted.partition(".")
    if head == "outputs":
        switch = installed_outputs_model().registered.get(name)
        if switch is not None:
            return "render" if switch.kind == "product" else None
    for stage, model in STAGE_INPUTS.items():
        for _, path in model.spec_paths():
            if dotted == path or dotted.startswith(path + ".") or path.startswith(dotted + "."):
                return stage
    return None


def unread_fields(model: type[BaseModel] = DatasetSpec, prefix: str = "") -> list[str]:
    """Spec fields neither in some stage's inputs nor in ``PLANNED`` or ``WRITTEN_ONLY``: a field
    added to the spec lands here until it is given to the stages that read it, or said to be
    read by no job."""
    taken = {path for m in STAGE_INPUTS.values() for _, path in m.spec_paths()} | set(PLANNED)
    missing = []
    for name, info in model.model_fields.items():
        path = f"{prefix}{name}"
        if path in taken or path in WRITTEN_ONLY or any(path.startswith(t + ".") for t in taken):
            continue
        inner = info.annotation
        if any(t.startswith(path + ".") for t in taken | set(WRITTEN_ONLY)) and isinstance(inner, type) \
                and issubclass(inner, BaseModel):
            missing += unread_fields(inner, path + ".")
        else:
            missing.append(path)
    return missing
