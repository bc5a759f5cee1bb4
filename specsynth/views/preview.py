"""`specsynth scenes preview`: an overview render of a scene with its stage polygons drawn on it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from ..assets.meshio import read_mesh
from ..atomic import atomic_write_via
from ..plugins import PluginNotFound, backend_plugin, installed_backend_plugins
from ..scenes import load_scene
from ..spec.models import Intrinsics, QualityPreset
from . import cameras


def _world_bounds(scene) -> np.ndarray:
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for m in scene.meshes:
        b = read_mesh(m.mesh_path).bounds
        corners = np.array([[x, y, z] for x in b[:, 0] for y in b[:, 1] for z in b[:, 2]])
        w = corners @ m.matrix[:3, :3].T + m.matrix[:3, 3]
        lo, hi = np.minimum(lo, w.min(0)), np.maximum(hi, w.max(0))
    return np.stack([lo, hi])


def overview_camera(scene, intr: Intrinsics):
    """A camera that shows every stage as large as possible from inside the scene's bounds (rooms
    are closed boxes): candidates around the stages' centre at 8 azimuths and 2 elevations, each
    pulled in until it is inside the bounds; the best shows all stage corners and most stage area."""
    stages = list(scene.stages.values())
    pts = np.array([(x, y, s.height) for s in stages for x, y in s.polygon], dtype=np.float64)
    lo, hi = _world_bounds(scene)
    lo, hi = lo + 0.15, hi - 0.15
    centre = pts.mean(0) if len(pts) else 0.5 * (lo + hi)
    radius = float(np.linalg.norm(pts - centre, axis=1).max()) + 0.2 if len(pts) else 1.0
    fov = 2 * np.arctan(min(intr.width / intr.fx, intr.height / intr.fy) / 2)
    best = None
    for elevation in (30.0, 50.0):
        for azimuth in range(0, 360, 45):
            d = cameras.spherical_offset(azimuth, elevation, radius / np.sin(fov / 2))
            # the largest fraction of the offset that keeps the eye inside the bounds
            with np.errstate(divide="ignore", invalid="ignore"):
                limits = np.where(d > 0, (hi - centre) / d, np.where(d < 0, (lo - centre) / d, np.inf))
            eye = centre + d * float(np.clip(limits.min(), 0.05, 1.0))
            R, t = cameras.look_at(eye, centre)
            K = cameras.intrinsics_matrix(intr)
            # Union of the stages' image areas (overlapping stages count once), rasterised.
            union = Image.new("1", (intr.width, intr.height))
            seen = 0
            for s in stages:
                poly = np.array([(x, y, s.height) for x, y in s.polygon])
                pc = poly @ R.T + t
                uv = cameras.project(K, R, t, poly)
                ok = (pc[:, 2] > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < intr.width) & (uv[:, 1] >= 0) & (uv[:, 1] < intr.height)
                seen += int(ok.sum())
                if ok.all():
                    ImageDraw.Draw(union).polygon([tuple(p) for p in uv], fill=1)
            score = (seen, int(np.asarray(union).sum()))
            if best is None or score > best[0]:
                best = (score, cameras.camera_ir(intr, R, t))
    return best[1]


def draw_stages(rgb: np.ndarray, scene, cam) -> Image.Image:
    im = Image.fromarray(rgb)
    draw = ImageDraw.Draw(im)
    K, R, t = cam.K_array, np.asarray(cam.R_w2c), np.asarray(cam.t_w2c)
    for i, (name, st) in enumerate(sorted(scene.stages.items())):
        poly = np.array([(x, y, st.height) for x, y in st.polygon])
        pc = (R @ poly.T).T + t
        if (pc[:, 2] <= 0).any():
            continue
        uv = cameras.project(K, R, t, poly)
        colour = (255, 64 + (i * 53) % 192, (i * 97) % 255)
        draw.line([tuple(p) for p in uv] + [tuple(uv[0])], fill=colour, width=2)
        c = uv.mean(0)
        draw.text((c[0] - 3 * len(name), c[1] - 5), name, fill=colour)
    return im


def scene_backends() -> list[str]:
    """Installed backends that draw scenes, the first the default for previews."""
    return [p.name for p in installed_backend_plugins() if p.capabilities.draws_scene]


def preview_scene(name: str, backend: str | None, dest: Path, *, width: int = 640, height: int = 480, samples: int = 16,
                  variant: int | None = None, stages: bool = True, denoise: bool = False) -> Path:
    """An overview render of a scene (``variant``: random_room's seed), with its stages drawn."""
    scene = load_scene(name, Path.cwd(), variant=variant)
    intr = Intrinsics(width=width, height=height, fx=0.45 * width, fy=0.45 * width, cx=width / 2 - 0.5, cy=height / 2 - 0.5)
    cam = overview_camera(scene, intr)
    drawers = scene_backends()
    backend = backend or (drawers[0] if drawers else None)
    if backend is None:
        raise PluginNotFound("no installed backend draws scenes")
    plugin = backend_plugin(backend)
    if not plugin.capabilities.draws_scene:
        raise ValueError(f"backend {backend!r} draws only dataset objects; preview a scene with one that draws "
                         f"scenes ({', '.join(drawers) or 'none installed'})")
    r = plugin.load_class()(plugin.options(denoise=denoise), threads=0)
    rs = scene.with_objects(())
    r.load(rs)
    res = r.render(cam, QualityPreset(aa=samples, diffuse_rays=samples, specular_rays=samples, diffuse_depth=3,
                                      specular_depth=3, max_depth=4), seed=0)
    r.close()
    dest = Path(dest)
    dest.parent.mkdir(parents=True, exist_ok=True)
    image = draw_stages(res.rgb, scene, cam) if stages else Image.fromarray(res.rgb)
    atomic_write_via(dest, image.save, suffix=dest.suffix)  # a link there is replaced, not followed
    return dest
