"""BOP model folders: which models a folder holds and their ``models_info.json``.

A BOP models folder holds ``obj_XXXXXX.ply`` (millimetres) and ``models_info.json``. Folders
without the latter (the real LM-O set installed from a wheel, a folder a user assembled) get it
computed as the BOP toolkit's ``scripts/calc_model_info.py`` does: ``min_x/y/z`` and
``size_x/y/z`` from the vertices' bounding box, ``diameter`` the largest distance between two
vertices (``misc.calc_pts_diameter``), all in the file's units. The result is cached by the
models' content, so a folder is read once.
"""

from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path

import numpy as np

from ..atomic import atomic_write_bytes

MODEL_NAME = re.compile(r"^obj_(\d{6})\.ply$")
INFO_VERSION = 1  # bump when the computation below changes


def pts_diameter(points: np.ndarray) -> float:
    """The largest distance between two points, exactly (the BOP toolkit's ``calc_pts_diameter``).

    The farthest pair of a point set are vertices of its convex hull, so only those are compared
    (all pairs, in blocks); a flat or degenerate set compares all its points."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    if len(pts) < 2:
        return 0.0
    if len(pts) > 64:
        try:
            from scipy.spatial import ConvexHull

            pts = pts[ConvexHull(pts).vertices]
        except Exception:  # qhull refuses flat sets; every point then stays a candidate
            pass
    best = 0.0
    for i in range(0, len(pts), 1024):
        d2 = ((pts[i:i + 1024, None, :] - pts[None, :, :]) ** 2).sum(-1)
        best = max(best, float(d2.max()))
    return float(np.sqrt(best))


def model_info(points: np.ndarray) -> dict[str, float]:
    """One ``models_info.json`` entry of a model's vertices, in their units."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    lo, hi = pts.min(0), pts.max(0)
    size = hi - lo
    return {"diameter": pts_diameter(pts), "min_x": float(lo[0]), "min_y": float(lo[1]), "min_z": float(lo[2]),
            "size_x": float(size[0]), "size_y": float(size[1]), "size_z": float(size[2])}


def model_ids(folder: Path) -> list[int]:
    """obj ids of the ``obj_XXXXXX.ply`` files in a folder (regular files only)."""
    return sorted(int(m.group(1)) for p in Path(folder).iterdir()
                  if (m := MODEL_NAME.match(p.name)) and p.is_file() and not p.is_symlink())


def bad_model_ids(ids) -> list[int]:
    """BOP's object ids start at 1 (the toolkit's and every dataset's; 0 marks no object in masks)."""
    return [i for i in ids if i < 1]


def _folder_digest(folder: Path, ids: list[int]) -> str:
    h = hashlib.sha256(f"v{INFO_VERSION}".encode())
    for i in ids:
        h.update(f"|{i}|".encode())
        with open(Path(folder) / f"obj_{i:06d}.ply", "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()


def computed_models_info(folder: Path, cache: Path, read_points) -> tuple[dict[int, dict[str, float]], Path]:
    """``models_info`` of a folder that has none, computed once and cached by the models' bytes ->
    (info by obj_id, the cached file). ``read_points(path)`` returns a model's vertices in its units."""
    ids = model_ids(folder)
    path = Path(cache) / "models_info" / f"{_folder_digest(folder, ids)}.json"
    if path.is_file():
        try:
            return {int(k): v for k, v in json.loads(path.read_text()).items()}, path
        except (ValueError, OSError, RecursionError, AttributeError):
            pass  # a torn cache file is recomputed
    info = {i: model_info(read_points(Path(folder) / f"obj_{i:06d}.ply")) for i in ids}
    atomic_write_bytes(path, json.dumps({str(k): v for k, v in info.items()}, indent=1, sort_keys=True).encode())
    return info, path
