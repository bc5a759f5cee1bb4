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


def overview_camera(scene, intr: Intrinsics, azimuth: float = 35.0, elevation: float = 35.0):
    """A camera that frames every stage: looks at their centre from outside their bounding sphere."""
    pts = np.array([(x, y, s.height) for s in scene.stages.values() for x, y in s.polygon], dtype=np.float64)
    if len(pts) == 0:
        pts = np.concatenate([(m.matrix[:3, :3] @ read_mesh(m.mesh_path).bounds.T).T + m.matrix[:3, 3] for m in scene.meshes])
    centre = 0.5 * (pts.min(0) + pts.max(0))
    radius = float(np.linalg.norm(pts - centre, axis=1).max()) + 0.3
    fov = 2 * np.arctan(min(intr.width / intr.fx, intr.height / intr.fy) / 2)
    dist = radius / np.sin(fov / 2)
    eye = centre + cameras.spherical_offset(azimuth, elevation, dist)
    R, t = cameras.look_at(eye, centre)
    return cameras.camera_ir(intr, R, t)


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
    intr = Intrinsics(width=width, height=height, fx=0.8 * width, fy=0.8 * width, cx=width / 2 - 0.5, cy=height / 2 - 0.5)
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
