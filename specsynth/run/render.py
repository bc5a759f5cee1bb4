"""The render step: per accepted view, render (both eyes for a stereo rig), annotate, apply lens and
sensor, write every file of the image into the store."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from ..assets.resolve import ObjectAsset
from ..model import lens
from ..model.colour import check_finite, linear_to_srgb8
from ..model.error import ErrorTarget, render_to_target
from ..model.ir import RenderResult, RenderScene
from ..model.records import ArrangementRecord, ImageRecord, ViewRecord
from ..plan import seeds
from ..plan.compiler import Job
from ..plan.inputs import RenderedFiles, RenderInputs
from ..plugins import backend_plugin
from ..views.sensor import jpeg_quality, sensor_depth, sensor_rgb
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
                  w.assets_by_id(arr), error_target(inp))
    out = []
    for view_job, job in pairs:
        if w.store.has("render", job.key):  # finished before a retry
            continue
        view = ViewRecord.from_json(w.store.load("view", view_job.key))
        wd = w.store.begin()
        rec = render_eye(w, wd, job, view, view.t_w2c, ctx, load_phase)
        stereo = inp.stereo
        if stereo is not None:  # the right eye: the rig moved by the baseline along the camera's x
            t_right = (np.asarray(view.t_w2c, np.float64) - [stereo.baseline, 0.0, 0.0]).tolist()
            (wd / "right").mkdir()
            right = render_eye(w, wd / "right", job, view, t_right, ctx, 0.0)
            rec = replace(rec, eye="left", baseline=stereo.baseline,
                          right_eye=replace(right, eye="right", baseline=stereo.baseline).to_json())
        t5 = time.perf_counter()
        w.store.commit("render", job.key, wd, rec.to_json())
        out.append({"id": job.id, "seconds": rec.render_seconds,
                    "phases": {**rec.stats["phases"], "write": round(time.perf_counter() - t5, 5)}})
        load_phase = 0.0  # the scene load is paid by the first render of the call
    return out


def render_eye(w: Worker, wd: Path, job: Job, view: ViewRecord, t_w2c, ctx: _Render, load_phase: float) -> ImageRecord:
    """One camera's image of the arrangement, its files written into ``wd``: render, annotate,
    lens and sensor, outputs; -> its record (both eyes of a stereo rig share the job's seed)."""
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
    files = write_image(w, wd, job, res, ann, cam, cam_r, ctx)
    stats = dict(res.stats)
    stats["load_seconds"] = ctx.load_seconds
    stats["phases"] = render_phases(res.stats.get("phases"), seconds, load=load_phase,
                                    annotate=t3 - t2, encode=time.perf_counter() - t3)
    return ImageRecord(
        arr=job.arr, cam=job.cam, index=view.index, scene=ctx.arr.scene, stage=ctx.arr.stage,
        backend=inp.backend.name, backend_version=ctx.backend.version(), quality=inp.quality.level,
        seed=job.seed, width=cam.width, height=cam.height, K=cam.K_array.tolist(),
        R_w2c=view.R_w2c, t_w2c=list(t_w2c), instances=ann.instances, render_seconds=seconds, stats=stats,
        **files, distortion=list(inp.intrinsics.distortion) if warp else None,
    )


def write_image(w: Worker, wd: Path, job: Job, res, ann, cam, cam_r, ctx: _Render) -> dict[str, Any]:
    """Every file of one image into the store folder ``wd`` (sensor effects applied to the colour
    image, each from its own seeded stream) -> the record's file fields and depth scale."""
    from ..outputs.coco import write_visible_rles
    from ..outputs.images import encode_depth, write_exr, write_jpg, write_mask, write_png

    inp, warp = ctx.inp, w.lens_warp()
    ext = inp.outputs.image_format
    rgb_file = f"rgb.{ext}"
    rng_rgb, rng_jpeg, rng_depth = (np.random.default_rng(ss) for ss in np.random.SeedSequence(
        seeds.job_seed(inp.arrange.seed, f"{job.id}/sensor")).spawn(3))
    albedo8 = None
    if inp.outputs.albedo or inp.sensor.auto_white_balance:
        albedo8 = w.albedo(ctx.arrange_key, ctx.scene).render(cam_r)
        albedo8 = lens.remap_nearest(albedo8, warp) if warp else albedo8
    rgb = sensor_rgb(res.linear, res.rgb, inp.sensor, rng_rgb, albedo8)
    if ext == "jpg":
        write_jpg(wd / rgb_file, rgb, jpeg_quality(inp.sensor, inp.outputs.jpeg_quality, rng_jpeg))
    else:
        write_png(wd / rgb_file, rgb)
    depth_file, scale = None, inp.outputs.depth_scale
    if inp.outputs.depth:
        depth16, scale = encode_depth(ann.depth, inp.outputs.depth_scale)
        depth_file = "depth.png"
        write_png(wd / depth_file, depth16)
    if scale == "auto":
        scale = 1.0
    depth_noisy_file = None
    if inp.outputs.depth and inp.sensor.depth is not None:
        depth_noisy_file = "depth_noisy.png"
        write_png(wd / depth_noisy_file, encode_depth(sensor_depth(ann.depth, inp.sensor.depth, rng_depth), scale)[0])
    masks, masks_visib = [], []
    if inp.outputs.masks:
        for gt, (m, mv) in enumerate(zip(ann.masks, ann.masks_visib)):
            masks.append(f"mask_{gt:06d}.png")
            masks_visib.append(f"mask_visib_{gt:06d}.png")
            write_mask(wd / masks[-1], m)
            write_mask(wd / masks_visib[-1], mv)
        write_visible_rles(wd, ann.masks_visib)
    exr_file = None
    if inp.outputs.exr and res.linear is not None:
        exr_file = "rgb.exr"
        write_exr(wd / exr_file, res.linear)
    normals_file, nocs_file = geometry_maps(w, inp.outputs, wd, cam, ann, ctx.by_id)
    albedo_file = None
    if inp.outputs.albedo:
        albedo_file = "albedo.png"
        write_png(wd / albedo_file, albedo8)
    return dict(rgb_file=rgb_file, depth_file=depth_file, depth_scale=float(scale), mask_files=masks,
                mask_visib_files=masks_visib, exr_file=exr_file, normals_file=normals_file, nocs_file=nocs_file,
                depth_noisy_file=depth_noisy_file, albedo_file=albedo_file)


def geometry_maps(w: Worker, out: RenderedFiles, wd: Path, cam, ann, by_id: dict[int, ObjectAsset]) -> tuple[str | None, str | None]:
    """normals.exr and nocs.exr from the annotation's depth, when the spec asks for them."""
    from ..annotate.maps import nocs_map, normals_from_depth
    from ..outputs.images import write_exr

    warp = w.lens_warp()
    rays = warp.rays if warp else None  # through a lens, each pixel's own ray instead of K
    normals_file = nocs_file = None
    if out.normals:
        normals_file = "normals.exr"
        write_exr(wd / normals_file, normals_from_depth(ann.depth, cam.K_array, rays))
    if out.nocs:
        diagonals = [float(np.linalg.norm(by_id[g.obj_id].extents)) for g in ann.instances]
        poses = [(g.R_m2c, g.t_m2c) for g in ann.instances]
        nocs_file = "nocs.exr"
        write_exr(wd / nocs_file, nocs_map(ann.depth, cam.K_array, ann.masks_visib, poses, diagonals, rays))
    return normals_file, nocs_file


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
    return plugin.error_target(plugin.options_for(inp.backend, inp.quality), inp.quality)


def draw(ctx: _Render, cam, seed: int) -> RenderResult:
    """One image from the backend: one render of the level's samples, or, under an error target,
    pairs of renders with independent seeds until the image's estimated error reaches the target."""
    clamp = ctx.inp.quality.clamp
    if ctx.target is None:
        return ctx.backend.render(cam, ctx.preset, seed, clamp=clamp)

    def one(samples: int, i: int) -> RenderResult:
        preset = ctx.preset.model_copy(update={"aa": samples, "diffuse_rays": samples, "specular_rays": samples})
        return ctx.backend.render(cam, preset, seed if i == 0 else seeds.job_seed(seed, f"render/{i}"), clamp=clamp)

    done = render_to_target(one, ctx.target, linear_to_srgb8)
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
