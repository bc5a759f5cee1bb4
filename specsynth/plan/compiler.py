"""Spec -> job graph. Imports no renderer, simulator or executor (enforced by import-linter).

The graph is lazy: jobs are generated from (arrangement, camera) indices on demand, so a spec with
a million images compiles in seconds and little memory. Every job has a stable id, a seed that
depends only on the root seed and that id (``specsynth.plan.seeds``), and a content key
(``specsynth.plan.keys``) over exactly the inputs it reads.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

from ..assets import bopdistractors
from ..assets.resolve import (
    AssetError,
    bop_folder_notes,
    builtin_objects,
    catalogue_objects,
    check_photo,
    check_texture,
    expand_path,
    file_digest,
    object_fingerprints,
    object_size_problems,
)
from ..model import error as error_control
from ..output_api import active_products
from ..plugins import backend_plugin, dist_version, output_fingerprint
from ..scenes import FIXED_ROOMS, PROCEDURAL, declares_stages, generated_name, scene_fingerprint, stage_table

GENERATED = PROCEDURAL + FIXED_ROOMS
from ..spec.models import DatasetSpec
from ..spec.yamlio import LoadedSpec, SpecError
from . import keys, seeds
from .inputs import BuildInputs, stage_of_field  # noqa: F401 (stage_of_field: the docs' reference)

STAGES = ("arrange", "view", "render")


# Guards on work and memory, checked before anything runs (overridable: the estimate is rough).
MAX_IMAGES = 100_000_000
BYTES_PER_PIXEL = 200  # per worker: renderer film and passes (~160 B/px in Cycles) + annotation buffers
MAX_WORKER_BYTES = 8 << 30
# Objects dropped in one arrangement: every one is a rigid body settling against the others, and
# a pile of thousands never settles within max_time (10^6 instances validated and never ended).
MAX_OBJECTS = 500


def _limit(env: str, default: float) -> float:
    value = os.environ.get(env)
    try:
        return float(value) if value else default
    except ValueError:
        return default


def check_budgets(spec: DatasetSpec, loaded: LoadedSpec) -> list:
    """Located problems for a plan or an image too large to build on purpose."""
    problems = []
    images = spec.arrangements.count * spec.cameras.per_arrangement
    max_images = _limit("SPECSYNTH_MAX_IMAGES", MAX_IMAGES)
    if images > max_images:
        problems.append(loaded.locate("arrangements.count", f"{images:,} images planned, over the limit of "
                                      f"{int(max_images):,} (set SPECSYNTH_MAX_IMAGES to raise it)"))
    px = spec.intrinsics.width * spec.intrinsics.height
    need = px * BYTES_PER_PIXEL
    max_bytes = _limit("SPECSYNTH_MAX_WORKER_GB", MAX_WORKER_BYTES / (1 << 30)) * (1 << 30)
    if need > max_bytes:
        problems.append(loaded.locate("intrinsics.width", f"a {spec.intrinsics.width} x {spec.intrinsics.height} image "
                                      f"needs about {need / (1 << 30):.1f} GiB per worker ({BYTES_PER_PIXEL} B/pixel), over "
                                      f"the limit of {max_bytes / (1 << 30):.1f} GiB (set SPECSYNTH_MAX_WORKER_GB to raise it)"))
    return problems


def check_objects(spec: DatasetSpec, loaded: LoadedSpec, n_models: int) -> list:
    """A located problem when an arrangement may drop more objects than physics can settle."""
    objects = spec.objects
    models = objects.models_per_arrangement[1] if objects.models_per_arrangement else n_models
    most = objects.instances[1] * min(models, n_models) + spec.arrangements.distractors.count[1]
    limit = _limit("SPECSYNTH_MAX_OBJECTS", MAX_OBJECTS)
    if most <= limit:
        return []
    return [loaded.locate("objects.instances", f"up to {most:,} objects per arrangement ({objects.instances[1]} "
                          f"instances x {min(models, n_models)} models + {spec.arrangements.distractors.count[1]} "
                          f"distractors), over the limit of {int(limit):,} (set SPECSYNTH_MAX_OBJECTS to raise it)")]


def check_room_categories(ref, i: int, loaded: LoadedSpec) -> list:
    """A located problem for each ``room.categories`` entry the furniture catalogue does not have
    (the build would otherwise fail later, on a room that found no furniture)."""
    if ref.room is None or not ref.room.categories:
        return []
    from ..assets.library.furniture import LibraryError, catalogue

    try:
        known = {item.category for item in catalogue()}
    except LibraryError:
        return []  # no catalogue installed: the build names it
    return [loaded.locate(f"scenes.{i}.room.categories.{k}", f"no furniture category {name!r}; the catalogue has "
                          f"{', '.join(sorted(known))}")
            for k, name in enumerate(ref.room.categories) if name not in known]


def check_capabilities(spec: DatasetSpec, loaded: LoadedSpec) -> list:
    """Located problems for a camera effect the spec's backend cannot render, supersampling where
    it has no samples to average, or an error target it cannot keep (``error_control_problems``)."""
    problems = []
    plugin = backend_plugin(spec.backend.name)
    caps = plugin.capabilities
    for name, what in (("depth_of_field", "depth of field"), ("motion_blur", "motion blur")):
        if getattr(spec.cameras, name) is not None and not getattr(caps, name):
            problems.append(loaded.locate(f"cameras.{name}", f"backend {spec.backend.name!r} cannot render {what} (its "
                                          f"plugin does not declare it); remove {name} or use one that does "
                                          "(`specsynth backends`)"))
    if spec.backend.supersample > 1 and not caps.sampling_noise:
        problems.append(loaded.locate("backend.supersample", f"backend {spec.backend.name!r} has no sampling noise "
                                      "to average (its plugin does not declare sampling_noise), and its filters "
                                      "work in pixels of the image it renders; remove backend.supersample"))
    return problems + (error_control_problems(spec, loaded) if spec.quality.control == "error" else [])


def error_control_problems(spec: DatasetSpec, loaded: LoadedSpec) -> list:
    """Located problems of ``quality.control: error``: no sampling noise to control, supersampling
    beside it, or a budget no pair of the backend's sample counts fits."""
    plugin = backend_plugin(spec.backend.name)
    if not plugin.capabilities.sampling_noise:
        return [loaded.locate("quality.control", f"backend {spec.backend.name!r} has no sampling noise to control "
                              "(its plugin does not declare sampling_noise); use control: samples")]
    if spec.backend.supersample > 1:
        return [loaded.locate("backend.supersample", "an error target renders each image at its own resolution; "
                              "remove backend.supersample or use quality.control: samples")]
    try:
        plugin.error_target(spec.backend, spec.quality)
    except ValueError as e:
        return [loaded.locate("quality.max_samples", str(e))]
    return []


def arr_id(arr: int) -> str:
    return f"arr={arr:06d}"


def view_id(arr: int, cam: int) -> str:
    return f"arr={arr:06d}/cam={cam:03d}"


def render_id(arr: int, cam: int) -> str:
    return f"arr={arr:06d}/cam={cam:03d}/render"


@dataclass(frozen=True)
class Job:
    stage: str
    id: str
    key: str
    root_seed: int
    arr: int
    cam: int | None = None
    upstream: str | None = None  # key of the job this one reads

    @property
    def seed(self) -> int:
        # Derived on demand: planning a million jobs never needs their seeds.
        return seeds.job_seed(self.root_seed, self.id)


def calibration_applied(spec: DatasetSpec) -> str:
    """The option values the backend's calibration of the spec's level sets (canonical JSON), or
    "": a render key holds them, so a build made with another calibration of its level renders
    again instead of reading images of other samples."""
    options = spec.backend
    plugin = backend_plugin(options.name)
    keys_set = set(plugin.calibration(options, spec.quality)) - options.model_fields_set
    if not keys_set:
        return ""
    applied = plugin.options_for(options, spec.quality).model_dump(mode="json", include=keys_set)
    return keys.canonical_json(applied).decode()


def backend_fingerprint(name: str) -> str:
    """Backend name and the versions of what it renders with, without importing the renderer."""
    return backend_plugin(name).fingerprint()


def _folder_listing_digest(root: Path, files: list[Path]) -> str:
    """Names, sizes and mtimes of a folder's files: cheap, and changes when a photo changes."""
    entries = sorted((str(p.relative_to(root)), p.stat().st_size, p.stat().st_mtime_ns) for p in files)
    return keys.digest(entries)


@dataclass(frozen=True)
class JobGraph:
    spec: DatasetSpec  # read by planning and the merge in the main process; workers get ``inputs``
    spec_path: Path
    inputs: BuildInputs
    stage_inputs: dict[str, dict[str, str]]  # stage -> input name -> digest (for diff attribution)
    stage_digests: dict[str, str]
    asset_hashes: dict[str, str]
    backend: str
    # Content hash of each spec.scenes entry: an arrangement's key holds only its own scene's, so
    # editing one scene's texture re-runs exactly the arrangements drawn in that scene.
    scene_keys: tuple[str, ...] = ()
    # What compiling did that the user should hear about (e.g. a models_info.json computed).
    notes: tuple[str, ...] = ()

    @property
    def n_arrangements(self) -> int:
        return self.spec.arrangements.count

    @property
    def cams_per_arrangement(self) -> int:
        return self.spec.cameras.per_arrangement

    @property
    def n_views(self) -> int:
        return self.n_arrangements * self.cams_per_arrangement

    def arrange_job(self, arr: int) -> Job:
        jid = arr_id(arr)
        scene = 0
        if len(self.scene_keys) > 1:  # ~26 us a job: only when there is a choice
            scene = seeds.scene_draw(self.spec.seed, jid, [s.weight for s in self.spec.scenes])[0]
        up = self.scene_keys[scene] if self.scene_keys else None
        return Job("arrange", jid, keys.job_key(self.stage_digests["arrange"], jid, up), self.spec.seed, arr)

    def view_job(self, arr: int, cam: int, arrange_key: str | None = None) -> Job:
        jid = view_id(arr, cam)
        up = arrange_key or self.arrange_job(arr).key
        return Job("view", jid, keys.job_key(self.stage_digests["view"], jid, up), self.spec.seed, arr, cam, up)

    def render_job(self, arr: int, cam: int, view_key: str | None = None) -> Job:
        jid = render_id(arr, cam)
        up = view_key or self.view_job(arr, cam).key
        return Job("render", jid, keys.job_key(self.stage_digests["render"], jid, up), self.spec.seed, arr, cam, up)

    def arrangement_jobs(self, arr: int) -> tuple[Job, list[Job], list[Job]]:
        a = self.arrange_job(arr)
        views = [self.view_job(arr, c, a.key) for c in range(self.cams_per_arrangement)]
        renders = [self.render_job(arr, v.cam, v.key) for v in views]
        return a, views, renders

    def jobs(self) -> Iterator[Job]:
        for arr in range(self.n_arrangements):
            a, views, renders = self.arrangement_jobs(arr)
            yield a
            yield from views
            yield from renders

    def summary(self) -> dict:
        return {
            "spec": str(self.spec_path),
            "name": self.spec.name,
            "backend": self.backend,
            "stages": {
                "arrange": self.n_arrangements,
                "view": self.n_views,
                "render": self.n_views,
            },
            "stage_digests": self.stage_digests,
        }


def product_fingerprints(inputs) -> str:
    """The products a render writes (those a switch turns on and those other inputs do, like a
    stereo rig's right eye) with their packages' versions: upgrading one re-renders."""
    return "; ".join(output_fingerprint(p, "product") for p in active_products(inputs))


def principal_point_note(intr) -> str | None:
    """A principal point outside the image (width and height changed without the rest of the
    intrinsics) points every camera away from its object: every view is then rejected."""
    if 0 <= intr.cx <= intr.width and 0 <= intr.cy <= intr.height:
        return None
    return (f"intrinsics: the principal point (cx, cy) = ({intr.cx:g}, {intr.cy:g}) lies outside the "
            f"{intr.width} x {intr.height} image; when changing width and height, scale fx, fy, cx and cy too")


PHOTO_SUFFIXES = (".jpg", ".jpeg", ".png")


def _input_folders(spec: DatasetSpec, loaded: LoadedSpec) -> dict[str, str]:
    """The listing digest of every folder the backend's options name (photographs, HDRIs), each
    photograph's header checked."""
    found = {}
    for option, folder in spec.backend.input_folders().items():
        try:
            root = expand_path(folder, loaded.directory, f"backend.{option}")
        except AssetError as e:
            raise SpecError([loaded.locate(f"backend.{option}", str(e))]) from None
        if not root.is_dir():
            raise SpecError([loaded.locate(f"backend.{option}", f"folder {folder!r} not found ({root})")])
        files = [p for p in sorted(root.rglob("*")) if p.is_file()]
        if not files:
            raise SpecError([loaded.locate(f"backend.{option}", f"folder {folder!r} holds no files ({root})")])
        photos = [p for p in files if p.suffix.lower() in PHOTO_SUFFIXES]
        if not photos:  # the render jobs would each fail on it, after the arrangements and cameras
            raise SpecError([loaded.locate(f"backend.{option}", f"folder {folder!r} holds no photographs "
                                           f"({'/'.join(s.lstrip('.') for s in PHOTO_SUFFIXES)}) ({root})")])
        for p in photos:  # headers only: a bad one fails here,
            try:  # not in the render job that draws it
                check_photo(p, f"backend.{option}")
            except AssetError as e:
                raise SpecError([loaded.locate(f"backend.{option}", str(e))]) from None
        found[f"folder:{folder}"] = _folder_listing_digest(root, files)  # the folder walked once, ~ expanded
    return found


def compile_spec(loaded: LoadedSpec) -> JobGraph:
    """Resolve asset and scene fingerprints and derive the per-stage input digests."""
    spec = loaded.spec
    data = spec.model_dump(mode="json")
    problems = check_budgets(spec, loaded) + check_capabilities(spec, loaded)
    if problems:  # before hashing assets or loading scenes: refusing is the cheap part
        raise SpecError(problems)
    notes: list[str] = [n for n in (principal_point_note(spec.intrinsics),) if n]
    try:
        fingerprints = object_fingerprints(spec.objects, loaded.directory)
        asset_hashes = {f"asset:{k}": v for k, v in fingerprints.items()}
        notes += bop_folder_notes(spec.objects, loaded.directory)
        problems += check_objects(spec, loaded, len(asset_hashes))
        problems += [loaded.locate(e.field, str(e)) for e in object_size_problems(spec.objects, loaded.directory, fingerprints)]
    except AssetError as e:
        field = e.field or "objects"
        problems.append(loaded.locate(field, str(e).removeprefix(f"{field}: ")))
        asset_hashes = {}
    # Files the spec names only by path: their bytes, not their names, go into the keys (a
    # material's into the renders': materials are only theirs).
    texture_hashes = {}
    for key, mat in spec.objects.materials.items():
        if mat.texture is None:
            continue
        field = f"objects.materials.{key}.texture"
        try:
            tex = expand_path(mat.texture, loaded.directory, field)
            texture_hashes[f"texture:{key}"] = file_digest(tex, field)
            check_texture(tex, field)
        except AssetError as e:
            problems.append(loaded.locate(field, str(e)))
    distractor_prints, folder_problems = bopdistractors.fingerprints(spec.arrangements.distractors.paths,
                                                                     loaded.directory)
    asset_hashes.update({f"asset:{k}": v for k, v in distractor_prints.items()})
    problems += [loaded.locate(e.field, str(e).removeprefix(f"{e.field}: ")) for e in folder_problems]
    known = set(builtin_objects()) | set(catalogue_objects()) | {"random_urdfs/*", "catalogue/*"}
    for k, name in enumerate(spec.arrangements.distractors.objects):
        if name not in known:
            field = f"arrangements.distractors.objects.{k}"
            problems.append(loaded.locate(field, f"unknown built-in object {name!r} (see specsynth.assets.resolve.builtin_objects)"))
    scene_hashes = {}
    for i, ref in enumerate(spec.scenes):
        try:
            scene_hashes[f"scene:{ref.ref}"] = scene_fingerprint(ref, loaded.directory)
            problems += check_room_categories(ref, i, loaded)
            if ref.clutter != 1.0 and not generated_name(ref):
                problems.append(loaded.locate(f"scenes.{i}.clutter", "clutter is for the built-in generated rooms "
                                              f"({', '.join(GENERATED)}); {ref.ref!r} is not one"))
            if ref.stages and declares_stages(ref, loaded.directory):
                # Found stages depend on the objects' sizes: their names are checked when the scene loads.
                known = {st.name for st, _, _ in stage_table(ref, loaded.directory)}
                unknown = [n for n in ref.stages if n not in known and n != "focus"]
                if unknown:
                    problems.append(loaded.locate(f"scenes.{i}.stages", f"scene {ref.ref!r} has no stage(s) {unknown}; it has {sorted(known)}"))
        except (AssetError, ValueError, FileNotFoundError) as e:
            problems.append(loaded.locate(f"scenes.{i}.{'name' if ref.name else 'file'}", str(e)))
    if problems:
        raise SpecError(problems)

    inputs = BuildInputs.of(spec)
    backend = backend_fingerprint(spec.backend.name)
    extra = {"arrange": dict(asset_hashes), "view": {"annotator": f"pyrender {dist_version('pyrender')}"},
             "render": {"backend": backend, "products": product_fingerprints(inputs.render),
                        **texture_hashes, **_input_folders(spec, loaded)}}
    if calibration := calibration_applied(spec):
        extra["render"]["calibration"] = calibration
    if spec.quality.control == "error":  # only these renders are the error control's
        plugin = backend_plugin(spec.backend.name)
        way = ", continued halves" if plugin.capabilities.continues_samples else ""
        rate = f", sampler rate {plugin.sampler_rate}" if plugin.sampler_rate != 1.0 else ""
        extra["render"]["error_control"] = f"revision {error_control.REVISION}{way}{rate}"
    # A stage's key: the digest of its whole inputs model, and what it reads besides the spec.
    stage_digests = {s: keys.stage_digest(s, {"inputs": keys.digest(getattr(inputs, s).model_dump(mode="json")),
                                              **extra[s]}) for s in STAGES}
    # Which of its inputs changed, field by field, for ``diff``.
    stage_inputs = {s: {**{k: keys.digest(v) for k, v in getattr(inputs, s).digest_parts().items()}, **extra[s]}
                    for s in STAGES}
    stage_inputs["arrange"].update(scene_hashes)  # for diff attribution; keyed per job (arrange_job)
    return JobGraph(
        spec=spec,
        spec_path=loaded.path,
        inputs=inputs,
        stage_inputs=stage_inputs,
        stage_digests=stage_digests,
        asset_hashes={**asset_hashes, **texture_hashes, **scene_hashes},
        backend=backend,
        scene_keys=tuple(scene_hashes[f"scene:{ref.ref}"] for ref in spec.scenes),
        notes=tuple(notes),
    )
