"""The conformance suite every render backend must pass (in the spirit of fsspec's abstract tests).

Backend-agnostic: it talks to a backend only through ``specsynth.backend_api`` (discovery by entry
point name, then the ``RenderBackend`` protocol) and builds its own tiny scene in code, so it can
run against any plugin::

    from specsynth.testing.conformance import check_backend
    check_backend("mitsuba", {"name": "mitsuba"}, tmp_path)

or, one pytest test per check, in the backend's own tests: subclass
``specsynth.testing.suite.BackendConformanceTests`` (it runs every check of ``CHECKS`` on one
``ConformanceContext``) and add checks of the backend's own.

The scene: a 1 m grey plane (scene geometry), a textured box and a vertex-coloured sphere
(dataset objects), a sun and an area light, a grey world; an 80x60 camera with an off-centre
principal point. Renders use the paper's "low" preset, so path tracers stay cheap.
"""

from __future__ import annotations

import hashlib
import math
import pickle
import subprocess
import sys
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path
from typing import Any, Callable

import numpy as np

from ..assets.meshio import MeshData, mesh_bytes, write_mesh
from ..backend_api import RenderBackend, render_takes
from ..model.colour import check_finite
from ..model.ir import (
    CameraIR,
    LightIR,
    MaterialIR,
    MeshInstance,
    RenderResult,
    RenderScene,
    WorldIR,
    as_tuple,
)
from ..plugins import BackendPlugin, Capabilities, backend_plugin, load_backend
from ..spec.models import PAPER_PRESETS, BackendOptions
from ..views.cameras import look_at

WIDTH, HEIGHT = 80, 60
K = ((90.0, 0.0, 40.3), (0.0, 90.0, 28.7), (0.0, 0.0, 1.0))
SEED = 1234
QUALITY = PAPER_PRESETS["low"]

BOX_CENTRE = (0.07, 0.0, 0.04)
BOX_SIZE = 0.08
SPHERE_CENTRE = (-0.07, 0.02, 0.045)
SPHERE_RADIUS = 0.045
EYE = (0.05, -0.45, 0.3)
EYE_MOVED = (-0.32, -0.33, 0.22)
TARGET = (0.0, 0.0, 0.03)

# A 3x3 window around a projected object centre must differ from the render without that object
# by at least this much (mean absolute difference, 8-bit levels).
SILHOUETTE_MIN_DIFF = 12.0


class ConformanceError(AssertionError):
    pass


def _require(cond: bool, backend: str, msg: str) -> None:
    if not cond:
        raise ConformanceError(f"backend {backend!r}: {msg}")


# --------------------------------------------------------------------------- the test scene




def make_camera(eye=EYE, target=TARGET) -> CameraIR:
    R, t = look_at(eye, target)
    return CameraIR(K=K, width=WIDTH, height=HEIGHT, R_w2c=as_tuple(R), t_w2c=as_tuple(t), near=0.01, far=10.0)


def project(camera: CameraIR, point_w) -> tuple[float, float, float]:
    """OpenCV pixel coordinates (integer = pixel centre) and depth of a world point."""
    x_c = np.asarray(camera.R_w2c) @ np.asarray(point_w, dtype=np.float64) + np.asarray(camera.t_w2c)
    uvw = camera.K_array @ x_c
    return float(uvw[0] / uvw[2]), float(uvw[1] / uvw[2]), float(x_c[2])


def _box_mesh(size: float) -> MeshData:
    """Cube with one quad of 4 vertices per face, so every face has flat normals and its own UVs."""
    h = size / 2
    verts, normals, uvs, faces = [], [], [], []
    for axis in range(3):
        for sign in (1.0, -1.0):
            n = np.zeros(3)
            n[axis] = sign
            a, b = [i for i in range(3) if i != axis]
            base = len(verts)
            for (s, t) in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
                p = np.zeros(3)
                p[axis], p[a], p[b] = sign * h, s * h, t * h
                verts.append(p)
                normals.append(n)
                uvs.append(((s + 1) / 2, (t + 1) / 2))
            tri = [(base, base + 1, base + 2), (base, base + 2, base + 3)]
            # Counter-clockwise seen from outside: flip where the quad's winding points inwards.
            e1, e2 = verts[base + 1] - verts[base], verts[base + 2] - verts[base]
            if np.dot(np.cross(e1, e2), n) < 0:
                tri = [(i, k, j) for (i, j, k) in tri]
            faces += tri
    return MeshData(
        vertices=np.asarray(verts, np.float32),
        faces=np.asarray(faces, np.int32),
        normals=np.asarray(normals, np.float32),
        uv=np.asarray(uvs, np.float32),
    )


def _sphere_mesh(radius: float, n_lat: int = 12, n_lon: int = 24) -> MeshData:
    """UV sphere with smooth normals and vertex colours that vary with position."""
    verts, faces = [], []
    for i in range(n_lat + 1):
        theta = math.pi * i / n_lat
        for j in range(n_lon + 1):
            phi = 2 * math.pi * j / n_lon
            verts.append((math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)))
    for i in range(n_lat):
        for j in range(n_lon):
            a = i * (n_lon + 1) + j
            b = a + n_lon + 1
            if i > 0:
                faces.append((a, b, a + 1))
            if i < n_lat - 1:
                faces.append((a + 1, b, b + 1))
    unit = np.asarray(verts, np.float64)
    colors = np.empty((len(unit), 4), np.uint8)
    colors[:, 0] = 40
    colors[:, 1] = np.round(120 + 100 * unit[:, 2]).astype(np.uint8)
    colors[:, 2] = np.round(140 + 100 * unit[:, 0]).astype(np.uint8)
    colors[:, 3] = 255
    return MeshData(
        vertices=(unit * radius).astype(np.float32),
        faces=np.asarray(faces, np.int32),
        normals=unit.astype(np.float32),
        colors=colors,
    )


def _plane_mesh(size: float) -> MeshData:
    h = size / 2
    return MeshData(
        vertices=np.array([[-h, -h, 0], [h, -h, 0], [h, h, 0], [-h, h, 0]], np.float32),
        faces=np.array([[0, 1, 2], [0, 2, 3]], np.int32),
        normals=np.tile(np.array([[0, 0, 1]], np.float32), (4, 1)),
    )


def _checker(path: Path, n: int = 32, cells: int = 4) -> None:
    from PIL import Image

    ij = np.indices((n, n)) // (n // cells)
    on = ((ij[0] + ij[1]) % 2).astype(bool)
    img = np.where(on[..., None], np.array([220, 40, 30], np.uint8), np.array([30, 60, 220], np.uint8))
    Image.fromarray(img.astype(np.uint8)).save(path)


def _write(folder: Path, name: str, mesh: MeshData) -> tuple[str, str]:
    path = folder / f"{name}.ply"
    write_mesh(path, mesh.validate(name))
    return str(path), hashlib.sha256(mesh_bytes(mesh)).hexdigest()


def _pose(translation, yaw_deg: float = 0.0) -> tuple:
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    T = np.eye(4)
    T[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    T[:3, 3] = translation
    return as_tuple(T)


def _light_pose(position, target=(0.0, 0.0, 0.0)) -> tuple:
    """World-from-light with the light's local -Z pointing at ``target``."""
    position, target = np.asarray(position, float), np.asarray(target, float)
    z = position - target
    z /= np.linalg.norm(z)
    x = np.cross((0.0, 1.0, 0.0) if abs(z[1]) < 0.9 else (1.0, 0.0, 0.0), z)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    T[:3, 3] = position
    return as_tuple(T)


@dataclass(frozen=True)
class ConformanceScenes:
    full: RenderScene  # plane + box + sphere
    no_box: RenderScene  # plane + sphere
    no_sphere: RenderScene  # plane + box
    no_objects: RenderScene  # plane only
    camera: CameraIR
    camera_moved: CameraIR


def build_scenes(folder: str | Path) -> ConformanceScenes:
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    texture = folder / "checker.png"
    _checker(texture)
    box_path, box_key = _write(folder, "box", _box_mesh(BOX_SIZE))
    sphere_path, sphere_key = _write(folder, "sphere", _sphere_mesh(SPHERE_RADIUS))
    plane_path, plane_key = _write(folder, "plane", _plane_mesh(1.0))

    plane = MeshInstance("stage", plane_path, plane_key, _pose((0, 0, 0)), MaterialIR(base_color=(0.5, 0.5, 0.5)))
    box = MeshInstance(
        "obj_000001_0", box_path, box_key, _pose(BOX_CENTRE, 30.0),
        MaterialIR(base_color=(1.0, 1.0, 1.0), texture=str(texture), roughness=0.6), obj_id=1, inst=0,
    )
    sphere = MeshInstance(
        "obj_000002_0", sphere_path, sphere_key, _pose(SPHERE_CENTRE),
        MaterialIR(base_color=(1.0, 1.0, 1.0), use_vertex_colors=True, roughness=0.4), obj_id=2, inst=1,
    )
    lights = (
        LightIR(kind="sun", pose=_light_pose((0.3, -0.4, 1.0)), power=3.0),
        LightIR(kind="area", pose=_light_pose((0.4, -0.5, 0.7)), power=40.0, size=(0.3, 0.3)),
    )
    world = WorldIR(kind="color", color=(0.25, 0.25, 0.25))

    def scene(*meshes):
        return RenderScene(meshes=meshes, lights=lights, world=world)

    return ConformanceScenes(
        full=scene(plane, box, sphere),
        no_box=scene(plane, sphere),
        no_sphere=scene(plane, box),
        no_objects=scene(plane),
        camera=make_camera(EYE),
        camera_moved=make_camera(EYE_MOVED),
    )


# --------------------------------------------------------------------------- running a backend


class ConformanceContext:
    """One backend instance and the test scenes, shared by the checks (backends are slow to start)."""

    def __init__(
        self, name: str, options: Any = None, tmp_path: str | Path = ".", *, threads: int = 1, backend_class: type | None = None,
        capabilities: Capabilities | None = None,
    ):
        """``backend_class`` tests a class directly (before its entry point is registered, or a
        deliberately broken variant); by default the class is found by ``name`` like the core does.
        ``capabilities`` replaces what the plugin declares (a variant that claims more than it does)."""
        self.name = name
        if backend_class is not None:
            self.__dict__["backend_class"] = backend_class  # pre-fills the cached_property
        if capabilities is not None:
            self.__dict__["plugin"] = replace(backend_plugin(name), capabilities=capabilities)
        self.options = {"name": name} if options is None else options
        self.threads = threads
        self.tmp_path = Path(tmp_path)
        self.scenes = build_scenes(self.tmp_path / "conformance_scene")
        self._loaded: RenderScene | None = None

    @cached_property
    def plugin(self) -> BackendPlugin:
        return backend_plugin(self.name)

    @cached_property
    def backend_class(self) -> type:
        return self.plugin.load_class()

    @cached_property
    def backend(self):
        return self.backend_class(self.options, threads=self.threads)

    def load(self, scene: RenderScene) -> None:
        self.backend.load(scene)
        self._loaded = scene

    def render(self, scene: RenderScene | None = None, camera: CameraIR | None = None, seed: int = SEED) -> RenderResult:
        scene = self.scenes.full if scene is None else scene
        if self._loaded is not scene:
            self.load(scene)
        return self.backend.render(self.scenes.camera if camera is None else camera, QUALITY, seed)

    def close(self) -> None:
        if "backend" in self.__dict__:
            self.backend.close()
            del self.__dict__["backend"]
        self._loaded = None


def _rgb(ctx: ConformanceContext, result: RenderResult) -> np.ndarray:
    rgb = result.rgb
    _require(isinstance(rgb, np.ndarray), ctx.name, f"rgb is {type(rgb).__name__}, not a numpy array")
    _require(rgb.dtype == np.uint8, ctx.name, f"rgb dtype is {rgb.dtype}, expected uint8")
    _require(rgb.shape == (HEIGHT, WIDTH, 3), ctx.name, f"rgb shape is {rgb.shape}, expected {(HEIGHT, WIDTH, 3)}")
    return rgb


def _window(img: np.ndarray, u: float, v: float, r: int = 1) -> np.ndarray:
    x, y = int(round(u)), int(round(v))
    return img[max(y - r, 0) : y + r + 1, max(x - r, 0) : x + r + 1].astype(np.float64)


# --------------------------------------------------------------------------- the checks


def check_discovery(ctx: ConformanceContext) -> None:
    cls = ctx.backend_class
    found = load_backend(ctx.name)
    _require(found is cls, ctx.name, f"entry point {ctx.name!r} loads {found.__qualname__}, not {cls.__qualname__}")
    _require(getattr(cls, "name", None) == ctx.name, ctx.name, f"class {cls.__name__}.name is {getattr(cls, 'name', None)!r}")
    plugin = ctx.plugin
    _require(plugin.name == ctx.name, ctx.name, f"the plugin registered as {ctx.name!r} calls itself {plugin.name!r}")
    opts = plugin.options
    _require(isinstance(opts, type) and issubclass(opts, BackendOptions), ctx.name,
             "the plugin's options must subclass specsynth.spec.models.BackendOptions")
    _require(opts.model_validate({"name": ctx.name}).name == ctx.name, ctx.name, "the options model rejects its own name")
    for field in ("denoise", "samples"):  # what every spec may carry when only backend.name is swapped
        _require(field in opts.model_fields, ctx.name, f"the options model drops the shared field {field!r}")
    _require(isinstance(plugin.capabilities.draws_scene, bool), ctx.name, "capabilities.draws_scene must be a bool")
    _require(isinstance(ctx.backend, RenderBackend), ctx.name, "instance does not satisfy the RenderBackend protocol")


def check_version(ctx: ConformanceContext) -> None:
    v = ctx.backend.version()
    _require(isinstance(v, str) and v.strip() != "", ctx.name, f"version() must be a non-empty str, got {v!r}")
    _require("\n" not in v, ctx.name, "version() must be one line")
    _require(ctx.backend.version() == v, ctx.name, "version() changed between calls")


def check_render_shape(ctx: ConformanceContext) -> None:
    res = ctx.render()
    _require(isinstance(res, RenderResult), ctx.name, f"render() returned {type(res).__name__}, not RenderResult")
    rgb = _rgb(ctx, res)
    _require(isinstance(res.stats, dict), ctx.name, "stats must be a dict")
    _require(int(rgb.max()) > int(rgb.min()), ctx.name, "the image is a single flat colour")
    if res.linear is not None:
        lin = res.linear
        _require(lin.shape == (HEIGHT, WIDTH, 3), ctx.name, f"linear shape is {lin.shape}, expected {(HEIGHT, WIDTH, 3)}")
        _require(np.issubdtype(lin.dtype, np.floating), ctx.name, f"linear dtype is {lin.dtype}, expected float")
        check_finite(lin, f"backend {ctx.name!r}: linear")
    if res.guides is not None:
        _check_guides(ctx, ctx.backend, res)


def _check_guides(ctx: ConformanceContext, backend, res: RenderResult) -> None:
    """The denoiser's guides, with which the core denoises several renders together: HxWx6 float32
    (albedo in [0, 1], normal in [-1, 1]) beside the render before the denoiser, and the backend's
    ``denoise(linear, guides)``, which makes of that render about the image the backend denoised."""
    g = res.guides
    _require(res.noisy is not None and g.shape == (HEIGHT, WIDTH, 6) and g.dtype == np.float32, ctx.name,
             "guides need the render before the denoiser (noisy) and are HxWx6 float32: albedo, then normal")
    check_finite(g, f"backend {ctx.name!r}: guides")
    _require(float(g[..., :3].min()) >= 0.0 and float(g[..., :3].max()) <= 1.0 and float(np.abs(g[..., 3:]).max()) <= 1.0 + 1e-3,
             ctx.name, "guides: albedo must lie in [0, 1] and normals in [-1, 1]")
    denoise = getattr(backend, "denoise", None)
    _require(callable(denoise), ctx.name, "a backend that returns guides must offer denoise(linear, guides)")
    out = denoise(res.noisy, g)
    _require(out.shape == (HEIGHT, WIDTH, 3) and float(np.min(out)) >= 0.0, ctx.name,
             "denoise() must return an HxWx3 image, never negative")
    check_finite(out, f"backend {ctx.name!r}: denoise()")
    lin = np.asarray(res.linear, np.float64)

    def off(x) -> float:
        return float(np.mean((np.asarray(x, np.float64) - lin) ** 2 / (lin**2 + 1e-2)))

    _require(off(out) <= 0.5 * off(res.noisy), ctx.name,
             f"denoise(noisy, guides) is not the image the backend denoised (relMSE {off(out):.3g} against it, the "
             f"noisy render's {off(res.noisy):.3g})")


def check_denoiser_guides(ctx: ConformanceContext) -> None:
    """With ``denoise`` on, a render carries the render before its denoiser, and its guides if any
    pass ``_check_guides``. A backend instance of its own renders it, after the shared one is
    closed (a renderer may hold one scene per process, as bpy does: two instances at once would
    take each other's objects); the next check makes the shared one again."""
    _require_declared(ctx, "denoise")
    opts = ctx.options
    opts = {**opts, "denoise": True} if isinstance(opts, dict) else opts.model_copy(update={"denoise": True})
    ctx.close()
    backend = ctx.backend_class(opts, threads=ctx.threads)
    try:
        backend.load(ctx.scenes.full)
        res = backend.render(ctx.scenes.camera, QUALITY, SEED)
        _require(res.noisy is not None and res.noisy.shape == (HEIGHT, WIDTH, 3), ctx.name,
                 "a denoising render must also return the render before its denoiser (RenderResult.noisy)")
        if res.guides is not None:
            _check_guides(ctx, backend, res)
        if callable(getattr(backend, "denoise", None)) and render_takes(backend, "skip_denoiser"):
            _check_skipped_denoiser(ctx, backend, res)
    finally:
        backend.close()


def _check_skipped_denoiser(ctx: ConformanceContext, backend, denoised: RenderResult) -> None:
    """``render(..., skip_denoiser=True)`` (asked of a backend that offers ``denoise``, whose renders
    the core denoises itself): the same render before the denoiser, as ``linear`` and ``noisy``,
    with the same guides."""
    res = backend.render(ctx.scenes.camera, QUALITY, SEED, skip_denoiser=True)
    _require(res.guides is not None and res.noisy is not None and res.linear is not None, ctx.name,
             "render(..., skip_denoiser=True) must return the render before the denoiser (linear and noisy) and its guides")
    for name, got, want in (("linear", res.linear, denoised.noisy), ("noisy", res.noisy, denoised.noisy),
                            ("guides", res.guides, denoised.guides)):
        off = float(np.max(np.abs(np.asarray(got, np.float64) - want) / (1.0 + np.abs(want))))
        _require(off <= 1e-4, ctx.name, f"render(..., skip_denoiser=True): its {name} is not the denoising render's "
                 f"(off by up to {off:.3g} relative)")


def check_sample_continuation(ctx: ConformanceContext) -> None:
    """``render(..., sample_offset=k)`` (Capabilities.continues_samples): the samples 2 to 4 of a
    seed's sequence are not its first 2 again, and the two ranges averaged are the render of its
    first 4 (within float rounding: an error target takes the halves of an image as such)."""
    _require_declared(ctx, "continues_samples")
    ctx.render()  # the scene loaded

    def raw(samples: int, offset: int) -> np.ndarray:
        q = QUALITY.model_copy(update={"aa": samples, "diffuse_rays": samples, "specular_rays": samples})
        res = ctx.backend.render(ctx.scenes.camera, q, SEED, **({"sample_offset": offset} if offset else {}))
        got = res.noisy if res.noisy is not None else res.linear
        _require(got is not None, ctx.name, "a backend that continues samples must return the linear render")
        return np.asarray(got, np.float64)

    first, more, both = raw(2, 0), raw(2, 2), raw(4, 0)
    _require(not np.array_equal(first, more), ctx.name, "the render from sample_offset=2 is the first samples' again: "
             "is the offset used?")
    off = float(np.max(np.abs((first + more) / 2 - both) / (1.0 + np.abs(both))))
    _require(off <= 1e-4, ctx.name, f"samples 0-2 and 2-4 averaged are not the render of samples 0-4 (off by up to "
             f"{off:.3g} relative)")


def check_determinism(ctx: ConformanceContext) -> None:
    """Same inputs and seed give identical pixels, whatever was rendered in between."""
    a = _rgb(ctx, ctx.render(seed=SEED))
    ctx.render(seed=SEED + 1)
    ctx.render(camera=ctx.scenes.camera_moved, seed=SEED)
    b = _rgb(ctx, ctx.render(seed=SEED))
    n = int((a != b).any(axis=-1).sum())
    _require(n == 0, ctx.name, f"same scene, camera and seed gave {n} different pixel(s) in one process")


def check_fresh_process_determinism(ctx: ConformanceContext) -> None:
    """The same render in a new Python process gives identical pixels."""
    a = _rgb(ctx, ctx.render(seed=SEED))
    job = ctx.tmp_path / "conformance_job.pkl"
    out = ctx.tmp_path / "conformance_out.npy"
    with open(job, "wb") as f:
        pickle.dump((ctx.name, ctx.options, ctx.threads, ctx.scenes.full, ctx.scenes.camera, SEED), f)
    proc = subprocess.run(
        [sys.executable, "-m", "specsynth.testing.conformance", str(job), str(out)],
        capture_output=True, text=True, timeout=600,
    )
    _require(proc.returncode == 0, ctx.name, f"render in a fresh process failed:\n{proc.stderr[-4000:]}")
    b = np.load(out)
    _require(b.shape == a.shape, ctx.name, f"fresh-process render has shape {b.shape}, expected {a.shape}")
    n = int((a != b).any(axis=-1).sum())
    _require(n == 0, ctx.name, f"a fresh process gave {n} different pixel(s) for the same render")


def check_seed_matters(ctx: ConformanceContext) -> None:
    """Optional (not in CHECKS): the seed changes the image. The protocol does not demand it, but
    for a sampling backend or one with random backgrounds an ignored seed is a bug."""
    a = _rgb(ctx, ctx.render(seed=SEED))
    b = _rgb(ctx, ctx.render(seed=SEED + 17))
    _require(not np.array_equal(a, b), ctx.name, "different seeds gave identical images (is the seed used?)")


def check_camera_moves(ctx: ConformanceContext) -> None:
    a = _rgb(ctx, ctx.render(seed=SEED)).astype(np.int16)
    b = _rgb(ctx, ctx.render(camera=ctx.scenes.camera_moved, seed=SEED)).astype(np.int16)
    diff = float(np.abs(a - b).mean())
    _require(diff > 2.0, ctx.name, f"moving the camera barely changed the image (mean |diff| {diff:.2f})")


def check_silhouettes(ctx: ConformanceContext) -> None:
    """Each object shows up at the pixel where K and the camera pose project its centre."""
    s = ctx.scenes
    cam = s.camera
    full = _rgb(ctx, ctx.render(s.full, seed=SEED))
    for label, centre, without in (("box", BOX_CENTRE, s.no_box), ("sphere", SPHERE_CENTRE, s.no_sphere)):
        u, v, z = project(cam, centre)
        _require(1 <= u <= WIDTH - 2 and 1 <= v <= HEIGHT - 2 and z > 0, ctx.name, f"test setup: {label} off screen")
        other = _rgb(ctx, ctx.render(without, seed=SEED))
        d = float(np.abs(_window(full, u, v) - _window(other, u, v)).mean())
        _require(
            d >= SILHOUETTE_MIN_DIFF, ctx.name,
            f"the {label} does not appear where the camera projects its centre (pixel {u:.1f}, {v:.1f}): "
            f"mean |diff| with and without it is {d:.1f} < {SILHOUETTE_MIN_DIFF} (check K, the pose convention "
            "and the image's row order)",
        )
    if not ctx.plugin.capabilities.draws_scene:
        # Objects-only backends: away from the objects, the image is exactly the object-free one.
        empty = _rgb(ctx, ctx.render(s.no_objects, seed=SEED))
        margin = 6
        far = np.ones((HEIGHT, WIDTH), bool)
        for centre, radius in ((BOX_CENTRE, BOX_SIZE * math.sqrt(3) / 2), (SPHERE_CENTRE, SPHERE_RADIUS)):
            u, v, z = project(cam, centre)
            r_px = cam.K_array[0, 0] * radius / (z - radius) + margin
            yy, xx = np.mgrid[:HEIGHT, :WIDTH]
            far &= (xx - u) ** 2 + (yy - v) ** 2 > r_px**2
        same = float((full[far] == empty[far]).all(axis=-1).mean())
        _require(
            same >= 0.99, ctx.name,
            f"an objects-only backend changed pixels far from the objects ({100 * (1 - same):.1f}% of them)",
        )


WINDOW = (17, 9, 44, 36)  # (x0, y0, w, h) off the image's centre, holding both objects


def check_window(ctx: ConformanceContext) -> None:
    """A camera cropped to a window of the image (``CameraIR.cropped``: its principal point moved
    by the window's corner) renders that window of the whole image's render, to the pixel: on the
    whole image's edges, the window lines up at no shift better than at the one it claims.
    ``specsynth bench --ref-crop`` renders its references so."""
    x0, y0, w, h = WINDOW
    quality = PAPER_PRESETS["medium"]  # the samples to see edges through a path tracer's noise
    ctx.load(ctx.scenes.full)
    full = _rgb(ctx, ctx.backend.render(ctx.scenes.camera, quality, SEED)).astype(np.float64)
    part = ctx.backend.render(ctx.scenes.camera.cropped(x0, y0, w, h), quality, SEED).rgb
    _require(part.shape == (h, w, 3), ctx.name, f"a {w}x{h} camera rendered an image of shape {part.shape}")
    grey = full.mean(axis=-1)
    gradient = np.hypot(*np.gradient(grey))[y0:y0 + h, x0:x0 + w]
    if not ctx.plugin.capabilities.draws_scene:  # its backdrop is drawn for each image size: the objects only
        from scipy.ndimage import binary_erosion

        ctx.load(ctx.scenes.no_objects)
        empty = ctx.backend.render(ctx.scenes.camera, quality, SEED).rgb
        ctx.load(ctx.scenes.full)
        objects = binary_erosion((full != empty).any(axis=-1), iterations=1)[y0:y0 + h, x0:x0 + w]
        _require(objects.sum() >= 20, ctx.name, "test setup: too few object pixels in the window")
        gradient = np.where(objects, gradient, -1.0)
    edges = gradient >= np.quantile(gradient[gradient >= 0], 0.9)

    def off(dx: int, dy: int) -> float:
        there = full[y0 + dy:y0 + dy + h, x0 + dx:x0 + dx + w]
        return float(np.abs(part.astype(np.float64) - there)[edges].mean())

    shifts = {(dx, dy): off(dx, dy) for dx in (-1, 0, 1) for dy in (-1, 0, 1)}
    best = min(shifts, key=shifts.get)
    _require(best == (0, 0) and shifts[0, 0] < 0.5 * min(v for k, v in shifts.items() if k != (0, 0)), ctx.name,
             f"the window rendered by a cropped camera lines up with the whole image shifted by {best} pixels "
             f"(mean |diff| on edges {shifts[best]:.1f}, unshifted {shifts[0, 0]:.1f}): check how the principal "
             "point is placed")


def check_reload(ctx: ConformanceContext) -> None:
    """load() replaces the previous scene completely: nothing of it leaks into the next."""
    s = ctx.scenes
    ctx.close()  # a fresh instance, so the first render of no_box cannot inherit anything
    first = _rgb(ctx, ctx.render(s.no_box, seed=SEED))
    full = _rgb(ctx, ctx.render(s.full, seed=SEED))
    again = _rgb(ctx, ctx.render(s.no_box, seed=SEED))
    _require(not np.array_equal(first, full), ctx.name, "scenes with and without the box rendered identically")
    n = int((first != again).any(axis=-1).sum())
    _require(n == 0, ctx.name, f"after load(other scene), reloading a scene changed {n} pixel(s) (a leak?)")


def _sharpness(img: np.ndarray, u: float, v: float, r: int) -> float:
    """Mean absolute luminance gradient in a window: texture edges give it, blur takes it away."""
    w = _window(img, u, v, r).mean(axis=-1)
    return float(np.abs(np.diff(w, axis=0)).mean() + np.abs(np.diff(w, axis=1)).mean())


def check_depth_of_field(ctx: ConformanceContext) -> None:
    """A backend declaring depth_of_field renders a thin lens: focused on the checker-textured box,
    the box stays about as sharp as through a pinhole; focused 4x farther, it blurs."""
    _require_declared(ctx, "depth_of_field")

    s = ctx.scenes
    u, v, z = project(s.camera, BOX_CENTRE)
    aperture = 0.05  # metres: a 4x focus error spreads the box's points over ~6 px here
    quality = PAPER_PRESETS["medium"]  # enough samples that noise does not pass for texture
    ctx.load(s.full)
    images = {}
    for label, cam in (("pinhole", s.camera), ("focused", replace(s.camera, aperture=aperture, focus_distance=z)),
                       ("defocused", replace(s.camera, aperture=aperture, focus_distance=4 * z))):
        images[label] = _sharpness(_rgb(ctx, ctx.backend.render(cam, quality, SEED)), u, v, 5)
    _require(images["focused"] >= 0.7 * images["pinhole"], ctx.name,
             f"the box in focus lost its texture (gradient {images['focused']:.1f} vs {images['pinhole']:.1f} "
             "through a pinhole): is focus_distance measured along the optical axis, in metres?")
    _require(images["defocused"] <= 0.5 * images["pinhole"], ctx.name,
             f"the box out of focus stayed sharp (gradient {images['defocused']:.1f} vs {images['pinhole']:.1f}): "
             "is CameraIR.aperture (diameter, metres) used?")


def _centroid_u(img: np.ndarray, without: np.ndarray) -> float:
    """Column centroid of what an object adds to the image (weighted by the difference)."""
    w = np.abs(img.astype(np.float64) - without.astype(np.float64)).sum(axis=-1)
    return float((w.sum(axis=0) * np.arange(w.shape[1])).sum() / max(w.sum(), 1e-9))


def check_motion_blur(ctx: ConformanceContext) -> None:
    """A backend declaring motion_blur moves the camera over the exposure (CameraIR.motion): a
    sideways travel and a turn each smear the textured box, and the smear is centred on the
    mid-exposure pose (the record's pose, which the labels use)."""
    _require_declared(ctx, "motion_blur")

    s = ctx.scenes
    u, v, _ = project(s.camera, BOX_CENTRE)
    quality = PAPER_PRESETS["medium"]
    images = {}
    motions = {"still": (), "travel": (0.04, 0.0, 0.0, 0.0, 0.0, 0.0), "turn": (0.0, 0.0, 0.0, 0.0, 0.07, 0.0)}
    for scene, suffix in ((s.full, ""), (s.no_box, " without box")):
        ctx.load(scene)
        for label, motion in motions.items():
            images[label + suffix] = _rgb(ctx, ctx.backend.render(replace(s.camera, motion=motion), quality, SEED))
    sharp = _sharpness(images["still"], u, v, 5)
    still_u = _centroid_u(images["still"], images["still without box"])
    for label in ("travel", "turn"):
        got = _sharpness(images[label], u, v, 5)
        _require(got <= 0.6 * sharp, ctx.name, f"a camera {label} over the exposure left the box sharp (gradient "
                 f"{got:.1f} vs {sharp:.1f} still): is CameraIR.motion used?")
        shift = _centroid_u(images[label], images[label + " without box"]) - still_u
        # The smear is ~6.5 px long: a motion run from the pose instead of around it shifts it by ~3.3 px
        # (measured: Cycles and Mitsuba both within 1.3 px of the still box, shading included).
        _require(abs(shift) <= 2.0, ctx.name, f"the {label}'s smear is off the mid-exposure pose by {shift:+.1f} px "
                 "(the pose is the middle of the exposure: the motion runs from -1/2 to +1/2 of it)")


# Checks of an optional capability: they apply to the backends that declare it.
NEEDS_CAPABILITY = {"depth_of_field": "depth_of_field", "motion_blur": "motion_blur", "denoiser_guides": "denoise",
                    "sample_continuation": "continues_samples"}


class NotDeclared(Exception):
    """A check of a capability the backend does not declare: it does not apply (neither passed nor failed)."""


def not_applicable(ctx: ConformanceContext, check_name: str) -> str | None:
    """Why the check ``check_name`` does not apply to this backend, or None when it does."""
    cap = NEEDS_CAPABILITY.get(check_name)
    if cap is not None and not getattr(ctx.plugin.capabilities, cap):
        return f"{ctx.name} does not declare the capability {cap!r}"
    return None


def _require_declared(ctx: ConformanceContext, cap: str) -> None:
    if not getattr(ctx.plugin.capabilities, cap):
        raise NotDeclared(f"{ctx.name} does not declare the capability {cap!r}")


CHECKS: dict[str, Callable[[ConformanceContext], None]] = {
    "discovery": check_discovery,
    "version": check_version,
    "render_shape": check_render_shape,
    "determinism": check_determinism,
    "fresh_process_determinism": check_fresh_process_determinism,
    "camera_moves": check_camera_moves,
    "silhouettes": check_silhouettes,
    "reload": check_reload,
    "window": check_window,
    "depth_of_field": check_depth_of_field,
    "motion_blur": check_motion_blur,
    "denoiser_guides": check_denoiser_guides,
    "sample_continuation": check_sample_continuation,
}


def check_backend(name: str, options: Any = None, tmp_path: str | Path = ".", *, skip: tuple[str, ...] = (), threads: int = 1) -> None:
    """Run every check that applies to the backend ``name`` (those of undeclared capabilities do
    not); raises ConformanceError on the first failure."""
    unknown = set(skip) - set(CHECKS)
    if unknown:
        raise ValueError(f"unknown conformance checks: {sorted(unknown)}")
    ctx = ConformanceContext(name, options, tmp_path, threads=threads)
    try:
        for check_name, check in CHECKS.items():
            if check_name not in skip and not_applicable(ctx, check_name) is None:
                check(ctx)
    finally:
        ctx.close()


def _render_job(job: Path, out: Path) -> None:
    """Entry of the fresh-process determinism check: render one pickled job, save the pixels."""
    with open(job, "rb") as f:
        name, options, threads, scene, camera, seed = pickle.load(f)
    backend = load_backend(name)(options, threads=threads)
    try:
        backend.load(scene)
        np.save(out, backend.render(camera, QUALITY, seed).rgb)
    finally:
        backend.close()


if __name__ == "__main__":
    _render_job(Path(sys.argv[1]), Path(sys.argv[2]))
