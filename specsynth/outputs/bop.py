"""BOP writer: ``<out>/bop/`` in the layout the BOP toolkit (``bop_toolkit_lib.inout``) reads as is.

Units change here and only here: records are metres, BOP files are millimetres.

Merge semantics, so that an interrupted or repeated merge is harmless:
- every file lands by atomic rename of a temp file next to it;
- images are independent copies of the store's files (a reflink where the filesystem has them),
  never hard links: editing an output must not edit the cache. A copy keeps its source's mtime,
  so a rebuild finds an output that was edited or deleted (size or mtime differ) and restores it;
- a file whose bytes are already right is left untouched (same inode, same mtime);
- image files and chunk folders of images no longer in the build are removed, but only names this
  writer would produce, so anything a user put next to them survives.

Every file kind of a record lands in its own chunk subfolder (``<kind>/<im_id>.<ext>``, or
``<kind>/<im_id>_<gt_id>.<ext>`` for one file per instance): a product registered by another
package gets its folder with no change here.
"""

from __future__ import annotations

import json
import re
from collections import defaultdict
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np

from ..assets.meshio import MeshData, mesh_bytes, read_mesh
from ..assets.resolve import ObjectAsset
from ..model.records import ImageRecord
from ..output_api import DatasetWriter, Merge
from ..spec.models import Intrinsics, Outputs
from .dataset import (
    ImageEntry,
    check_image,
    chunk_and_im_id,
    place_file,
    plain,
    rotation_list,
    sorted_images,
    vec_mm,
    write_if_changed,
)

# What this writer may delete in a chunk's file-kind folders: names it would produce.
_FILE_NAME = re.compile(r"^\d{6}(_\d{6})?\.[A-Za-z0-9]+$")
CHUNK_JSONS = ("scene_camera.json", "scene_gt.json", "scene_gt_info.json")
_CHUNK_NAME = re.compile(r"^\d{6}$")
_MODEL_NAME = re.compile(r"^obj_\d{6}\.\w+$")
_TMP_NAME = re.compile(r"^\..+\.tmp$")
_NOTHING = re.compile(r"(?!)")  # for folders where only temp files are ours to delete


# --------------------------------------------------------------------------- JSON


def bop_json_bytes(content: dict | list) -> bytes:
    """The layout of ``bop_toolkit_lib.inout.save_json``: one top-level entry per line, keys in
    numeric order, inner keys sorted. Floats use repr, so they round-trip exactly."""
    content = plain(content)

    def dumps(v: Any) -> str:
        return json.dumps(v, sort_keys=True, allow_nan=False)

    if isinstance(content, dict):
        items = sorted(content.items(), key=lambda kv: kv[0])
        lines = [f"  {json.dumps(str(k))}: {dumps(v)}" for k, v in items]
        text = "{\n" + ",\n".join(lines) + ("\n}" if lines else "}")
    elif isinstance(content, list):
        lines = [f"  {dumps(v)}" for v in content]
        text = "[\n" + ",\n".join(lines) + ("\n]" if lines else "]")
    else:
        text = dumps(content)
    return text.encode("utf-8")


# --------------------------------------------------------------------------- idempotent file placement


def _remove_unexpected(folder: Path, pattern: re.Pattern, keep: set[str]) -> int:
    """Delete our own stale files (and temp files of an interrupted merge) from ``folder``."""
    if not folder.is_dir():
        return 0
    removed = 0
    for p in sorted(folder.iterdir()):
        if p.is_file() and ((pattern.match(p.name) and p.name not in keep) or _TMP_NAME.match(p.name)):
            p.unlink()
            removed += 1
    return removed


# --------------------------------------------------------------------------- validation


# --------------------------------------------------------------------------- per-chunk content


def scene_camera_entry(rec: ImageRecord) -> dict[str, Any]:
    entry = {
        "cam_K": np.asarray(rec.K, dtype=np.float64).reshape(-1).tolist(),
        "depth_scale": float(rec.depth_scale),
        "cam_R_w2c": rotation_list(rec.R_w2c, f"image {rec.index} R_w2c"),
        "cam_t_w2c": vec_mm(rec.t_w2c, f"image {rec.index} t_w2c"),
    }
    if rec.distortion:  # OpenCV's order, as cv2.projectPoints(..., cam_K, cam_dist) takes it
        entry["cam_dist"] = [float(c) for c in rec.distortion]
    if rec.eye is not None:  # the same im_id in '<split>' (left) and '<split>_right' is one pair
        entry["stereo"] = {"eye": rec.eye, "baseline_mm": float(rec.baseline) * 1000.0}
    return entry


def scene_gt_entry(rec: ImageRecord) -> list[dict[str, Any]]:
    return [
        {
            "cam_R_m2c": rotation_list(g.R_m2c, f"image {rec.index} gt {i} R_m2c"),
            "cam_t_m2c": vec_mm(g.t_m2c, f"image {rec.index} gt {i} t_m2c"),
            "obj_id": int(g.obj_id),
        }
        for i, g in enumerate(rec.instances)
    ]


def scene_gt_info_entry(rec: ImageRecord) -> list[dict[str, Any]]:
    return [
        {
            "bbox_obj": [int(v) for v in g.bbox_obj],
            "bbox_visib": [int(v) for v in g.bbox_visib],
            "px_count_all": int(g.px_count_all),
            "px_count_valid": int(g.px_count_valid),
            "px_count_visib": int(g.px_count_visib),
            "visib_fract": float(g.visib_fract),
        }
        for g in rec.instances
    ]


def _chunk_files(rec: ImageRecord, store: Path, im_id: int) -> list[tuple[str, str, Path]]:
    """(subfolder, file name, source) of every file of one image: its kind's folder, named by
    image (and by instance for one file per instance)."""
    files = []
    for kind, names in sorted(rec.files.items()):
        if isinstance(names, str):
            files.append((kind, f"{im_id:06d}{Path(names).suffix.lower()}", store / names))
        else:
            files += [(kind, f"{im_id:06d}_{gt_id:06d}{Path(n).suffix.lower()}", store / n) for gt_id, n in enumerate(names)]
    return files


# --------------------------------------------------------------------------- models


def bop_model_bytes(mesh: MeshData, texture_file: str | None = None) -> bytes:
    """Binary PLY in millimetres with the property names ``inout.load_ply`` understands
    (``texture_u``/``texture_v``, ``comment TextureFile``) and only types it can unpack."""
    comments = ("units: millimetres (written by specsynth)",) + ((f"TextureFile {texture_file}",) if texture_file else ())
    return mesh_bytes(mesh, comments, scale=1000.0, uv_names=("texture_u", "texture_v"), colors_first=True)


def write_models(models_dir: Path, models: Sequence[ObjectAsset]) -> dict[str, int]:
    models_dir = Path(models_dir)
    info: dict[int, dict[str, float]] = {}
    keep: set[str] = set()
    written = 0
    seen: set[int] = set()
    for asset in sorted(models, key=lambda a: a.obj_id):
        if asset.obj_id in seen:
            raise ValueError(f"two models with obj_id {asset.obj_id}")
        seen.add(asset.obj_id)
        stem = f"obj_{asset.obj_id:06d}"
        mesh = read_mesh(asset.mesh_path)
        texture_name = None
        tex = asset.material.texture
        if tex and mesh.uv is not None and Path(tex).is_file():
            texture_name = stem + Path(tex).suffix.lower()
            written += place_file(Path(tex), models_dir / texture_name)
            keep.add(texture_name)
        written += write_if_changed(models_dir / f"{stem}.ply", bop_model_bytes(mesh, texture_name))
        keep.add(f"{stem}.ply")
        # Bounds from the written (float32, mm) vertices so models_info matches the file exactly;
        # the diameter needs all vertex pairs, so it comes precomputed from the asset.
        v = (mesh.vertices.astype(np.float64) * 1000.0).astype(np.float32).astype(np.float64)
        lo, hi = v.min(0), v.max(0)
        info[asset.obj_id] = {
            "diameter": float(asset.diameter * 1000.0),
            "min_x": float(lo[0]), "min_y": float(lo[1]), "min_z": float(lo[2]),
            "size_x": float(hi[0] - lo[0]), "size_y": float(hi[1] - lo[1]), "size_z": float(hi[2] - lo[2]),
        }
    written += write_if_changed(models_dir / "models_info.json", bop_json_bytes(info))
    keep.add("models_info.json")
    removed = _remove_unexpected(models_dir, _MODEL_NAME, keep)
    return {"models": len(info), "written": written, "removed": removed}


# --------------------------------------------------------------------------- the writer


def camera_json(intrinsics: Intrinsics, outputs: Outputs, images: Sequence[ImageEntry]) -> dict[str, Any]:
    if outputs.depth_scale == "auto":
        # Per-image scales live in scene_camera.json; camera.json can hold one, so take the
        # coarsest used (the one that fits every image's range).
        scales = {float(r.depth_scale) for r, _ in images}
        depth_scale = max(scales) if scales else 1.0
    else:
        depth_scale = float(outputs.depth_scale)
    return {
        "cx": float(intrinsics.cx),
        "cy": float(intrinsics.cy),
        "depth_scale": depth_scale,
        "fx": float(intrinsics.fx),
        "fy": float(intrinsics.fy),
        "height": int(intrinsics.height),
        "width": int(intrinsics.width),
    }


def write_bop(
    out: Path,
    split: str,
    images: Sequence[ImageEntry],
    models: Sequence[ObjectAsset],
    intrinsics: Intrinsics,
    outputs: Outputs,
    kinds: Iterable[str] = (),
) -> dict[str, int]:
    """Write (or bring up to date) ``<out>/bop``; returns counts. ``kinds``: file kinds whose chunk
    folders this writer tidies besides those the images have (a kind no longer written leaves)."""
    out = Path(out)
    root = out / "bop"
    split_dir = root / split
    images = sorted_images(images)
    counts = {"bop_images": len(images), "bop_instances": 0, "bop_chunks": 0, "bop_written": 0, "bop_removed": 0}

    counts["bop_written"] += write_if_changed(root / "camera.json", bop_json_bytes(camera_json(intrinsics, outputs, images)))
    m = write_models(root / "models", models)
    counts["bop_models"] = m["models"]
    counts["bop_written"] += m["written"]
    counts["bop_removed"] += m["removed"]

    by_chunk: dict[int, list[ImageEntry]] = defaultdict(list)
    for rec, store in images:
        check_image(rec)
        by_chunk[chunk_and_im_id(rec.index, outputs.chunk_size)[0]].append((rec, store))
    managed = sorted(set(kinds) | {k for rec, _ in images for k in rec.files})
    for chunk, entries in sorted(by_chunk.items()):
        for k, v in _write_chunk(split_dir / f"{chunk:06d}", entries, outputs.chunk_size, managed).items():
            counts[k] += v
        counts["bop_chunks"] += 1
    counts["bop_removed"] += _remove_stale_chunks(split_dir, set(by_chunk), managed)
    return counts


def _write_chunk(cdir: Path, entries: list[ImageEntry], chunk_size: int, managed: list[str]) -> dict[str, int]:
    """One chunk folder: every image's files, then its JSON, then what is no longer ours."""
    counts = {"bop_instances": 0, "bop_written": 0, "bop_removed": 0}
    keep: dict[str, set[str]] = {d: set() for d in managed}
    scene_camera: dict[int, Any] = {}
    scene_gt: dict[int, Any] = {}
    scene_gt_info: dict[int, Any] = {}
    for rec, store in entries:
        im_id = chunk_and_im_id(rec.index, chunk_size)[1]
        # Build the JSON entries before touching files: a corrupt record fails the merge early.
        scene_camera[im_id] = scene_camera_entry(rec)
        scene_gt[im_id] = scene_gt_entry(rec)
        scene_gt_info[im_id] = scene_gt_info_entry(rec)
        counts["bop_instances"] += len(rec.instances)
        for sub, name, src in _chunk_files(rec, store, im_id):
            counts["bop_written"] += place_file(src, cdir / sub / name)
            keep[sub].add(name)

    # Images first, JSON last: the JSON never names a file that is not in place yet.
    jsons = {
        "scene_camera.json": bop_json_bytes(scene_camera),
        "scene_gt.json": bop_json_bytes(scene_gt),
        "scene_gt_info.json": bop_json_bytes(scene_gt_info),
    }
    for name, data in jsons.items():
        counts["bop_written"] += write_if_changed(cdir / name, data)
    for sub in managed:
        counts["bop_removed"] += _remove_unexpected(cdir / sub, _FILE_NAME, keep[sub])
        _rmdir_if_empty(cdir / sub)
    _remove_unexpected(cdir, _NOTHING, set())  # temp files of an interrupted JSON write
    return counts


def _rmdir_if_empty(folder: Path) -> None:
    try:
        folder.rmdir()
    except OSError:
        pass  # missing or not empty: both fine


def _remove_stale_chunks(split_dir: Path, live: set[int], managed: list[str]) -> int:
    """Chunk folders of images no longer built: this writer's files in them (another writer's
    files, like COCO's, are its own to remove; the folder goes when the last one has)."""
    if not split_dir.is_dir():
        return 0
    removed = 0
    for cdir in sorted(split_dir.iterdir()):
        if not (cdir.is_dir() and _CHUNK_NAME.match(cdir.name)) or int(cdir.name) in live:
            continue
        for sub in managed:
            removed += _remove_unexpected(cdir / sub, _FILE_NAME, set())
            _rmdir_if_empty(cdir / sub)
        for name in CHUNK_JSONS:
            if (cdir / name).exists():
                (cdir / name).unlink()
                removed += 1
        _remove_unexpected(cdir, _NOTHING, set())
        _rmdir_if_empty(cdir)
    return removed


class BopWriter(DatasetWriter):
    name = "bop"
    description = ("BOP: bop/camera.json, models/ (millimetres) and per split and chunk every file kind's "
                   "folder, scene_camera.json, scene_gt.json, scene_gt_info.json (the layout bop_toolkit_lib reads).")
    default = True

    def write(self, merge: Merge) -> dict[str, int]:
        counts: dict[str, int] = {}
        spec = merge.spec
        for part in merge.parts:
            found = write_bop(merge.out, part.split, part.images, merge.models, spec.intrinsics, spec.outputs, merge.kinds)
            for k, v in found.items():
                counts[k] = v if k == "bop_models" else counts.get(k, 0) + v
        return counts

    def owns(self, rel: str, merge: Merge) -> bool | None:
        parts = rel.split("/")
        if parts[0] != "bop":
            return None
        if len(parts) == 2 or parts[1] == "models":
            return True
        ours = (len(parts) == 5 and _FILE_NAME.match(parts[4])) or (len(parts) == 4 and parts[3] in CHUNK_JSONS)
        return (parts[1] in merge.splits) if ours else None


WRITER = BopWriter()
