"""Cycles (Blender 5.0, bpy wheel) render backend: PBR path tracing on the CPU.

See docs/backends/cycles.md for the preset mapping and the traps this avoids.
"""

from __future__ import annotations

import atexit
import contextlib
import functools
import os
import shutil
import sys
import tempfile
import threading
import time
import warnings
from dataclasses import replace
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from specsynth.model.colour import check_finite, linear_to_srgb8
from specsynth.model.conventions import c2w_during_exposure, opencv_to_blender_c2w
from specsynth.model.denoiser import oidn
from specsynth.model.ir import CameraIR, RenderResult, RenderScene
from specsynth.processes import captured_fd
from specsynth.spec.models import QualityPreset

from .settings import (
    PathSettings,
    blender_intrinsics,
    coerce_options,
    path_settings,
    resolve_threads,
    tbb_sized_to,
)

__all__ = ["CyclesBackend"]


def cycles_phases(events: list[tuple[float, str]], start: float, end: float, denoise: bool) -> dict[str, float]:
    """Seconds per phase of one ``render.render`` call, from Cycles' own status lines (the
    ``render_stats`` handler): scene sync (objects, BVH, shaders, kernels, images) until the first
    ``Sample 0/N``; path tracing until the last ``Sample``; then finishing and writing the EXR.
    Cycles reports its last sample only after denoising it, so with denoising on the two are one
    phase, ``trace+denoise`` (``specsynth bench`` prices the denoiser: the same views with and without)."""
    first_sample = next((t for t, s in events if "Sample " in s), None)
    last_sample = max((t for t, s in events if "Sample " in s), default=None)
    finished = next((t for t, s in events if "Finished" in s), None)
    if first_sample is None or last_sample is None:
        return {"cycles": end - start}
    return {
        "sync": first_sample - start,
        "trace+denoise" if denoise else "trace": last_sample - first_sample,
        "finish": (finished or end) - last_sample,
        "write": end - (finished or end),
    }

# Data-blocks the backend keeps for its whole life (camera, mask material and world).
_KEEP_PREFIX = "__specsynth"


def _read_exr_rgb(path: Path) -> dict[str, np.ndarray]:
    """The EXR's colour passes as HxWx3 arrays: {"Combined": ...} and, in a multilayer file written
    while denoising, {"Noisy Image": ...} (the render before the denoiser) and the denoiser's
    guides {"Denoising Albedo": ..., "Denoising Normal": ...} as well."""
    import OpenEXR

    out = {}
    with OpenEXR.File(str(path)) as f:
        for part in f.parts:
            ch = part.channels
            if "RGB" in ch or "RGBA" in ch:
                out["Combined"] = np.asarray(ch["RGB" if "RGB" in ch else "RGBA"].pixels, dtype=np.float32)
            elif all(c in ch for c in "RGB"):
                out["Combined"] = np.stack([np.asarray(ch[c].pixels, dtype=np.float32) for c in "RGB"], axis=-1)
            for name, c in ch.items():  # multilayer: "ViewLayer.<pass>", RGB(A) in one channel entry
                layer = name.split(".", 1)[-1]
                if layer in ("Combined", "Noisy Image", "Denoising Albedo"):
                    out[layer] = np.asarray(c.pixels, dtype=np.float32)
            # one channel entry per axis, "<view layer>.Denoising Normal.X"
            normal = [next((c for name, c in ch.items() if name.endswith(f"Denoising Normal.{a}")), None) for a in "XYZ"]
            if all(c is not None for c in normal):
                out["Denoising Normal"] = np.stack([np.asarray(c.pixels, dtype=np.float32) for c in normal], axis=-1)
    return {k: np.ascontiguousarray(v[..., :3]) for k, v in out.items()}


@contextlib.contextmanager
def _quiet_stdout():
    """Blender prints a 'Saved: ...' line per render straight to fd 1; keep worker logs readable."""
    fd = 1  # Blender writes to the C-level stdout whatever sys.stdout has been replaced with
    try:
        sys.stdout.flush()
    except (AttributeError, OSError, ValueError):
        pass
    saved = os.dup(fd)
    try:
        with open(os.devnull, "w") as devnull:
            os.dup2(devnull.fileno(), fd)
        yield
    finally:
        os.dup2(saved, fd)
        os.close(saved)


@contextlib.contextmanager
def _driver_probe_quiet():
    """Blender's device enumeration logs 'WARNING CUEW initialization failed: Error opening the
    library' (and HIPEW's) to stdout on every machine without a CUDA / HIP driver: that only means
    there is no such GPU, which the caller turns into one sentence (or an error naming the device
    the spec asked for)."""
    with captured_fd(1), captured_fd(2):
        yield


@functools.cache  # once per process
def _remove_session_folder_at_exit(bpy) -> None:
    # Blender's exit handler crashes at interpreter exit when bpy runs off the main thread (a Dask
    # worker's job thread), before it removes its session folder: remove it first. Read at exit:
    # loading factory settings moves the session folder.
    atexit.register(lambda: shutil.rmtree(bpy.app.tempdir, ignore_errors=True))


class CyclesBackend:
    name: ClassVar[str] = "cycles"

    def __init__(self, options: Any = None, *, threads: int = 0) -> None:
        self.options = coerce_options(options)
        self.threads = resolve_threads(self.options, threads)
        with tbb_sized_to(self.threads):
            import bpy  # once per worker process; the core never imports bpy

        if threading.current_thread() is not threading.main_thread():
            _remove_session_folder_at_exit(bpy)
        self._bpy = bpy
        self._tmp = Path(tempfile.mkdtemp(prefix="specsynth-cycles-"))
        self._scene_ir: RenderScene | None = None
        bpy.ops.wm.read_factory_settings(use_empty=True)
        self._configure_static()
        self._cam_obj = self._make_camera()
        from .build import build_mask_material, build_mask_world

        self._mask_mat = build_mask_material(bpy)
        self._mask_world = build_mask_world(bpy)
        self._events: list[tuple[float, str]] = []
        bpy.app.handlers.render_stats.append(self._on_stats)

    def _on_stats(self, stats, *_):
        self._events.append((time.perf_counter(), str(stats)))

    # ------------------------------------------------------------------ setup

    def version(self) -> str:
        app = self._bpy.app
        h = app.build_hash.decode() if isinstance(app.build_hash, bytes) else str(app.build_hash)
        return f"cycles (blender {app.version_string}, {h})"

    def _configure_static(self) -> None:
        """Settings that never change between renders; anything per-render is set in _apply."""
        sc = self._bpy.context.scene
        sc.render.engine = "CYCLES"
        cy = sc.cycles
        self.device = self._select_device()
        cy.use_animated_seed = False
        cy.sample_clamp_direct = 0.0
        # Glossy filter (default 1.0) trades bias for less noise; keep the estimate unbiased.
        cy.blur_glossy = 0.0
        cy.pixel_filter_type = "BOX"
        cy.filter_width = 1.0
        cy.volume_bounces = 0
        cy.transparent_max_bounces = 8
        # Blender 5.0's defaults, pinned: a release that changed them would change every image.
        # Measured on a demo view (docs/backends/cycles.md): without the light tree a sample cost
        # 0.7x the time for 2.1x the variance; without caustics 0.85x the time, 0.77x the variance
        # and 3 % of the light gone.
        cy.use_light_tree = True
        cy.caustics_reflective = True
        cy.caustics_refractive = True
        with _driver_probe_quiet():  # choosing the denoiser enumerates GPU devices too
            cy.denoiser = "OPENIMAGEDENOISE"
            cy.denoising_use_gpu = self.device != "cpu"
            cy.denoising_input_passes = "RGB_ALBEDO_NORMAL"
        r = sc.render
        # Persistent data keeps the synced scene (BVH, images) between renders; it silently ignores a
        # changed sample count (measurements.md), so _apply drops what is kept (switching it off frees
        # it) whenever a setting or the scene changes, and keeps the fresh full sync for the next render.
        r.use_persistent_data = False
        self._last_settings: tuple | None = None  # what the kept sync was made with; None: nothing kept
        self._last_draw: tuple | None = None  # (samples, seed, sample offset) of the last render
        r.threads_mode = "FIXED"
        r.threads = self.threads
        r.resolution_percentage = 100
        r.use_border = False
        r.film_transparent = False
        r.use_compositing = False
        r.use_sequencer = False
        r.use_file_extension = True
        vs = sc.view_settings
        # 5.0 defaults to AgX; the EXR is linear either way but keep the display path neutral too.
        vs.view_transform = "Standard"
        vs.look = "None"
        vs.exposure = 0.0
        vs.gamma = 1.0
        sc.display_settings.display_device = "sRGB"
        im = r.image_settings
        im.media_type = "IMAGE"
        im.file_format = "OPEN_EXR"
        im.color_mode = "RGB"
        im.color_depth = "32"
        im.exr_codec = "NONE"  # the file lives for milliseconds: skip compression

    def _select_device(self) -> str:
        """The device the options ask for, set up in Blender's preferences -> its kind ('cpu', 'cuda', ...)."""
        cy = self._bpy.context.scene.cycles
        want = self.options.device
        if want == "cpu":
            cy.device = "CPU"
            return "cpu"
        prefs = self._bpy.context.preferences.addons["cycles"].preferences
        for kind in (("OPTIX", "CUDA", "HIP", "ONEAPI") if want == "auto" else (want.upper(),)):
            try:
                prefs.compute_device_type = kind
            except TypeError:  # not built into this Blender
                continue
            with _driver_probe_quiet():
                prefs.get_devices()
            if any(d.type == kind for d in prefs.devices):
                for d in prefs.devices:
                    d.use = d.type == kind
                cy.device = "GPU"
                return kind.lower()
        prefs.compute_device_type = "NONE"
        if want != "auto":
            raise RuntimeError(f"cycles: backend.device is {want!r} but Blender finds no {want.upper()} device on "
                               "this machine; use device: cpu, or auto to fall back to the CPU")
        warnings.warn("cycles: no GPU found on this machine (device: auto); rendering on the CPU", stacklevel=2)
        cy.device = "CPU"
        return "cpu"

    def _make_camera(self):
        bpy = self._bpy
        cam = bpy.data.cameras.new("__specsynth_cam")
        cam.use_fake_user = True
        cam.type = "PERSP"
        cam.sensor_fit = "HORIZONTAL"
        ob = bpy.data.objects.new("__specsynth_cam", cam)
        ob.use_fake_user = True
        sc = bpy.context.scene
        sc.collection.objects.link(ob)
        sc.camera = ob
        return ob

    # ------------------------------------------------------------------ load

    def _clear(self) -> None:
        """Drop the previous arrangement's data-blocks so memory stays flat over many loads."""
        bpy = self._bpy
        sc = bpy.context.scene
        for ob in list(bpy.data.objects):
            if ob is not self._cam_obj:
                bpy.data.objects.remove(ob, do_unlink=True)
        for coll in (bpy.data.meshes, bpy.data.materials, bpy.data.lights, bpy.data.images, bpy.data.worlds):
            for block in list(coll):
                if not block.name.startswith(_KEEP_PREFIX):
                    coll.remove(block, do_unlink=True)
        sc.world = None
        bpy.data.orphans_purge(do_local_ids=True, do_linked_ids=True, do_recursive=True)

    def load(self, scene: RenderScene) -> None:
        from .build import build_light, build_meshes, build_world

        bpy = self._bpy
        self._clear()
        self._scene_ir = None
        self._last_settings = None  # a new scene: the next render syncs in full
        sc = bpy.context.scene
        coll = sc.collection
        build_meshes(bpy, coll, scene.meshes)
        self._lights = [build_light(bpy, coll, i, li) for i, li in enumerate(scene.lights)]
        self._world = build_world(bpy, scene.world)
        sc.world = self._world
        self._scene_ir = scene

    # ------------------------------------------------------------------ render

    def _set_camera(self, camera: CameraIR) -> None:
        from mathutils import Matrix

        sc = self._bpy.context.scene
        bi = blender_intrinsics(camera)
        cam = self._cam_obj.data
        cam.sensor_fit = "HORIZONTAL"
        cam.sensor_width = bi.sensor_width
        cam.lens = bi.lens
        cam.shift_x, cam.shift_y = bi.shift_x, bi.shift_y
        cam.clip_start, cam.clip_end = float(camera.near), float(camera.far)
        # A thin lens: Blender's f-number is its focal length over the pupil's diameter, both in mm
        # (1 Blender unit = 1 m), so the world-space pupil is exactly camera.aperture.
        cam.dof.use_dof = camera.aperture > 0
        if camera.aperture > 0:
            cam.dof.focus_object = None
            cam.dof.focus_distance = float(camera.focus_distance)
            cam.dof.aperture_fstop = float(bi.lens / (camera.aperture * 1000.0))
            cam.dof.aperture_blades = 0  # a round pupil, as Mitsuba's
        r = sc.render
        r.resolution_x, r.resolution_y = int(camera.width), int(camera.height)
        r.pixel_aspect_x, r.pixel_aspect_y = bi.pixel_aspect_x, bi.pixel_aspect_y
        self._cam_obj.matrix_world = Matrix(opencv_to_blender_c2w(camera.T_c2w).tolist())
        self._set_motion(camera)

    def _set_motion(self, camera: CameraIR) -> None:
        """Camera motion blur: the camera keyed at shutter open, mid-exposure and close, half a frame
        either side of the current one (Cycles' shutter of one frame, centred), linearly; still
        cameras carry no animation at all."""
        from mathutils import Matrix

        sc, ob = self._bpy.context.scene, self._cam_obj
        if not camera.motion:
            if sc.render.use_motion_blur or ob.animation_data is not None:
                sc.render.use_motion_blur = False
                ob.animation_data_clear()
                ob.matrix_world = Matrix(opencv_to_blender_c2w(camera.T_c2w).tolist())
            return
        sc.render.use_motion_blur = True
        sc.render.motion_blur_shutter = 1.0
        sc.render.motion_blur_position = "CENTER"
        ob.animation_data_clear()
        ob.rotation_mode = "QUATERNION"
        prefs = self._bpy.context.preferences.edit
        before, prefs.keyframe_new_interpolation_type = prefs.keyframe_new_interpolation_type, "LINEAR"
        try:
            f, previous = sc.frame_current, None
            for s in (-0.5, 0.0, 0.5):
                ob.matrix_world = Matrix(opencv_to_blender_c2w(c2w_during_exposure(camera.T_c2w, camera.motion, s)).tolist())
                if previous is not None and previous.dot(ob.rotation_quaternion) < 0:
                    ob.rotation_quaternion = -ob.rotation_quaternion  # the short way round
                previous = ob.rotation_quaternion.copy()
                ob.keyframe_insert("location", frame=f + s)
                ob.keyframe_insert("rotation_quaternion", frame=f + s)
        finally:
            prefs.keyframe_new_interpolation_type = before
        sc.frame_set(f)

    def _apply(self, ps: PathSettings, seed: int, offset: int = 0, skip_denoiser: bool = False) -> None:
        cy = self._bpy.context.scene.cycles
        # Samples offset..offset+n of the sequence: a render of offset + n samples of which only
        # the subset is traced (the sampler's sequence, tabulated Sobol, does not depend on the
        # total; measured: [0, 8) and [8, 16) averaged equal [0, 16) to 3e-6).
        cy.use_sample_subset = offset > 0
        cy.samples = offset + ps.samples
        if offset:
            cy.sample_offset, cy.sample_subset_length = offset, ps.samples
        cy.seed = int(seed) % (2**31)
        cy.max_bounces = ps.max_bounces
        cy.diffuse_bounces = ps.diffuse_bounces
        cy.glossy_bounces = ps.glossy_bounces
        cy.transmission_bounces = ps.transmission_bounces
        # skip_denoiser: the passes the denoiser takes, written without running it (measured:
        # Combined is then the denoising render's Noisy Image, bit for bit, and the guides are its).
        cy.use_denoising = ps.denoise and not skip_denoiser
        cy.denoising_prefilter = ps.denoise_prefilter
        cy.denoising_quality = ps.denoise_quality
        cy.use_adaptive_sampling = ps.adaptive_threshold is not None
        if ps.adaptive_threshold is not None:
            cy.adaptive_threshold = ps.adaptive_threshold
            cy.adaptive_min_samples = 0
        cy.sample_clamp_indirect = ps.clamp_indirect
        cy.use_guiding = ps.guiding
        # Open PGL's training is threaded; its deterministic mode keeps the pixels reproducible.
        cy.use_deterministic_guiding = True
        cy.pixel_filter_type = "BOX"
        cy.filter_width = 1.0
        sc = self._bpy.context.scene
        r = sc.render
        r.threads = self.threads
        # While denoising, the render before the denoiser is written too (RenderResult.noisy).
        self._bpy.context.view_layer.cycles.denoising_store_passes = ps.denoise
        im = r.image_settings
        if im.media_type != ("MULTI_LAYER_IMAGE" if ps.denoise else "IMAGE"):  # a new media type resets the format
            im.media_type = "MULTI_LAYER_IMAGE" if ps.denoise else "IMAGE"
            im.file_format = "OPEN_EXR_MULTILAYER" if ps.denoise else "OPEN_EXR"
            im.color_mode, im.color_depth, im.exr_codec = "RGB", "32", "NONE"
            # One part for all passes: Blender 5.0's multipart writer fails on non-square pixels
            # ("Conflicting attributes ... pixelAspectRatio"), the interleaved one does not.
            im.use_exr_interleave = True
        r.use_persistent_data = self.options.persistent
        key = (replace(ps, samples=0), skip_denoiser, self.threads, r.resolution_x, r.resolution_y)
        if key != self._last_settings:
            r.use_persistent_data = False  # dropped: a full sync of the changed settings
            r.use_persistent_data = self.options.persistent
        elif (ps.samples, seed, offset) != self._last_draw:
            # Persistent data keeps the integrator's last seed and sample count unless the scene
            # is tagged for an update (measured on bare bpy: untagged, a new seed or sample count
            # rendered the same pixels); tagged, the render equals a fully synced one bit for bit
            # and the BVH is kept: a change of samples alone no longer costs a full sync.
            sc.update_tag()
        self._last_settings, self._last_draw = key, (ps.samples, seed, offset)

    def _render_exr(self, stem: str) -> np.ndarray:
        bpy = self._bpy
        sc = bpy.context.scene
        path = self._tmp / f"{stem}.exr"
        sc.render.filepath = str(path)
        self._events.clear()
        t0 = time.perf_counter()
        with _quiet_stdout():
            bpy.ops.render.render(write_still=True)
        t1 = time.perf_counter()
        try:
            passes = _read_exr_rgb(path)
        finally:
            path.unlink(missing_ok=True)
        denoise = bool(sc.cycles.use_denoising)
        self.last_phases = {**cycles_phases(self._events, t0, t1, denoise), "readback": time.perf_counter() - t1}
        return passes

    def _require_scene(self) -> RenderScene:
        if self._scene_ir is None:
            raise RuntimeError("cycles: render() called before load()")
        return self._scene_ir

    def render(self, camera: CameraIR, quality: QualityPreset, seed: int, *, clamp: float | None = None,
               sample_offset: int = 0, skip_denoiser: bool = False) -> RenderResult:
        """One view; ``sample_offset``: the samples from there on of the sequence ``seed`` starts
        (Capabilities.continues_samples); ``skip_denoiser``: with denoising on, the render before
        the denoiser and its guides, not denoised (the core denoises them, ``denoise``)."""
        scene = self._require_scene()
        budget = self.options.light_path_budget
        ps = path_settings(
            quality, self.options, has_glossy=scene.has_glossy or not budget,
            has_transmission=scene.has_transmission or not budget, clamp=clamp,
        )
        t0 = time.perf_counter()
        self._set_camera(camera)
        skip = bool(skip_denoiser) and ps.denoise
        self._apply(ps, seed, int(sample_offset), skip)
        t_setup = time.perf_counter()
        passes = self._render_exr("beauty")
        linear = passes["Combined"]
        noisy = linear if skip else passes.get("Noisy Image")
        guides = None
        if noisy is not None and "Denoising Albedo" in passes and "Denoising Normal" in passes:
            guides = np.concatenate([passes["Denoising Albedo"], passes["Denoising Normal"]], axis=-1)
        seconds = time.perf_counter() - t0
        check_finite(linear, "cycles render")
        stats = ps.stats()
        stats.update(seconds=round(seconds, 4), threads=self.threads, seed=int(seed) % (2**31), device=self.device)
        t_tone = time.perf_counter()
        rgb = linear_to_srgb8(linear)
        stats["phases"] = {"setup": t_setup - t0, **self.last_phases, "tonemap": time.perf_counter() - t_tone}
        return RenderResult(rgb=rgb, linear=linear, stats=stats, noisy=noisy, guides=guides)

    def denoise(self, linear: np.ndarray, guides: np.ndarray) -> np.ndarray:
        """``linear`` denoised with its guides (RenderResult.guides) by OpenImageDenoise on the CPU,
        with this backend's quality and prefilter: the images the core makes of several renders."""
        return oidn(linear, guides, self.options.denoise_quality, self.options.denoise_prefilter, who="cycles")

    def render_index_masks(self, camera: CameraIR) -> np.ndarray:
        """HxW int32 instance map from Cycles itself: -1 background/scene geometry, else MeshInstance.inst.

        The emission override renders each object's pass index (inst + 1) as radiance; with one sample at
        the pixel centre (box filter of width ~0) and no bounces every pixel holds exactly one id.
        """
        self._require_scene()
        bpy = self._bpy
        sc = bpy.context.scene
        vl = bpy.context.view_layer
        cy = sc.cycles
        self._set_camera(camera)
        saved = dict(
            samples=cy.samples, max_bounces=cy.max_bounces, use_denoising=cy.use_denoising,
            use_adaptive_sampling=cy.use_adaptive_sampling, filter_width=cy.filter_width,
            sample_clamp_indirect=cy.sample_clamp_indirect, use_sample_subset=cy.use_sample_subset,
        )  # fmt: skip
        hidden = [ob for ob in sc.objects if ob.type == "LIGHT" and not ob.hide_render]
        world = sc.world
        sc.render.use_persistent_data = False  # other settings, overrides: a full sync, before and after
        self._last_settings = None
        try:
            cy.samples = 1
            cy.use_sample_subset = False  # the first sample, at the pixel centre, whatever rendered last
            cy.max_bounces = 0
            cy.use_denoising = False
            cy.use_adaptive_sampling = False
            cy.filter_width = 0.01  # Cycles' minimum: the single sample sits at the pixel centre
            cy.sample_clamp_indirect = 0.0
            vl.material_override = self._mask_mat
            sc.world = self._mask_world
            for ob in hidden:
                ob.hide_render = True
            ids = self._render_exr("mask")["Combined"][..., 0]
        finally:
            vl.material_override = None
            sc.world = world
            for ob in hidden:
                ob.hide_render = False
            for k, v in saved.items():
                setattr(cy, k, v)
        return (np.rint(ids).astype(np.int32) - 1).clip(min=-1)

    def close(self) -> None:
        if self._bpy is not None:
            self._clear()
            self._scene_ir = None
            # bpy's handler lists are process-wide: a closed backend must not keep timing renders.
            handlers = self._bpy.app.handlers.render_stats
            if self._on_stats in handlers:
                handlers.remove(self._on_stats)
        shutil.rmtree(self._tmp, ignore_errors=True)

    def __del__(self) -> None:  # the temp dir must not outlive a crashed worker loop
        tmp = getattr(self, "_tmp", None)
        if tmp is not None and os.path.isdir(tmp):
            shutil.rmtree(tmp, ignore_errors=True)
