"""COCO instance annotations: BOP's per-chunk ``scene_gt_coco.json`` and one ``<out>/coco/<split>.json``.

Follows the BOP toolkit's ``calc_gt_coco.py`` output: category_id = obj_id, segmentation = RLE of
``mask_visib``, instances with an empty visible mask left out, ``ignore`` set below 10 % visible.
Differences, on purpose: bbox is the *visible* (modal) box, as in the BOP'22 train_pbr downloads;
RLE counts are pycocotools' compressed strings (``pycocotools.coco.COCO`` and the toolkit's
``rle_to_binary_mask`` both read them).

Box convention: COCO's, not BOP's. A box ``[x, y, w, h]`` covers the pixels ``x .. x + w - 1``, so
``w = xmax - xmin + 1``, exactly what ``pycocotools.mask.toBbox`` gives for the annotation's own
mask (and what detectron2, mmdetection and the BOP toolkit's COCO converter read). BOP files keep
BOP's ``w = xmax - xmin``.

Dates (``info.date_created``, ``images[].date_captured``) come from the spec's ``metadata``, never
from the clock, so two builds of one spec are byte-identical.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Sequence

import numpy as np
from PIL import Image
from pycocotools import mask as mask_utils

from ..assets.resolve import ObjectAsset
from ..model.records import ImageRecord
from ..spec.models import Metadata
from .dataset import ImageEntry, chunk_and_im_id, image_relpaths, plain, sorted_images, write_if_changed

IGNORE_VISIB_FRACT = 0.1  # the toolkit's threshold for "ignore" ground truth

Rle = dict[str, Any]  # {"counts": str, "size": [h, w]}


def read_mask(path: Path) -> np.ndarray:
    with Image.open(path) as im:
        return np.asarray(im) > 0


def encode_rle(mask: np.ndarray) -> Rle:
    rle = mask_utils.encode(np.asfortranarray(mask.astype(np.uint8)))
    return {"counts": rle["counts"].decode("ascii"), "size": [int(s) for s in rle["size"]]}


# Written by the render job next to its masks, so the serial merge does not decode every mask.
RLE_FILE = "mask_visib_rle.json"


def write_visible_rles(folder: Path, masks_visib: Sequence[np.ndarray]) -> None:
    """Worker side: the RLEs of a view's visible masks, in gt order."""
    (Path(folder) / RLE_FILE).write_text(json.dumps([encode_rle(m) for m in masks_visib]))


def visible_rles(rec: ImageRecord, store: Path) -> list[Rle | None]:
    """RLE of each instance's ``mask_visib`` in gt order; None when the build wrote no masks.
    Read from the render job's RLE file, or encoded from the mask files (stores from before it)."""
    if not rec.mask_visib_files:
        return [None] * len(rec.instances)
    cached = Path(store) / RLE_FILE
    if cached.is_file():
        return json.loads(cached.read_text())
    return [encode_rle(read_mask(Path(store) / name)) for name in rec.mask_visib_files]


def all_visible_rles(images: Sequence[ImageEntry]) -> dict[int, list[Rle | None]]:
    """Read every visible mask once; BOP's COCO files, the split COCO file and Parquet share it."""
    return {rec.index: visible_rles(rec, store) for rec, store in images}


def coco_box(bbox_visib: Sequence[int]) -> list[int]:
    """BOP box (w = xmax - xmin) -> COCO box (w = xmax - xmin + 1); an empty box stays as it is."""
    x, y, w, h = (int(v) for v in bbox_visib)
    if w < 0 or h < 0:
        return [x, y, w, h]
    return [x, y, w + 1, h + 1]


LICENSE_ID = 1  # the dataset's one licence; every image refers to it


def info_and_licenses(meta: Metadata, description: str) -> dict[str, Any]:
    """COCO's ``info`` and ``licenses``, which FiftyOne and CVAT imports look for."""
    return {
        "info": {
            "description": description,
            "url": meta.url,
            "version": meta.version,
            "year": meta.date_created.year,
            "contributor": meta.contributor,
            "date_created": meta.date_created.isoformat(),
        },
        "licenses": [{"id": LICENSE_ID, "name": meta.license.name, "url": meta.license.url}],
    }


def date_captured(meta: Metadata) -> str:
    return f"{meta.date_created.isoformat()} 00:00:00"  # COCO's "YYYY-MM-DD hh:mm:ss"


def categories(models: Sequence[ObjectAsset], supercategory: str) -> list[dict[str, Any]]:
    return [
        {"id": int(a.obj_id), "name": a.name, "supercategory": supercategory}
        for a in sorted(models, key=lambda a: a.obj_id)
    ]


def _annotations(
    rec: ImageRecord, rles: list[Rle | None], image_id: int, first_id: int
) -> list[dict[str, Any]]:
    anns = []
    for g, rle in zip(rec.instances, rles):
        ann: dict[str, Any] = {
            "id": first_id + len(anns),
            "image_id": image_id,
            "category_id": int(g.obj_id),
            "iscrowd": 0,
            "width": int(rec.width),
            "height": int(rec.height),
            "ignore": bool(g.visib_fract < IGNORE_VISIB_FRACT),
        }
        if rle is not None:
            area = int(mask_utils.area({"counts": rle["counts"].encode("ascii"), "size": rle["size"]}))
            if area < 1:
                continue  # the toolkit drops instances with nothing visible
            ann["segmentation"] = rle
            ann["area"] = area
        else:
            # Built without masks: boxes only, area from the annotation engine's pixel count.
            if g.px_count_visib < 1:
                continue
            ann["area"] = int(g.px_count_visib)
        ann["bbox"] = coco_box(g.bbox_visib)
        anns.append(ann)
    return anns


def _document(
    entries: list[tuple[int, str, ImageRecord, list[Rle | None]]],
    cats: list[dict[str, Any]],
    description: str,
    meta: Metadata,
) -> dict[str, Any]:
    images, annotations = [], []
    captured = date_captured(meta)
    for image_id, file_name, rec, rles in entries:
        images.append({
            "id": image_id, "file_name": file_name, "width": int(rec.width), "height": int(rec.height),
            "license": LICENSE_ID, "date_captured": captured,
        })
        annotations += _annotations(rec, rles, image_id, len(annotations) + 1)
    return {
        **info_and_licenses(meta, description),
        "categories": cats,
        "images": images,
        "annotations": annotations,
    }


def _rles_for(rec: ImageRecord, store: Path, rles: dict[int, list] | None) -> list[Rle | None]:
    return rles[rec.index] if rles is not None and rec.index in rles else visible_rles(rec, store)


def chunk_document(
    entries: Sequence[ImageEntry],
    chunk_size: int,
    cats: list[dict[str, Any]],
    rles: dict[int, list] | None,
    description: str,
    meta: Metadata,
) -> dict[str, Any]:
    """``scene_gt_coco.json`` of one chunk: image_id = im_id, file names relative to the chunk."""
    items = []
    for rec, store in sorted_images(entries):
        im_id = chunk_and_im_id(rec.index, chunk_size)[1]
        items.append((im_id, f"rgb/{im_id:06d}{Path(rec.rgb_file).suffix.lower()}", rec, _rles_for(rec, store, rles)))
    return _document(items, cats, description, meta)


def coco_json_bytes(doc: dict[str, Any]) -> bytes:
    return json.dumps(plain(doc), sort_keys=True, separators=(",", ":"), allow_nan=False).encode("utf-8")


def write_coco(
    out: Path,
    split: str,
    images: Sequence[ImageEntry],
    models: Sequence[ObjectAsset],
    chunk_size: int,
    *,
    bop_layout: bool = True,
    rles: dict[int, list] | None = None,
    dataset_name: str = "specsynth",
    meta: Metadata = Metadata(),
) -> dict[str, int]:
    """``<out>/coco/<split>.json`` for the whole split; image_id = the global image index.

    File names point into ``bop/`` when it is written, otherwise at the store files.
    """
    out = Path(out)
    path = out / "coco" / f"{split}.json"
    items = []
    for rec, store in sorted_images(images):
        if bop_layout:
            rgb = image_relpaths(split, rec, chunk_size)["rgb"]
        else:
            rgb = os.path.relpath(Path(store) / rec.rgb_file, out).replace(os.sep, "/")
        items.append((rec.index, "../" + rgb, rec, _rles_for(rec, store, rles)))
    doc = _document(items, categories(models, dataset_name), f"{dataset_name}_{split}", meta)
    write_if_changed(path, coco_json_bytes(doc))
    return {"coco_images": len(doc["images"]), "coco_annotations": len(doc["annotations"])}
