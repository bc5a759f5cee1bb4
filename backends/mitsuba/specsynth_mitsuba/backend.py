"""The Mitsuba 3 render backend (see docs/backends/mitsuba.md)."""

from __future__ import annotations

import gc
import os
import time
import warnings
from typing import Any, ClassVar

import numpy as np

from specsynth.assets.library.cache import cache_dir
from specsynth.assets.meshio import MeshData, read_mesh
from specsynth.model.colour import check_finite, linear_to_srgb8
from specsynth.model.conventions import cam_to_world, opencv_to_mitsuba_c2w
from specsynth.model.denoiser import oidn
from specsynth.model.ir import CameraIR, RenderResult, RenderScene
from specsynth.spec.models import QualityPreset

from . import mapping
from . import scene as scene_mod
from .options import MitsubaOptions
from .sensor import PINHOLE, register_pinhole_sensor
from .textures import register_product_texture
from .variant import choose_variant


# Worst-case reprojection error (px) below which Mitsuba's square-pixel perspective sensor counts as
# exact; above it the K sensor renders (JIT variants) or stats report fy_error_px (scalar_rgb).
EXACT_PX = 1e-3


def _options(options: Any) -> MitsubaOptions:
    if options is None:
        return MitsubaOptions()
    if isinstance(options, MitsubaOptions):
        return options
    return MitsubaOptions.model_validate({**dict(options), "name": "mitsuba"})


def keep_kernels_in_our_cache() -> None:
    """Dr.Jit's disk cache of compiled kernels under specsynth's cache (``<cache>/drjit``), not
    ``~/.drjit``: a build writes only to --out and the cache. Read by Dr.Jit when it first
    starts in the process, so set before Mitsuba is imported; a DRJIT_CACHE_DIR the user set wins."""
    os.environ.setdefault("DRJIT_CACHE_DIR", str(cache_dir() / "drjit"))


class MitsubaBackend:
    name: ClassVar[str] = "mitsuba"

    def __init__(self, options: Any = None, *, threads: int = 0) -> None:
        keep_kernels_in_our_cache()
        self.options = _options(options)
        self.variant, self.skipped_variants = choose_variant(self.options.variant)
        import drjit as dr
        import mitsuba as mi

        mi.set_variant(self.variant)
        register_product_texture(mi)
        register_pinhole_sensor(mi)
        if threads > 0:
            dr.set_thread_count(int(threads))
        self._mi, self._dr = mi, dr
        self._mesh_cache: dict[str, MeshData] = {}
        self._textures = scene_mod.DecodedTextures()
        self._scene = None
        # Sensors and integrators are rebuilt only when their settings change; the camera pose is
        # a traversable parameter, so moving it does not rebuild (or, in JIT variants, recompile).
        self._sensor = None
        self._sensor_key: tuple | None = None
        self._sensor_params = None
        self._sensor_type = "perspective"
        self._integrators: dict[tuple[int, int], Any] = {}
        self._guide_integrator = None
        self._clamp_warned = False

    # ------------------------------------------------------------------ protocol

    def version(self) -> str:
        return f"mitsuba {self._mi.__version__} ({self.variant}) drjit {self._dr.__version__}"

    def load(self, scene: RenderScene) -> None:
        mi = self._mi
        # Free the previous arrangement first: Dr.Jit identifies shapes/BSDFs in kernels by
        # registry ids, and ids still held by the old scene would give the new one different ids,
        # hence a different kernel and a recompilation (measured: ~0.5-2 s per arrangement).
        self._scene = None
        gc.collect()
        # Dr.Jit keeps freed buffers for reuse, and a new room's buffers rarely fit the last one's:
        # over 40 random rooms a worker grew 1.3 -> 2.2 GB; returning them at each load keeps it
        # at 0.7-1.4 GB over 100 rooms. (Its kernel cache was measured not to matter, and keeping it
        # is what lets an arrangement of the same structure reuse the last one's kernels.)
        self._dr.flush_malloc_cache()
        # Only this scene's meshes are kept: with a new room per arrangement the cache would
        # otherwise grow with every one.
        held, self._mesh_cache = self._mesh_cache, {}
        for inst in scene.meshes:
            if inst.mesh_key not in self._mesh_cache:
                data = held.get(inst.mesh_key)
                self._mesh_cache[inst.mesh_key] = data if data is not None else read_mesh(inst.mesh_path).validate(inst.mesh_path)
        d = scene_mod.scene_dict(mi, scene, self._mesh_cache, calibrate=self.options.match_cycles_bsdf,
                                 decoded=self._textures, emitter_sampling=self.options.emitter_sampling)
        if d.get("world", {}).get("type") == "sunsky" and not self._has_plugin("sunsky"):
            d["world"] = _sky_fallback(scene.world)
        # Serially: parallel loading created the emitters in an order that varied from run to run,
        # and their registry ids' order is part of the kernel, so a new arrangement of the same
        # structure recompiled now and then. Serial loading measured no slower on 2 cores (the
        # built-in scenes, 22-354 meshes: 0.06-1.3 s per load either way).
        self._scene = mi.load_dict(d, parallel=False)

    def render(self, camera: CameraIR, quality: QualityPreset, seed: int, *, clamp: float | None = None,
               skip_denoiser: bool = False) -> RenderResult:
        """One view; ``skip_denoiser``: with denoising on, the render before the denoiser and its
        guides, not denoised (the core denoises them, ``denoise``)."""
        if self._scene is None:
            raise RuntimeError("MitsubaBackend.render() before load()")
        mi, dr = self._mi, self._dr
        if clamp is not None and not self._clamp_warned:
            warnings.warn("Mitsuba's path integrator has no radiance clamp; 'quality.clamp' is ignored", stacklevel=2)
            self._clamp_warned = True
        t_setup = time.perf_counter()
        st = mapping.integrator_settings(quality, self.options.sampler, self.options.samples)
        sensor, sset = self._sensor_for(camera, st)
        self._set_pose(camera)
        # Beauty alone: tracing the denoiser's guides inside every path sample (the `aov`
        # integrator around `path`) doubled the cost; they get a pass of their own below.
        integrator = self._integrator(st.max_depth, st.rr_depth)
        t0 = time.perf_counter()
        # An opaque seed is a kernel input rather than a constant baked into it, so a new seed
        # does not trigger a recompilation in JIT variants.
        seed32 = mapping.fold_seed(seed)
        seed_arg = dr.opaque(mi.UInt32, seed32) if dr.is_jit_v(mi.Float) else seed32
        image = mi.render(self._scene, sensor=sensor, integrator=integrator, seed=seed_arg, spp=st.spp)
        dr.eval(image)
        dr.sync_thread()  # LLVM kernels run asynchronously: wait, so "trace" is the tracing
        t_trace = time.perf_counter()
        img = np.array(image, dtype=np.float32)
        linear = img[..., :3]
        seconds = time.perf_counter() - t0
        check_finite(linear, f"mitsuba render ({self.variant})")
        linear = np.ascontiguousarray(np.maximum(linear, 0.0))
        t_read = time.perf_counter()
        denoise_seconds = guide_seconds = noisy = guides = guide_spp = None
        if self.options.denoise:
            noisy = linear
            # The guides take the beauty's seed and at least its samples (mapping.guide_samples):
            # with fewer (4), their antialiased edges differed from the image's and OIDN drew those
            # edges into it; with more they are the true edges (docs/backends/mitsuba.md).
            guide_spp = mapping.round_spp(mapping.guide_samples(st.spp), st.sampler)
            guides = self._guides(sensor, seed_arg, guide_spp)
            t1 = time.perf_counter()
            guide_seconds = t1 - t_read
            guides = np.ascontiguousarray(guides[..., 0:6], np.float32)
            if not skip_denoiser:
                linear = self.denoise(linear, guides)
                denoise_seconds = time.perf_counter() - t1
        stats = {
            "variant": self.variant,
            "spp": st.spp,
            "requested_spp": st.requested_spp,
            "sampler": st.sampler,
            "max_depth": st.max_depth,
            "rr_depth": st.rr_depth,
            "seconds": seconds,
            "seed32": seed32,
            "sensor": self._sensor_type,
        }
        if self._sensor_type == "perspective" and sset.fy_error_px > EXACT_PX:
            # only the scalar fallback renders fy != fx with square pixels (see _use_k_sensor)
            stats["fy_error_px"] = sset.fy_error_px
        if clamp is not None:
            stats["clamp_ignored"] = clamp
        if self.options.denoise:
            stats["guide_spp"] = guide_spp
        if denoise_seconds is not None:
            stats["denoise_seconds"] = denoise_seconds
        t_tone = time.perf_counter()
        rgb = linear_to_srgb8(linear)
        # Scene sync happens in load(); here: camera/integrator set-up (and a kernel compile on a
        # new setting), path tracing (kernel launch to evaluated image), read-back, denoise, tone map.
        stats["phases"] = {"setup": t0 - t_setup, "trace": t_trace - t0, "readback": t_read - t_trace,
                           "guides": guide_seconds or 0.0, "denoise": denoise_seconds or 0.0,
                           "tonemap": time.perf_counter() - t_tone}
        return RenderResult(rgb=rgb, linear=linear, stats=stats, noisy=noisy, guides=guides)

    def denoise(self, linear: np.ndarray, guides: np.ndarray) -> np.ndarray:
        """``linear`` denoised as a render is (OpenImageDenoise on the CPU, as Cycles runs it), with
        its guides (albedo, normal: RenderResult.guides); prefilter 'none' takes them as noise-free."""
        return oidn(linear, guides, self.options.denoise_quality, self.options.denoise_prefilter, who="mitsuba")

    def close(self) -> None:
        self._scene = None
        self._sensor = self._sensor_params = self._sensor_key = None
        self._sensor_type = "perspective"
        self._integrators.clear()
        self._guide_integrator = None
        self._mesh_cache.clear()

    # ------------------------------------------------------------------ internals

    def _has_plugin(self, name: str) -> bool:
        # (Mitsuba 3.9 has no PluginManager.get_plugin_class: calling it made this always False, so
        # every sky fell back to the constant one; tests/test_mitsuba_agreement.py guards it.)
        try:
            return self._mi.PluginManager.instance().plugin_type(name) != self._mi.ObjectType.Unknown
        except Exception:
            return False

    def _guides(self, sensor, seed_arg, spp: int) -> np.ndarray:
        """HxWx6 albedo and shading normal at the first hit (OIDN's guides), a cheap pass."""
        mi, dr = self._mi, self._dr
        if self._guide_integrator is None:
            self._guide_integrator = mi.load_dict({"type": "aov", "aovs": "albedo:albedo,nn:sh_normal"})
        img = mi.render(self._scene, sensor=sensor, integrator=self._guide_integrator, seed=seed_arg, spp=spp)
        dr.eval(img)
        dr.sync_thread()
        return np.array(img, dtype=np.float32)

    def _integrator(self, max_depth: int, rr_depth: int):
        key = (max_depth, rr_depth)
        if key not in self._integrators:
            path = {"type": "path", "max_depth": max_depth, "rr_depth": rr_depth, "hide_emitters": False}
            self._integrators[key] = self._mi.load_dict(path)
        return self._integrators[key]

    def _use_k_sensor(self, sset: mapping.SensorSettings) -> bool:
        """The K sensor (sensor.py) when the square-pixel ``perspective`` would be off by more than
        EXACT_PX (fy != fx or skew). Not in ``scalar_rgb``: there Mitsuba calls the Python sensor
        once per sample (~50x the whole render's cost, measured), so the scalar fallback keeps
        ``perspective`` and reports ``fy_error_px``."""
        return sset.fy_error_px > EXACT_PX and self._dr.is_jit_v(self._mi.Float)

    def _sensor_for(self, camera: CameraIR, st: mapping.IntegratorSettings):
        sset = mapping.sensor_settings(camera.K_array, camera.width, camera.height)
        lens, moving = camera.aperture > 0, bool(camera.motion)
        key = (camera.K, camera.width, camera.height, camera.near, camera.far, st.sampler, st.spp, lens, moving)
        if key != self._sensor_key:
            mi = self._mi
            if (lens or moving) and not self._dr.is_jit_v(mi.Float):
                raise ValueError("mitsuba: depth of field and motion blur need a JIT variant (llvm_ad_rgb or "
                                 f"cuda_ad_rgb); this one is {self.variant}")
            if lens or moving or self._use_k_sensor(sset):
                K = camera.K_array
                # exact for any upper-triangular K; same to_world frame, clip and children
                optics = {
                    "type": PINHOLE,
                    "fx": float(K[0, 0]),
                    "fy": float(K[1, 1]),
                    "cx": float(K[0, 2]),
                    "cy": float(K[1, 2]),
                    "skew": float(K[0, 1]),
                    **({"aperture_radius": camera.aperture / 2.0, "focus_distance": camera.focus_distance} if lens else {}),
                    **({"shutter_open": 0.0, "shutter_close": 1.0} if moving else {}),
                }
            else:
                # Mitsuba's own (C++) sensor when pixels are square: exact there, no Python in the loop
                optics = {
                    "type": "perspective",
                    "fov": sset.x_fov,
                    "fov_axis": "x",
                    "principal_point_offset_x": sset.ppo_x,
                    "principal_point_offset_y": sset.ppo_y,
                }
            self._sensor = mi.load_dict(
                {
                    **optics,
                    "near_clip": float(camera.near),
                    "far_clip": float(camera.far),
                    "film": {
                        "type": "hdrfilm",
                        "width": int(camera.width),
                        "height": int(camera.height),
                        "pixel_format": "rgb",
                        "component_format": "float32",
                        # Box = each sample lands in its own pixel only, as in the Cycles backend.
                        "rfilter": {"type": "box"},
                    },
                    "sampler": {"type": st.sampler, "sample_count": st.spp},
                }
            )
            self._sensor_params = mi.traverse(self._sensor)
            self._sensor_key = key
            self._sensor_type = optics["type"]
            got = self._sensor.sampler().sample_count()
            if got != st.spp:  # mapping.round_spp must mirror Mitsuba's own rounding
                raise RuntimeError(f"Mitsuba's {st.sampler} took {got} spp, expected {st.spp}")
        return self._sensor, sset

    def _set_pose(self, camera: CameraIR) -> None:
        c2w = opencv_to_mitsuba_c2w(cam_to_world(np.asarray(camera.R_w2c), np.asarray(camera.t_w2c)))
        self._sensor_params["to_world"] = self._mi.Transform4f(c2w.tolist())
        if camera.aperture > 0:
            self._sensor_params["aperture_radius"] = camera.aperture / 2.0
            self._sensor_params["focus_distance"] = camera.focus_distance
        if camera.motion:  # OpenCV camera frame -> Mitsuba's local (x and y flipped: a turn about z)
            t, r = camera.motion[:3], camera.motion[3:6]
            self._sensor_params["motion_translation"] = self._mi.Vector3f(-t[0], -t[1], t[2])
            self._sensor_params["motion_rotation"] = self._mi.Vector3f(-r[0], -r[1], r[2])
        self._sensor_params.update()


def _sky_fallback(world) -> dict:
    """For Mitsuba builds without ``sunsky`` (< 3.6): a uniform pale-blue sky, brightened to
    Blender's sky units like ``sunsky`` is. Crude (no horizon gradient, no colour shift with the
    sun); the sun itself is the scene's own sun light, as with ``sunsky``."""
    s = mapping.sky_scale(world.strength, min(max(world.turbidity, 1.0), 10.0), world.sun_elevation)
    # The constant radiance giving a white floor the horizontal irradiance of Mitsuba 3.9's sunsky
    # (turbidity 3, sun elevation 38 deg, sky_scale 1; measured: a 16x16 render of an albedo-1 floor;
    # 0.040-0.054 red at elevation 20-60 deg).
    return {"type": "constant", "radiance": {"type": "rgb", "value": [0.049 * s, 0.076 * s, 0.124 * s]}}
