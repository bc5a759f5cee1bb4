"""The render step: per accepted view, render, annotate, apply lens and sensor, write the colour
image and every active product's files into the store (a product may add another image of the
view: a stereo rig's right eye is one)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Sequence

import numpy as np

from ..backend_api import render_takes
from ..model import lens
from ..model.colour import check_finite, linear_to_srgb8
from ..model.error import ErrorTarget, render_group_to_target
from ..model.ir import CameraIR, RenderResult, RenderScene
from ..model.records import ArrangementRecord, ImageRecord, ViewRecord
from ..model.supersample import downsampled
from ..output_api import ViewProduct, active_products
from ..plan import seeds
from ..plan.compiler import Job
from ..plan.inputs import RenderInputs
from ..plugins import BackendPlugin, backend_plugin
from ..spec.models import QualityPreset
from ..views.sensor import jpeg_quality, sensor_rgb
from .reports import Rendered
from .store import Store, stored
from .worker import Framed, Held, Optics, World

if TYPE_CHECKING:
    from ..annotate.engine import Annotation
    from ..assets.resolve import ObjectAsset


@dataclass(frozen=True)
class RenderSetup:
    """What every render of a build shares, fixed when the step is built: the inputs, what the
    backend plugin says it draws, the preset, the error target and the active products."""

    inputs: RenderInputs
    draws_scene: bool  # False: the backend draws the objects only (what occludes them, what the albedo shows)
    preset: QualityPreset
    target: ErrorTarget | None  # quality.control: error
    products: tuple[ViewProduct, ...]  # what every image writes besides its colour (by name)
    supersample: int = 1  # each image rendered at this many times its resolution (the level's calibration may set it)

    @classmethod
    def of(cls, inputs: RenderInputs, plugin: BackendPlugin) -> "RenderSetup":
        return cls(inputs, plugin.capabilities.draws_scene, inputs.quality.resolved(), error_target(inputs, plugin),
                   tuple(active_products(inputs)), plugin.options_for(inputs.backend, inputs.quality).supersample)

    @property
    def occluders(self) -> str:
        return "scene" if self.draws_scene else "objects"

    def drawn(self, scene: RenderScene) -> RenderScene:
        """What the backend draws of ``scene`` (the albedo raster draws the same)."""
        return scene if self.draws_scene else scene.objects_only()


@dataclass(frozen=True)
class RenderCall:
    """One arrangement loaded for a render call: what each of its images shares."""

    key: str  # the arrangement's store key
    framed: Framed
    load_seconds: float  # the backend's and the annotator's loads of the arrangement
    backend_version: str


@dataclass(frozen=True)
class Drawn:
    """One image of a view as the backend drew it, before annotation."""

    t_w2c: tuple[float, ...]  # the camera's position (world to camera, metres)
    camera: CameraIR
    render_camera: CameraIR  # what the backend got (see RenderStep.render_camera)
    result: RenderResult
    seconds: float  # the backend's time for it


class RenderStep:
    """Renders with its own inputs and the backend plugin's capabilities (read once, here). The
    backend, the annotator and the albedo raster are ``Held``: each loads an arrangement once for
    consecutive calls of it; the annotator is the view step's (one per image size)."""

    def __init__(self, inputs: RenderInputs, world: World, annotator: Held, store: Store, *,
                 spec_dir: Path, threads: int = 0):
        if world.inputs != inputs.arrange:
            raise ValueError("the render step's world must be built from its own arrangement inputs")
        plugin = backend_plugin(inputs.backend.name)
        self.setup = RenderSetup.of(inputs, plugin)
        self.world, self.annotator, self.store = world, annotator, store
        self.optics = Optics(inputs.intrinsics)
        # Paths in a spec are relative to the spec file (as the compiler hashes them), never to
        # wherever the build was started.
        options = plugin.options_for(inputs.backend.relative_to(spec_dir), inputs.quality)
        self.backend = Held(lambda: plugin.load_class()(options, threads=threads))
        self.albedo = Held(self._albedo_renderer)

    def _albedo_renderer(self):
        from ..annotate.albedo import AlbedoRenderer

        return AlbedoRenderer(*self.optics.canvas)  # through a lens, drawn like the colour: pinhole, then warped

    def close(self) -> None:
        self.backend.close()
        self.albedo.close()

    def run(self, arrange_key: str, pairs: list[tuple[Job, Job]]) -> list[Rendered]:
        """Render each accepted view of one arrangement: files and record committed to the store together."""
        call = self.load(arrange_key)
        out, load_phase = [], call.load_seconds
        for view_job, job in pairs:
            if self.store.has("render", job.key):  # finished before a retry
                continue
            view = ViewRecord.from_json(self.store.load("view", view_job.key))
            wd = self.store.begin()
            # Every image of the view drawn before any is written: under an error target the
            # images of a stereo rig are rendered as one, to the same samples.
            drawn = self.draw_view(job, view, call, self.images_of(view))
            rec, image = self.render_eye(wd, job, view, drawn[""], call, load_phase, drawn)
            for product in self.setup.products:  # once per view: a product adding another image links it here
                rec = product.finish(rec, image)
            record = rec.to_json()
            t5 = time.perf_counter()
            self.store.commit("render", job.key, wd, record)
            phases = {**rec.stats["phases"], "write": round(time.perf_counter() - t5, 5)}
            out.append(Rendered(job.id, job.key, rec.render_seconds, phases, stored(record)))
            load_phase = 0.0  # the scene load is paid by the first render of the call
        return out

    def load(self, arrange_key: str) -> RenderCall:
        """The arrangement, loaded into the backend and the annotator unless they hold it."""
        framed = self.world.frame(ArrangementRecord.from_json(self.store.load("arrange", arrange_key)),
                                  self.setup.inputs.materials)
        seconds = self.backend.load(arrange_key, framed.scene) + self.annotator.load(arrange_key, framed.scene)
        return RenderCall(arrange_key, framed, seconds, self.backend.get().version())

    def images_of(self, view: ViewRecord) -> dict[str, list[float]]:
        """Every image of a view by its folder ('' the view's own, then each one a product adds:
        a stereo rig's right eye) -> the camera's position for it."""
        found = {"": list(view.t_w2c)}
        for product in self.setup.products:
            found.update(product.other_images(self.setup.inputs, view.t_w2c))
        return found

    def draw_view(self, job: Job, view: ViewRecord, call: RenderCall, images: dict[str, Sequence[float]]) -> dict[str, Drawn]:
        """The backend's images of one view, by folder: the cameras at ``images``' positions, all
        with the job's seed, and under an error target rendered to it together."""
        cams = {f: self.optics.camera(view.R_w2c, t, call.framed.origin) for f, t in images.items()}
        cams_r = {f: self.render_camera(c, call.framed.scene, view.focus_inst, job) for f, c in cams.items()}
        drawn = self.draw(list(cams_r.values()), job.seed)
        return {f: Drawn(tuple(float(x) for x in images[f]), cams[f], cams_r[f], res, seconds)
                for f, (res, seconds) in zip(images, drawn)}

    def render_eye(self, wd: Path, job: Job, view: ViewRecord, drawn: Drawn, call: RenderCall,
                   load_phase: float, others: dict[str, Drawn]) -> tuple[ImageRecord, _Image]:
        """One camera's image of the arrangement, its files written into ``wd``: annotate, lens and
        sensor, products; -> its record and the image the products saw (every image of a view
        shares the job's seed). ``others``: the view's other images, drawn with it."""
        inp, warp = self.setup.inputs, self.optics.warp
        cam, cam_r, res, seconds, t_w2c = drawn.camera, drawn.render_camera, drawn.result, drawn.seconds, drawn.t_w2c
        if res.linear is not None:
            check_finite(res.linear, f"{inp.backend.name} render of {job.id}")
        t2 = time.perf_counter()
        annotator = self.annotator.get()
        if warp:
            ann = annotator.annotate_lens(cam, warp, inp.intrinsics.distortion, inp.visibility_delta, self.setup.occluders)
            res = through_lens(res, warp)
        else:
            ann = annotator.annotate(cam, inp.visibility_delta, self.setup.occluders)
        t3 = time.perf_counter()

        def albedo() -> np.ndarray:  # through a lens, drawn like the colour: pinhole, then warped
            self.albedo.load(call.key, self.setup.drawn(call.framed.scene))
            albedo8 = self.albedo.get().render(cam_r)
            return lens.remap_nearest(albedo8, warp) if warp else albedo8

        def other_eye(t: Any, folder: str) -> ImageRecord:
            (wd / folder).mkdir()
            got = others.get(folder)
            if got is None or got.t_w2c != tuple(float(x) for x in t):  # not announced: drawn on its own
                got = self.draw_view(job, view, call, {folder: t})[folder]
            return self.render_eye(wd / folder, job, view, got, call, 0.0, others)[0]

        image = _Image(wd, inp, cam, cam_r, res, ann, call.framed.assets, warp.rays if warp else None, job.id,
                       albedo, other_eye)
        files = write_image(image, self.setup.products)
        stats = dict(res.stats)
        stats["load_seconds"] = call.load_seconds
        stats["phases"] = render_phases(res.stats.get("phases"), seconds, load=load_phase,
                                        annotate=t3 - t2, encode=time.perf_counter() - t3)
        arr = call.framed.record
        return ImageRecord(
            arr=job.arr, cam=job.cam, index=view.index, scene=arr.scene, stage=arr.stage,
            backend=inp.backend.name, backend_version=call.backend_version, quality=inp.quality.level,
            seed=job.seed, width=cam.width, height=cam.height, K=cam.K_array.tolist(),
            R_w2c=view.R_w2c, t_w2c=list(t_w2c), depth_scale=image.recorded_depth_scale(), instances=ann.instances,
            files=files, distortion=list(inp.intrinsics.distortion) if warp else None, render_seconds=seconds,
            stats=stats,
        ), image

    def render_camera(self, cam: CameraIR, scene: RenderScene, focus_inst: int, job: Job) -> CameraIR:
        """The camera the backend gets: through a lens its pinhole window, with the thin lens and
        the motion over the exposure the spec asks for."""
        inp, warp = self.setup.inputs, self.optics.warp
        cam_r = lens.render_camera(cam, warp) if warp else cam
        if inp.depth_of_field is not None:
            cam_r = focused(inp, cam_r, scene, focus_inst, job)
        if inp.motion_blur is not None:
            cam_r = replace(cam_r, motion=camera_motion(inp.motion_blur, seeds.job_seed(inp.arrange.seed, f"{job.id}/motion")))
        return cam_r

    def draw(self, cams: list[CameraIR], seed: int) -> list[tuple[RenderResult, float]]:
        """The backend's images of one view's cameras, each with its seconds: one render each of the
        level's samples, or, under an error target, pairs of renders of all of them with
        independent seeds until every image's estimated error reaches its target."""
        setup, backend = self.setup, self.backend.get()
        clamp = setup.inputs.quality.clamp
        if setup.target is not None:
            return draw_to_target(backend, cams, setup.preset, seed, setup.target, clamp)
        out = []
        for cam in cams:
            t0 = time.perf_counter()
            res = render_at(backend, cam, setup.preset, seed, clamp, setup.supersample)
            out.append((res, time.perf_counter() - t0))
        return out


def render_at(backend, cam: CameraIR, preset, seed: int, clamp: float | None, supersample: int = 1) -> RenderResult:
    """One render of ``preset`` from ``cam``; with ``supersample`` > 1 rendered at that many times
    the resolution and brought back to it (``model.supersample``)."""
    if supersample == 1:
        return backend.render(cam, preset, seed, clamp=clamp)
    return downsampled(backend.render(cam.scaled(supersample), preset, seed, clamp=clamp), supersample)


def write_image(image: _Image, products: tuple[ViewProduct, ...]) -> dict[str, Any]:
    """Every file of one image into its store folder: the colour image through the sensor, then
    each product's -> the record's files by kind."""
    files: dict[str, Any] = {"rgb": write_rgb(image)}
    for product in products:
        found = product.write(image)
        taken = sorted(set(found) & set(files))
        if taken:
            raise ValueError(f"product {product.name!r} writes files of kind {taken[0]!r}, which another output writes")
        files.update(found)
    return files


def write_rgb(image: _Image) -> str:
    """The colour image: the sensor's response (exposure, white balance, tone, noise, blur; each
    from its own seeded stream) encoded as the spec asks."""
    from ..outputs.images import write_jpg, write_png

    inp = image.inputs
    name = f"rgb.{inp.outputs.image_format}"
    # Three streams of the image's sensor seed: colour, JPEG quality, and the depth sensor's.
    rng_rgb, rng_jpeg, _ = (np.random.default_rng(ss) for ss in np.random.SeedSequence(image.seed("sensor")).spawn(3))
    albedo8 = image.albedo() if inp.sensor.auto_white_balance else None
    rgb = sensor_rgb(image.result.linear, image.result.rgb, inp.sensor, rng_rgb, albedo8)
    if inp.outputs.image_format == "jpg":
        write_jpg(image.folder / name, rgb, jpeg_quality(inp.sensor, inp.outputs.jpeg_quality, rng_jpeg))
    else:
        write_png(image.folder / name, rgb)
    return name


@dataclass
class _Image:
    """One image as the products see it (``output_api.View``): what is drawn only when a product
    asks (the albedo, the encoded depth) is drawn once and kept for the others."""

    folder: Path
    inputs: RenderInputs
    camera: CameraIR
    render_camera: CameraIR
    result: RenderResult
    annotation: Annotation
    assets: dict[int, ObjectAsset]
    rays: np.ndarray | None
    job_id: str
    draw_albedo: Callable[[], np.ndarray]
    other_eye: Callable[[Any, str], ImageRecord]
    _albedo: np.ndarray | None = field(default=None, repr=False)
    _depth: tuple[np.ndarray, float] | None = field(default=None, repr=False)

    def seed(self, stream: str) -> int:
        return seeds.job_seed(self.inputs.arrange.seed, f"{self.job_id}/{stream}")

    def albedo(self) -> np.ndarray:
        if self._albedo is None:
            self._albedo = self.draw_albedo()
        return self._albedo

    def depth16(self) -> tuple[np.ndarray, float]:
        from ..outputs.images import encode_depth

        if self._depth is None:
            self._depth = encode_depth(self.annotation.depth, self.inputs.outputs.depth_scale)
        return self._depth

    def recorded_depth_scale(self) -> float:
        """The scale the image's depth files were encoded with; without any, the spec's (1 for 'auto')."""
        if self._depth is not None:
            return float(self._depth[1])
        scale = self.inputs.outputs.depth_scale
        return 1.0 if scale == "auto" else float(scale)

    def render_eye(self, t_w2c, folder: str) -> ImageRecord:
        return self.other_eye(t_w2c, folder)


def focused(inp: RenderInputs, cam, scene: RenderScene, focus_inst: int, job: Job):
    """``cam`` with its thin lens: an aperture drawn for this image, focused on the centre of
    the object the camera aims at (its model origin, BOP's bounding-box centre)."""
    dof = inp.depth_of_field
    rng = np.random.default_rng(seeds.job_seed(inp.arrange.seed, f"{job.id}/lens"))
    aperture_m = float(rng.uniform(*dof.aperture)) / 1000.0
    jitter = float(rng.uniform(-dof.focus_jitter, dof.focus_jitter))
    focus = next((o for o in scene.objects() if o.inst == focus_inst), None)
    z = float((cam.T_w2c @ focus.matrix)[2, 3]) if focus is not None else 1.0
    return replace(cam, aperture=aperture_m, focus_distance=max(z + jitter, 2.0 * cam.near))


def error_target(inp: RenderInputs, plugin: BackendPlugin) -> ErrorTarget | None:
    """The per-image error target of ``quality.control: error``, else None (the level's samples)."""
    if inp.quality.control != "error":
        return None
    return plugin.error_target(inp.backend, inp.quality)  # the spec's own samples start it


def draw_to_target(backend, cams: Sequence[CameraIR], preset, seed: int, target: ErrorTarget,
                   clamp: float | None) -> list[tuple[RenderResult, float]]:
    """Renders of ``preset``'s light paths from each of ``cams`` (the images of one view), each with
    the samples ``target`` asks for, the first with ``seed`` and the i-th with a seed of its own,
    until every image reaches its target (``render_group_to_target``: the images of a stereo rig
    take the same samples); also what `specsynth bench` times as ``+targeted``. -> each image,
    its samples and error in its stats, and its seconds: its own renders' and a share of the
    estimates'."""
    spent = [0.0] * len(cams)
    # A backend that can denoise an image of its own kind (RenderBackend.denoise) gets every sample
    # spent denoised together, not only the last pair: its renders skip their own denoiser.
    denoise = getattr(backend, "denoise", None)
    skip = {"skip_denoiser": True} if denoise is not None and render_takes(backend, "skip_denoiser") else {}

    def drawer(k: int) -> Callable[..., RenderResult]:
        def one(samples: int, i: int, offset: int = 0) -> RenderResult:
            q = preset.model_copy(update={"aa": samples, "diffuse_rays": samples, "specular_rays": samples})
            more = {**skip, **({"sample_offset": offset} if offset else {})}  # offsets: target.continues only
            t0 = time.perf_counter()
            res = backend.render(cams[k], q, seed if i == 0 else seeds.job_seed(seed, f"render/{i}"), clamp=clamp, **more)
            spent[k] += time.perf_counter() - t0
            return res
        return one

    t0 = time.perf_counter()
    done = render_group_to_target([drawer(k) for k in range(len(cams))], target, linear_to_srgb8, denoise)
    shared = (time.perf_counter() - t0 - sum(spent)) / len(cams)
    return [(replace(d.result, stats={**d.result.stats, **d.stats()}), spent[k] + shared) for k, d in enumerate(done)]


def render_phases(backend_phases: dict | None, render_seconds: float, **core: float) -> dict[str, float]:
    """Where one image's time went: the backend's own phases (prefixed ``render.``; what it does
    not account for is ``render.other``) and the core's (scene load, annotation, encoding). The
    store commit (``write``) happens after the record is made and is summed by the build."""
    phases = {f"render.{k}": float(v) for k, v in (backend_phases or {}).items()}
    phases["render.other"] = max(0.0, render_seconds - sum(phases.values()))
    phases.update({k: float(v) for k, v in core.items()})
    return {k: round(v, 5) for k, v in phases.items()}


def camera_motion(blur, seed: int) -> tuple[float, ...]:
    """One image's camera motion over the exposure (CameraIR.motion): a direction of travel and an
    axis of turn uniform on the sphere, speed and rate uniform in the spec's ranges."""
    rng = np.random.default_rng(seed)
    direction, axis = (v / np.linalg.norm(v) for v in rng.standard_normal((2, 3)))
    speed, rate = float(rng.uniform(*blur.speed)), np.radians(float(rng.uniform(*blur.rotation)))
    return tuple(float(x) for x in (*(direction * speed * blur.shutter), *(axis * rate * blur.shutter)))


def through_lens(res: RenderResult, warp) -> RenderResult:
    """A pinhole render warped into the distorted image: radiance interpolated (bilinear), then
    encoded by the same sRGB transform every backend uses; an 8-bit-only render interpolated as is."""
    if res.linear is not None:
        linear = np.maximum(lens.remap_bilinear(res.linear, warp), 0.0).astype(np.float32)
        return replace(res, linear=linear, rgb=linear_to_srgb8(linear))
    rgb = np.clip(np.rint(lens.remap_bilinear(res.rgb, warp)), 0, 255).astype(np.uint8)
    return replace(res, rgb=rgb)
