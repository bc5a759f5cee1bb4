"""Where a synthetic build's pixels are, and how dense their edges: each view's pixels lifted to the
world with its BOP depth and camera, and split by height into the floor (below 5 cm), the work
surface (within 15 cm of the height the objects stand at, less 5 cm), above it and between; for each
region its share of the image and the edge density there (``specsynth compare``'s edge measure, on
half-size luma). Real test sets have no depth, so this describes the synthetic side only.

    python benchmarks/realism_regions.py out/demo [out/other ...]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from PIL import Image

from specsynth.compare import imagestats as S

REGIONS = ("floor", "between", "worktop", "above")


def world_heights(depth_png: Path, cam: dict) -> tuple[np.ndarray, np.ndarray]:
    """(height above the floor in metres per pixel, pixels with depth) of one BOP view."""
    K = np.array(cam["cam_K"]).reshape(3, 3)
    R, t = np.array(cam["cam_R_w2c"]).reshape(3, 3), np.array(cam["cam_t_w2c"])
    z = np.asarray(Image.open(depth_png)).astype(np.float64) * cam["depth_scale"]
    v, u = np.mgrid[0 : z.shape[0], 0 : z.shape[1]]
    X = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], -1).reshape(-1, 3)
    return (((X - t) @ R)[:, 2] / 1000.0).reshape(z.shape), z > 0


def view_regions(scene: Path, key: str, cam: dict, gt: list[dict]) -> list[float]:
    """[share of each region, then edge density in each region (nan where empty)] of one view."""
    height, valid = world_heights(scene / "depth" / f"{int(key):06d}.png", cam)
    R, t = np.array(cam["cam_R_w2c"]).reshape(3, 3), np.array(cam["cam_t_w2c"])
    stage = np.median([((np.array(o["cam_t_m2c"]) - t) @ R)[2] for o in gt]) / 1000.0 - 0.05
    edges = S.gradient_magnitude(S.half(S.luma(np.asarray(Image.open(scene / "rgb" / f"{int(key):06d}.png").convert("RGB"))))) > S.EDGE_GRADIENT
    h, ok = height[::2, ::2][: edges.shape[0], : edges.shape[1]], valid[::2, ::2][: edges.shape[0], : edges.shape[1]]
    floor, worktop, above = ok & (h < 0.05), ok & (np.abs(h - stage) < 0.15), ok & (h > stage + 0.15)
    masks = (floor, ok & ~floor & ~worktop & ~above, worktop, above)
    return [m.mean() for m in masks] + [edges[m].mean() if m.any() else np.nan for m in masks]


def regions(build: Path) -> dict:
    rows = []
    for scene in sorted((build / "bop").glob("*/[0-9]*")):
        cams = json.loads((scene / "scene_camera.json").read_text())
        gt = json.loads((scene / "scene_gt.json").read_text())
        rows += [view_regions(scene, k, c, gt[k]) for k, c in cams.items() if gt.get(k)]
    r = np.array(rows)
    return {"views": len(rows), **{name: {"share": round(float(np.nanmean(r[:, i])), 3),
                                          "edge_density": round(float(np.nanmean(r[:, 4 + i])), 3)}
                                   for i, name in enumerate(REGIONS)}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("builds", nargs="+", type=Path)
    for build in ap.parse_args().builds:
        print(build, json.dumps(regions(build)))


if __name__ == "__main__":
    main()
