"""The photo baseline (the paper's BL images): dataset objects rasterised with OpenGL (pyrender over
EGL) under random lights and composited over random real photographs, from the same cameras as
the PBR images.

Only the dataset objects are drawn (capability ``draws_scene=False``): the scene's stage geometry, lights
and world are ignored, the photograph stands in for them. Everything random in one image (the
background and its crop, the lights, the augmentation) derives from the ``seed`` passed to
``render``; nothing depends on what was rendered before.
"""

from __future__ import annotations

import os
import time
from importlib import metadata
from typing import Any, ClassVar

import numpy as np
from OpenGL.error import GLError  # noqa: E402  (after .gl, see above)

from specsynth.model.colour import linear_to_srgb
from specsynth.model.conventions import cam_to_world, opencv_to_opengl_c2w
from specsynth.model.ir import CameraIR, MeshInstance, RenderResult, RenderScene
from specsynth.spec.models import QualityPreset
from specsynth.views.augment import augment

from . import gl  # first: it selects the EGL platform before OpenGL is imported
from .backgrounds import BackgroundError, BackgroundPool
from .gl import pyrender
from .options import PhotoOptions

__all__ = ["PhotoBackend", "BackgroundError"]

# Bump when a change alters pixels for the same inputs (it is part of every render job's key).
ALGORITHM_VERSION = 4  # 2: background and augmentation maths without BLAS; 3: pano trigonometry in float64;
# 4: lights summed in the order they are drawn

# Random light ranges. pyrender shades a white Lambertian surface facing a light of intensity E as
# about 0.25 * E, so E in [1.2, 4] spans dim to bright without washing out.
_IRRADIANCE = (1.2, 4.0)
_POINT_FRACTION = 0.5  # share of point lights; the rest are directional
_POINT_DISTANCE = (2.0, 5.0)  # in radii of the objects' bounding sphere
_TINT = 0.15  # max per-channel deviation of a light's colour from white


def _gamma22_to_srgb_lut() -> np.ndarray:
    # pyrender encodes with a plain 1/2.2 power; re-encode with the sRGB curve every backend uses.
    x = np.arange(256, dtype=np.float64) / 255.0
    return np.round(linear_to_srgb(x**2.2) * 255.0).astype(np.uint8)


def _frame_from_z(z: np.ndarray) -> np.ndarray:
    """A rotation whose third column is the unit vector ``z``."""
    z = z / np.linalg.norm(z)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1)


def _package_version(name: str) -> str | None:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None


class PhotoBackend:
    name: ClassVar[str] = "photo"

    def __init__(self, options: Any = None, *, threads: int = 0) -> None:
        if options is None:
            options = {"name": "photo"}
        if isinstance(options, dict):
            options = PhotoOptions.model_validate({**options, "name": "photo"})
        if not isinstance(options, PhotoOptions):
            raise TypeError(f"photo backend options must be PhotoOptions or a dict, got {type(options).__name__}")
        self.options = options
        self.threads = int(threads)
        if self.threads > 0:
            # llvmpipe reads its thread count when the process's EGL display is first initialised,
            # so this only takes effect if no pyrender context exists yet in this process.
            os.environ["LP_NUM_THREADS"] = str(self.threads)
        # Fails here, not at the first render, on a missing or empty folder.
        self._backgrounds = BackgroundPool(options.backgrounds)
        self._lut = _gamma22_to_srgb_lut()
        self._meshes: dict[tuple, pyrender.Mesh] = {}
        self._textures: dict[str, pyrender.Texture] = {}
        self._renderer: pyrender.OffscreenRenderer | None = None
        self._scene: pyrender.Scene | None = None
        self._scene_ir: RenderScene | None = None
        self._objects: tuple[MeshInstance, ...] = ()
        self._centre = np.zeros(3)
        self._radius = 0.1

    # ------------------------------------------------------------------ protocol

    def version(self) -> str:
        parts = [f"photo-{ALGORITHM_VERSION}", f"pyrender-{_package_version('pyrender') or 'unknown'}"]
        if self.options.backgrounds == "builtin":
            # The built-in backgrounds are package data: their versions change the pixels too.
            parts.append(f"skimage-{_package_version('scikit-image') or 'none'}")
            parts.append(f"bpy-{_package_version('bpy') or 'none'}")
        return " ".join(parts)

    def load(self, scene: RenderScene) -> None:
        objects = scene.objects()
        pr_scene = gl.Scene(bg_color=(0.0, 0.0, 0.0, 0.0), ambient_light=(0.0, 0.0, 0.0))
        corners = []
        for inst in objects:
            key = (inst.mesh_key, inst.material)
            mesh = self._meshes.get(key)
            if mesh is None:
                mesh = self._meshes[key] = gl.build_mesh(inst.mesh_path, inst.material, self._textures)
            pose = inst.matrix
            pr_scene.add(mesh, pose=pose, name=inst.name)
            lo, hi = mesh.bounds
            box = np.array([[x, y, z, 1.0] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
            corners.append(np.einsum("ij,kj->ik", box, pose)[:, :3])  # box @ pose.T without BLAS
        self._scene = pr_scene
        self._scene_ir = scene
        self._objects = objects
        if corners:
            pts = np.concatenate(corners)
            lo, hi = pts.min(0), pts.max(0)
            self._centre = (lo + hi) / 2
            self._radius = max(float(np.linalg.norm(hi - lo)) / 2, 0.05)
        else:
            self._centre, self._radius = np.zeros(3), 0.1

    def render(self, camera: CameraIR, quality: QualityPreset, seed: int, *, clamp: float | None = None) -> RenderResult:
        # Of the quality preset only ``aa`` maps to a rasteriser (MSAA); clamp is path-tracer only.
        if self._scene is None:
            raise RuntimeError("photo backend: render() called before load()")
        t0 = time.perf_counter()
        W, H = int(camera.width), int(camera.height)
        # Independent streams, so e.g. a different light count leaves the background unchanged.
        bg_ss, light_ss, aug_ss = np.random.SeedSequence(int(seed)).spawn(3)
        background, bg_key = self._backgrounds.sample(W, H, np.random.default_rng(bg_ss))
        t_bg = time.perf_counter()

        # Closed-form inverse: exact, and np.linalg.inv costs milliseconds under BLAS contention.
        T_c2w = cam_to_world(camera.R_w2c, camera.t_w2c)
        lights, ambient, n_point = self._draw_lights(T_c2w[:3, 3], np.random.default_rng(light_ss))
        gl_camera = gl.KCamera(camera.K_array, camera.near, camera.far)
        cam_pose = opencv_to_opengl_c2w(T_c2w)
        # The preset's camera rays per pixel: one ray is a single-sampled raster, more get
        # pyrender's 4x MSAA (it offers no other count).
        samples = 0 if quality.aa <= 1 else 4
        try:
            rgba = self._rasterise(gl_camera, cam_pose, lights, ambient, W, H, samples)
        except GLError:
            # Another pyrender user in this process terminated the shared EGL display (pyrender's
            # OffscreenRenderer.delete does): start a new context, re-upload everything, retry once.
            self._reset_gl()
            rgba = self._rasterise(gl_camera, cam_pose, lights, ambient, W, H, samples)
        t_gl = time.perf_counter()

        rgb = self._composite(rgba, background)
        rgb = augment(rgb, self.options.augment, np.random.default_rng(aug_ss))
        t_end = time.perf_counter()
        stats = {
            "background": bg_key,
            "lights": len(lights),
            "point_lights": n_point,
            "ambient": ambient,
            "msaa": max(samples, 1),
            "seconds": t_end - t0,
            "seconds_background": t_bg - t0,
            "seconds_raster": t_gl - t_bg,
            "phases": {"background": t_bg - t0, "raster": t_gl - t_bg, "composite": t_end - t_gl},
        }
        return RenderResult(rgb=np.ascontiguousarray(rgb), linear=None, stats=stats)

    def close(self) -> None:
        if self._renderer is not None:
            gl.release_renderer(self._renderer)
            self._renderer = None
        # The GL buffers these held are gone with the context; rebuilt on the next load.
        self._meshes.clear()
        self._textures.clear()
        self._scene = None
        self._scene_ir = None

    def __del__(self):
        # Without this, pyrender's own finaliser would terminate the process-wide EGL display.
        try:
            self.close()
        except Exception:  # noqa: BLE001 - interpreter shutdown: modules may already be gone
            pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    # ------------------------------------------------------------------ internals

    def _rasterise(self, camera, cam_pose, lights, ambient: float, width: int, height: int, samples: int) -> np.ndarray:
        """RGBA of the loaded objects; camera and lights are added for this view only."""
        scene = self._scene
        nodes = [scene.add(camera, pose=cam_pose)]
        # Named in drawing order: gl.Scene hands the lights to the shader in name order.
        nodes += [scene.add(light, pose=pose, name=f"light{i:03d}") for i, (light, pose) in enumerate(lights)]
        scene.ambient_light = np.full(3, ambient)
        try:
            if self._renderer is None:
                self._renderer = gl.new_renderer(width, height, samples)
            else:
                self._renderer.viewport_width, self._renderer.viewport_height = width, height
            self._renderer._renderer.samples = samples
            # No shadows: the objects float over a photograph with no ground to receive them, point
            # lights cannot cast them in pyrender (NotImplementedError), and each directional
            # shadow map is another full pass.
            color, _depth = self._renderer.render(scene, flags=pyrender.RenderFlags.RGBA)
        finally:
            for node in nodes:
                scene.remove_node(node)
        return color

    def _reset_gl(self) -> None:
        if self._renderer is not None:
            gl.discard_renderer(self._renderer)
            self._renderer = None
        self._meshes.clear()
        self._textures.clear()
        self.load(self._scene_ir)

    def _composite(self, rgba: np.ndarray, background: np.ndarray) -> np.ndarray:
        """Object layer over the photo. pyrender's colour is already premultiplied by coverage
        (MSAA resolved over a transparent black clear; alpha is 0 or 1 without MSAA), so
        out = fg + (1 - alpha) * bg.
        Integer arithmetic: this runs on every pixel and float32 costs 4x as much here."""
        inv_alpha = 255 - rgba[..., 3:4].astype(np.uint16)
        out = background * inv_alpha  # uint16: 255 * 255 fits
        out += 127
        out //= 255
        out += self._lut[rgba[..., :3]]
        # fg <= alpha (premultiplied), so fg + (255 - alpha) * bg / 255 <= 255; min() guards rounding.
        np.minimum(out, 255, out=out)
        return out.astype(np.uint8)

    def _draw_lights(self, cam_pos: np.ndarray, rng: np.random.Generator):
        """Random lights for one view: ([(pyrender light, 4x4 pose)], ambient, number of point lights)."""
        lo, hi = self.options.lights
        n = int(rng.integers(lo, hi + 1))
        a_lo, a_hi = self.options.ambient
        ambient = float(rng.uniform(a_lo, a_hi))
        to_cam = cam_pos - self._centre
        norm = np.linalg.norm(to_cam)
        to_cam = to_cam / norm if norm > 0 else np.array([0.0, 0.0, 1.0])
        lights = []
        n_point = 0
        for _ in range(n):
            # A fixed number of draws per light keeps later lights independent of earlier kinds.
            u = rng.standard_normal(3)
            kind_u, irr_u, dist_u = rng.uniform(size=3)
            tint = 1.0 - _TINT * rng.uniform(size=3)
            # Directions biased towards the camera's side so the visible faces are mostly lit,
            # as in photographs taken with the light behind the photographer.
            direction = u / max(np.linalg.norm(u), 1e-9) + to_cam
            if np.linalg.norm(direction) < 1e-6:
                direction = to_cam
            direction = direction / np.linalg.norm(direction)
            irradiance = _IRRADIANCE[0] + (_IRRADIANCE[1] - _IRRADIANCE[0]) * irr_u
            pose = np.eye(4)
            pose[:3, :3] = _frame_from_z(direction)  # lights shine along their local -Z
            if kind_u < _POINT_FRACTION:
                dist = self._radius * (_POINT_DISTANCE[0] + (_POINT_DISTANCE[1] - _POINT_DISTANCE[0]) * dist_u)
                pose[:3, 3] = self._centre + direction * dist
                light = pyrender.PointLight(color=tint, intensity=irradiance * dist**2)
                n_point += 1
            else:
                light = pyrender.DirectionalLight(color=tint, intensity=irradiance)
            lights.append((light, pose))
        return lights, ambient, n_point
