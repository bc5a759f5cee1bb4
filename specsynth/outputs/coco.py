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
import re
from collections import defaultdict
from pathlib import Path
from typing import Any, Sequence

from ..assets.resolve import ObjectAsset
from ..model.records import ImageRecord
from ..output_api import DatasetWriter, Merge, Part
from ..spec.models import Metadata
from .dataset import LAYOUT, ImageEntry, chunk_and_im_id, coco_box, file_paths, plain, sorted_images, write_if_changed
from .masks import Rle, rle_area, visible_rles

IGNORE_VISIB_FRACT = 0.1  # the toolkit's threshold for "ignore" ground truth
CHUNK_FILE = "scene_gt_coco.json"  # one per BOP chunk, beside the BOP writer's JSON
_CHUNK_NAME = re.compile(r"^\d{6}$")


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
            area = rle_area(rle)
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


def chunk_document(
    entries: Sequence[tuple[ImageEntry, list[Rle | None]]],
    chunk_size: int,
    cats: list[dict[str, Any]],
    description: str,
    meta: Metadata,
) -> dict[str, Any]:
    """``scene_gt_coco.json`` of one chunk: image_id = im_id, file names relative to the chunk."""
    items = []
    for (rec, _), rles in entries:
        im_id = chunk_and_im_id(rec.index, chunk_size)[1]
        items.append((im_id, f"rgb/{im_id:06d}{Path(rec.files['rgb']).suffix.lower()}", rec, rles))
    return _document(items, cats, description, meta)


def coco_json_bytes(doc: dict[str, Any]) -> bytes:
    return json.dumps(plain(doc), sort_keys=True, separators=(",", ":"), allow_nan=False).encode("utf-8")


def write_coco(merge: Merge, part: Part) -> dict[str, int]:
    """``<out>/coco/<split>.json`` for the whole split (image_id = the global image index, file
    names into ``bop/`` when it is written, else at the store files) and, beside BOP's, each
    chunk's ``scene_gt_coco.json``."""
    spec, out = merge.spec, Path(merge.out)
    images = sorted_images(part.images)
    rles = [visible_rles(rec, store) for rec, store in images]  # each image's RLE file read once
    cats = categories(merge.models, spec.name)
    items = [(rec.index, "../" + file_paths(merge, part.split, rec, store)["rgb"], rec, r)
             for (rec, store), r in zip(images, rles)]
    doc = _document(items, cats, f"{spec.name}_{part.split}", spec.metadata)
    write_if_changed(out / "coco" / f"{part.split}.json", coco_json_bytes(doc))
    if LAYOUT in merge.enabled:
        _write_chunk_files(out / "bop" / part.split, list(zip(images, rles)), spec.outputs.chunk_size, cats,
                           f"{spec.name}_{part.split}", spec.metadata)
    return {"coco_images": len(doc["images"]), "coco_annotations": len(doc["annotations"])}


def _write_chunk_files(split_dir: Path, entries: list, chunk_size: int, cats: list, description: str,
                       meta: Metadata) -> None:
    """Each chunk's document; those of chunks no longer built are removed (with their folder
    when nothing else is left in it)."""
    by_chunk: dict[int, list] = defaultdict(list)
    for (rec, store), rles in entries:
        by_chunk[chunk_and_im_id(rec.index, chunk_size)[0]].append(((rec, store), rles))
    for chunk, items in sorted(by_chunk.items()):
        write_if_changed(split_dir / f"{chunk:06d}" / CHUNK_FILE,
                         coco_json_bytes(chunk_document(items, chunk_size, cats, description, meta)))
    stale = [d for d in (sorted(split_dir.iterdir()) if split_dir.is_dir() else [])
             if d.is_dir() and _CHUNK_NAME.match(d.name) and int(d.name) not in by_chunk]
    for cdir in stale:
        (cdir / CHUNK_FILE).unlink(missing_ok=True)
        try:
            cdir.rmdir()
        except OSError:
            pass  # something else is left in it


class CocoWriter(DatasetWriter):
    name = "coco"
    description = ("COCO instance annotations: coco/<split>.json and, with BOP, each chunk's scene_gt_coco.json "
                   "(visible masks as RLE, COCO's box convention).")
    default = True

    def write(self, merge: Merge) -> dict[str, int]:
        counts: dict[str, int] = {}
        for part in merge.parts:
            for k, v in write_coco(merge, part).items():
                counts[k] = counts.get(k, 0) + v
        return counts

    def owns(self, rel: str, merge: Merge) -> bool | None:
        parts = rel.split("/")
        if len(parts) == 2 and parts[0] == "coco" and parts[1].endswith(".json"):
            return parts[1].removesuffix(".json") in merge.splits
        if len(parts) == 4 and parts[0] == "bop" and parts[3] == CHUNK_FILE:
            return LAYOUT in merge.enabled and parts[1] in merge.splits
        return None


WRITER = CocoWriter()
