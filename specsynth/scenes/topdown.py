"""`specsynth scenes show`: a top-down picture of a scene (height-shaded) with its stages drawn on it."""

from __future__ import annotations

import math

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from ..assets.meshio import read_mesh
from .autostage import sample_triangles
from .types import SceneDesc

_COLOURS = [(230, 60, 60), (60, 170, 240), (250, 190, 40), (90, 200, 90), (200, 90, 220), (250, 130, 40)]


def world_triangles(desc: SceneDesc) -> np.ndarray:
    tris = []
    for m in desc.meshes:
        data = read_mesh(m.mesh_path)
        T = m.matrix
        tris.append((data.vertices.astype(np.float64) @ T[:3, :3].T + T[:3, 3])[data.faces])
    return np.concatenate(tris) if tris else np.zeros((0, 3, 3))


def top_down(desc: SceneDesc, max_px: int = 800, ceiling: float | None = None) -> Image.Image:
    """Orthographic view from above; geometry above ``ceiling`` (default: 0.3 m under the top of
    the scene, so a closed room shows its inside) is left out."""
    tris = world_triangles(desc)
    lo, hi = tris.reshape(-1, 3).min(0), tris.reshape(-1, 3).max(0)
    size = max(hi[0] - lo[0], hi[1] - lo[1], 1e-3)
    px = max_px / size  # pixels per metre
    w, h = int(math.ceil((hi[0] - lo[0]) * px)) + 1, int(math.ceil((hi[1] - lo[1]) * px)) + 1
    pts, normals = sample_triangles(tris, 0.5 / px)
    top = hi[2] - 0.3 if ceiling is None else ceiling
    keep = pts[:, 2] <= top
    pts, normals = pts[keep], normals[keep]
    col = np.clip(((pts[:, 0] - lo[0]) * px).astype(int), 0, w - 1)
    row = np.clip(((hi[1] - pts[:, 1]) * px).astype(int), 0, h - 1)  # north up
    order = np.argsort(pts[:, 2])  # later (higher) samples overwrite lower ones
    zbuf = np.full((h, w), np.nan)
    shade = np.zeros((h, w))
    zbuf[row[order], col[order]] = pts[order, 2]
    shade[row[order], col[order]] = np.abs(normals[order, 2])
    zr = (zbuf - np.nanmin(zbuf)) / max(np.nanmax(zbuf) - np.nanmin(zbuf), 1e-6)
    grey = np.where(np.isnan(zbuf), 20, 60 + 150 * np.nan_to_num(zr) * (0.5 + 0.5 * shade))
    img = Image.fromarray(np.repeat(grey[..., None], 3, axis=2).astype(np.uint8))
    draw = ImageDraw.Draw(img)
    font = ImageFont.load_default()
    for i, (name, st) in enumerate(sorted(desc.stages.items())):
        c = _COLOURS[i % len(_COLOURS)]
        poly = [((x - lo[0]) * px, (hi[1] - y) * px) for x, y in st.polygon]
        draw.polygon(poly, outline=c, width=2)
        cx, cy = np.mean(poly, axis=0)
        draw.text((cx - 3 * len(name), cy - 5), name, fill=c, font=font)
    return img
