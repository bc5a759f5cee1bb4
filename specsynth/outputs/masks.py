"""Masks as the writers share them: reading a mask PNG, COCO's run-length encoding, and the RLE file a
render job writes next to its visible masks so that the merge does not decode every mask again.

The visible masks are the ``mask_visib`` files of the ``masks`` product; an image without them
(masks switched off) has no RLEs, and the writers fall back to boxes.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from ..model.records import ImageRecord

Rle = dict[str, Any]  # {"counts": str, "size": [h, w]}: pycocotools' compressed RLE, as text

# Written by the render job next to its masks, so the serial merge does not decode every mask.
RLE_FILE = "mask_visib_rle.json"
VISIBLE = "mask_visib"  # the kind of the visible (modal) masks


def read_mask(path: Path) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as im:
        return np.asarray(im) > 0


def encode_rle(mask: np.ndarray) -> Rle:
    from pycocotools import mask as mask_utils

    rle = mask_utils.encode(np.asfortranarray(mask.astype(np.uint8)))
    return {"counts": rle["counts"].decode("ascii"), "size": [int(s) for s in rle["size"]]}


def rle_area(rle: Rle) -> int:
    from pycocotools import mask as mask_utils

    return int(mask_utils.area({"counts": rle["counts"].encode("ascii"), "size": rle["size"]}))


def write_visible_rles(folder: Path, masks_visib: Sequence[np.ndarray]) -> None:
    """Worker side: the RLEs of a view's visible masks, in gt order (into the job's private
    store folder, which is committed whole)."""
    (Path(folder) / RLE_FILE).write_text(json.dumps([encode_rle(m) for m in masks_visib]))


def visible_rles(rec: ImageRecord, store: Path) -> list[Rle | None]:
    """RLE of each instance's visible mask in gt order; None for each when the image has no masks.
    Read from the render job's RLE file, or encoded from the mask files when it is missing."""
    names = rec.instance_files(VISIBLE)
    if not names:
        return [None] * len(rec.instances)
    cached = Path(store) / RLE_FILE
    if cached.is_file():
        return json.loads(cached.read_text())
    return [encode_rle(read_mask(Path(store) / name)) for name in names]
