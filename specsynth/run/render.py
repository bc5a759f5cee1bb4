"""The render step: per accepted view, render, annotate, apply lens and sensor, write the colour
image and every active product's files into the store (a product may add another image of the
view: a stereo rig's right eye is one)."""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..model import lens
from ..model.colour import check_finite, linear_to_srgb8
from ..model.error import ErrorTarget, render_to_target
from ..model.ir import RenderResult, RenderScene
from ..model.records import ArrangementRecord, ImageRecord, ViewRecord
from ..output_api import ViewProduct, active_products
from ..plan import seeds
from ..plan.compiler import Job
from ..plan.inputs import RenderInputs
from ..plugins import backend_plugin
from ..views.sensor import jpeg_quality, sensor_rgb
from .worker import Worker


def run_renders(w: Worker, inp: RenderInputs, arrange_key: str, pairs: list[tuple[Job, Job]]) -> list[dict[str, Any]]:
    """Render each accepted view of one arrangement: files and record committed to the store together."""
    arr = ArrangementRecord.from_json(w.store.load("arrange", arrange_key))
    scene, origin = w.frame(arr)
    backend = w.backend()
    annot = w.annotator()
    load_seconds = w.load("backend", arrange_key, scene) + w.load("annotator", arrange_key, scene)
    load_phase = load_seconds
    occluders = "scene" if w.draws_scene else "objects"
    preset = inp.quality.resolved()
    ctx = _Render(inp, arr, scene, origin, arrange_key, backend, annot, occluders, preset, load_seconds,
                  w.assets_by_id(arr), error_target(inp), tuple(active_products(inp)))
    out = []
    for view_job, job in pairs:
        if w.store.has("render", job.key):  # finished before a retry
            continue
        view = ViewRecord.from_json(w.store.load("view", view_job.key))
        wd = w.store.begin()
        rec, image = render_eye(w, wd, job, view, view.t_w2c, ctx, load_phase)
        for product in ctx.products:  # once per view: a product adding another image links it here
            rec = product.finish(rec, image)
        t5 = time.perf_counter()
        w.store.commit("render", job.key, wd, rec.to_json())
        out.append({"id": job.id, "seconds": rec.render_seconds,
                    "phases": {**rec.stats["phases"], "write": round(time.perf_counter() - t5, 5)}})
        load_phase = 0.0  # the scene load is paid by the first render of the call
    return out


def render_eye(w: Worker, wd: Path, job: Job, view: ViewRecord, t_w2c, ctx: _Render,
               load_phase: float) -> tuple[ImageRecord, _Image]:
    """One camera's image of the arrangement, its files written into ``wd``: render, annotate,
    lens and sensor, products; -> its record and the image the products saw (every image of a
    view shares the job's seed)."""
    inp, warp = ctx.inp, w.lens_warp()
    cam = w.camera(view.R_w2c, t_w2c, ctx.origin)
    cam_r = lens.render_camera(cam, warp) if warp else cam
    if inp.depth_of_field is not None:
        cam_r = focused(inp, cam_r, ctx.scene, view.focus_inst, job)
    if inp.motion_blur is not None:
        cam_r = replace(cam_r, motion=camera_motion(inp.motion_blur, seeds.job_seed(inp.arrange.seed, f"{job.id}/motion")))
    t1 = time.perf_counter()
    res = draw(ctx, cam_r, job.seed)
    seconds = time.perf_counter() - t1
    if res.linear is not None:
        check_finite(res.linear, f"{inp.backend.name} render of {job.id}")
    t2 = time.perf_counter()
    if warp:
        ann = ctx.annot.annotate_lens(cam, warp, inp.intrinsics.distortion, inp.visibility_delta, ctx.occluders)
        res = through_lens(res, warp)
    else:
        ann = ctx.annot.annotate(cam, inp.visibility_delta, ctx.occluders)
    t3 = time.perf_counter()

    def albedo() -> np.ndarray:  # through a lens, drawn like the colour: pinhole, then warped
        albedo8 = w.albedo(ctx.arrange_key, ctx.scene).render(cam_r)
        return lens.remap_nearest(albedo8, warp) if warp else albedo8

    def other_eye(t: Any, folder: str) -> ImageRecord:
        (wd / folder).mkdir()
        return render_eye(w, wd / folder, job, view, t, ctx, 0.0)[0]

    image = _Image(wd, inp, cam, cam_r, res, ann, ctx.by_id, warp.rays if warp else None, job.id, albedo, other_eye)
    files = write_image(image, ctx.products)
    stats = dict(res.stats)
    stats["load_seconds"] = ctx.load_seconds
    stats["phases"] = render_phases(res.stats.get("phases"), seconds, load=load_phase,
                                    annotate=t3 - t2, encode=time.perf_counter() - t3)
    return ImageRecord(
        arr=job.arr, cam=job.cam, index=view.index, scene=ctx.arr.scene, stage=ctx.arr.stage,
        backend=inp.backend.name, backend_version=ctx.backend.version(), quality=inp.quality.level,
        seed=job.seed, width=cam.width, height=cam.height, K=cam.K_array.tolist(),
        R_w2c=view.R_w2c, t_w2c=list(t_w2c), depth_scale=image.recorded_depth_scale(), instances=ann.instances,
        files=files, distortion=list(inp.intrinsics.distortion) if warp else None, render_seconds=seconds, stats=stats,
    ), image


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
    camera: Any
    render_camera: Any
    result: RenderResult
    annotation: Any
    assets: dict
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


def error_target(inp: RenderInputs) -> ErrorTarget | None:
    """The per-image error target of ``quality.control: error``, else None (the level's samples)."""
    if inp.quality.control != "error":
        return None
    plugin = backend_plugin(inp.backend.name)
    return plugin.error_target(inp.backend, inp.quality)  # the spec's own samples start it


def draw(ctx: _Render, cam, seed: int) -> RenderResult:
    """One image from the backend: one render of the level's samples, or, under an error target,
    pairs of renders with independent seeds until the image's estimated error reaches the target."""
    clamp = ctx.inp.quality.clamp
    if ctx.target is None:
        return ctx.backend.render(cam, ctx.preset, seed, clamp=clamp)
    return draw_to_target(ctx.backend, cam, ctx.preset, seed, ctx.target, clamp)


def draw_to_target(backend, cam, preset, seed: int, target: ErrorTarget, clamp: float | None) -> RenderResult:
    """Renders of ``preset``'s light paths, each with the samples ``target`` asks for, the first
    with ``seed`` and the i-th with a seed of its own, until the image reaches the target (also
    what `specsynth bench` times as ``+targeted``); the image's samples and error in its stats."""
    def one(samples: int, i: int) -> RenderResult:
        q = preset.model_copy(update={"aa": samples, "diffuse_rays": samples, "specular_rays": samples})
        return backend.render(cam, q, seed if i == 0 else seeds.job_seed(seed, f"render/{i}"), clamp=clamp)

    done = render_to_target(one, target, linear_to_srgb8)
    return replace(done.result, stats={**done.result.stats, **done.stats()})


@dataclass(frozen=True)
class _Render:
    """What every image of one render call shares."""

    inp: RenderInputs
    arr: ArrangementRecord
    scene: RenderScene
    origin: Any
    arrange_key: str
    backend: Any
    annot: Any
    occluders: str
    preset: Any
    load_seconds: float
    by_id: dict  # obj_id -> ObjectAsset of every annotated object
    target: ErrorTarget | None  # quality.control: error
    products: tuple[ViewProduct, ...]  # what every image writes besides its colour (by name)


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
