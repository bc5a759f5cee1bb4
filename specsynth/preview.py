"""`specsynth scenes preview`: an overview render of a scene with its stage polygons drawn on it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from . import cameras
from .backend_api import load_backend
from .meshio import read_mesh
from .scenes import load_scene
from .spec import Intrinsics, QualityPreset


def _world_bounds(scene) -> np.ndarray:
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for m in scene.meshes:
        b = read_mesh(m.mesh_path).bounds
        corners = np.array([[x, y, z] for x in b[:, 0] for y in b[:, 1] for z in b[:, 2]])
        w = corners @ m.matrix[:3, :3].T + m.matrix[:3, 3]
        lo, hi = np.minimum(lo, w.min(0)), np.maximum(hi, w.max(0))
    return np.stack([lo, hi])


def overview_camera(scene, intr: Intrinsics):
    """A camera inside the scene's bounds (rooms are closed boxes), high in the corner from which
    most stage corners fall inside the image, looking at the stages' centre."""
    pts = np.array([(x, y, s.height) for s in scene.stages.values() for x, y in s.polygon], dtype=np.float64)
    lo, hi = _world_bounds(scene)
    centre = pts.mean(0) if len(pts) else 0.5 * (lo + hi)
    best = None
    for cx in (lo[0], hi[0]):
        for cy in (lo[1], hi[1]):
            eye = centre + 0.85 * (np.array([cx, cy, 0.0]) - np.array([centre[0], centre[1], 0.0]))
            eye[2] = lo[2] + 0.8 * (hi[2] - lo[2])
            R, t = cameras.look_at(eye, centre)
            cam = cameras.camera_ir(intr, R, t)
            pc = pts @ R.T + t
            uv = cameras.project(cam.K_array, R, t, pts)
            seen = int(((pc[:, 2] > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < intr.width) & (uv[:, 1] >= 0) & (uv[:, 1] < intr.height)).sum())
            if best is None or seen > best[0]:
                best = (seen, cam)
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


def preview_scene(name: str, backend: str, dest: Path, *, width: int = 640, height: int = 480, samples: int = 16) -> Path:
    scene = load_scene(name, Path.cwd())
    intr = Intrinsics(width=width, height=height, fx=0.45 * width, fy=0.45 * width, cx=width / 2 - 0.5, cy=height / 2 - 0.5)
    cam = overview_camera(scene, intr)
    cls = load_backend(backend)
    if not cls.draws_scene:
        raise ValueError(f"backend {backend!r} draws only dataset objects; preview a scene with a PBR backend (cycles, mitsuba)")
    r = cls({"name": backend}, threads=0)
    rs = scene.with_objects(())
    r.load(rs)
    res = r.render(cam, QualityPreset(aa=samples, diffuse_rays=samples, specular_rays=samples, diffuse_depth=3,
                                      specular_depth=3, max_depth=4), seed=0)
    r.close()
    dest = Path(dest)
    dest.parent.mkdir(parents=True, exist_ok=True)
    draw_stages(res.rgb, scene, cam).save(dest)
    return dest
