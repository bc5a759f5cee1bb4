"""Ultralytics YOLO export of a built dataset (``specsynth export yolo OUT DEST``).

Reads only the BOP output (``bop/<split>/<chunk>/scene_gt*.json`` and ``rgb/``), so it works on
any BOP-format folder. Writes the layout Ultralytics' ``check_det_dataset`` reads::

    DEST/data.yaml                  names, train/val folders (relative: the folder can be moved)
    DEST/images/<split>/<bop split>_<chunk>_<im_id>.<ext>   copies, never links into OUT
    DEST/labels/<split>/<bop split>_<chunk>_<im_id>.txt     one "class cx cy w h" line per visible object

DEST follows the rules of a build's ``--out``: a new folder, an empty one or an earlier export,
with no symbolic link in it leading elsewhere. Everything that could stop an export (options, a
missing RGB file, an unreadable image, a box outside its image, a split that leaves nothing to
train on) is checked before the first file is
written. A stereo build's right eye (``<split>_right``) goes with its left eye, into the same
YOLO split as the rest of its arrangement.

Boxes are the visible (modal) boxes, in COCO's pixel convention (``w = xmax - xmin + 1``, pixel
``i`` spanning ``[i, i + 1)``), normalised by the image size: what Ultralytics' own COCO
converter produces. Class indices are 0-based in obj_id order.

As a dataset writer (``outputs.yolo: true``, after BOP) the merge exports the build into
``<out>/yolo/`` with the defaults: every split a training split, names from the build's models.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import re
from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Sequence

import yaml

from ..files import UnsafeOutput, inside, refuse_links_out
from ..output_api import DatasetWriter, Merge
from .dataset import coco_box, place_file, write_if_changed
from .qa import BopImage, list_images, read_json

DEFAULT_MIN_VISIB = 0.1  # the COCO writer's "ignore" threshold: below it a box teaches noise
RIGHT = "_right"  # a stereo build's right eye: split <split>_right, parquet tables *_right
# Written before anything else: a DEST an export was interrupted in is still recognised as ours.
MARKER = ".specsynth-yolo"
_OURS = re.compile(r"^[A-Za-z0-9_\-]+_\d{6}_\d{6}\.(jpg|jpeg|png|txt)$")


class ExportError(ValueError):
    """A missing or unusable source, or a destination that is not ours to write."""


@dataclass
class YoloSummary:
    images: dict[str, int] = field(default_factory=dict)  # per YOLO split
    boxes: int = 0
    skipped_low_visibility: int = 0
    names: dict[int, str] = field(default_factory=dict)


def yolo_line(cls: int, bbox_visib: Sequence[int], width: int, height: int) -> str:
    """``class cx cy w h`` from a BOP visible box, normalised to [0, 1]."""
    x, y, w, h = coco_box(bbox_visib)
    cx, cy = (x + w / 2) / width, (y + h / 2) / height
    return f"{cls} {cx:.6f} {cy:.6f} {w / width:.6f} {h / height:.6f}"


def label_text(img: BopImage, class_of: dict[int, int], min_visib: float) -> tuple[str, int, int]:
    """The label file of one image -> (text, boxes written, boxes skipped for low visibility)."""
    width, height = _image_size(img)
    lines, skipped = [], 0
    for j, (g, info) in enumerate(zip(img.gt, img.gt_info)):
        if info.get("px_count_visib", 0) < 1 or info["bbox_visib"][2] < 0:
            continue
        if info.get("visib_fract", 1.0) < min_visib:
            skipped += 1
            continue
        _check_box(info["bbox_visib"], width, height, img, j)
        lines.append(yolo_line(class_of[obj_id(img, g)], info["bbox_visib"], width, height))
    return "".join(line + "\n" for line in lines), len(lines), skipped


def _check_box(box: Sequence[int], width: int, height: int, img: BopImage, j: int) -> None:
    """A visible box lies in its image (BOP: x + w <= width); one past it was made for another image
    size and would become a label out of [0, 1]."""
    x, y, w, h = box
    if x < 0 or y < 0 or x + w > width or y + h > height:
        raise ExportError(f"{img.chunk / 'scene_gt_info.json'}: image {img.im_id}, annotation {j}: bbox_visib lies "
                          f"outside its {width} x {height} image {img.rgb.name}")


def _image_size(img: BopImage) -> tuple[int, int]:
    from PIL import Image

    try:
        with Image.open(img.rgb) as im:
            return im.size
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as e:  # PIL's ways of saying "not an image"
        raise ExportError(f"{img.rgb}: unreadable image ({type(e).__name__})") from None


def class_names(out: Path, images: Sequence[BopImage]) -> dict[int, str]:
    """obj_id -> name: every model in ``models_info.json`` (so indices do not depend on which
    objects happened to be seen), names from the COCO categories when the build wrote them."""
    bop = out / "bop"
    ids: set[int] = {obj_id(img, g) for img in images for g in img.gt}
    info = bop / "models" / "models_info.json"
    if os.path.lexists(info):
        ids |= _model_ids(read_json(info, out), info)
    names = {i: f"obj_{i:06d}" for i in sorted(ids)}
    for coco in sorted((out / "coco").glob("*.json")):
        for oid, name in _categories(read_json(coco, out), coco):
            if oid in names:
                names[oid] = name
    return names


def _model_ids(info, path: Path) -> set[int]:
    if not isinstance(info, dict) or not all(k.isascii() and k.isdigit() for k in info):
        raise ExportError(f"{path}: expected an object keyed by obj_id")
    return {int(k) for k in info}


def _categories(coco, path: Path) -> list[tuple[int, str]]:
    """(id, name) of a COCO file's categories, or an error naming the file (never its values)."""
    cats = coco.get("categories", []) if isinstance(coco, dict) else None
    ok = isinstance(cats, list) and all(
        isinstance(c, dict) and isinstance(c.get("id"), int) and not isinstance(c.get("id"), bool)
        and isinstance(c.get("name"), str) for c in cats)
    if not ok:
        raise ExportError(f"{path}: categories must be a list of objects with an integer id and a name")
    return [(c["id"], c["name"]) for c in cats]


def obj_id(img: BopImage, gt: dict) -> int:
    """An annotation's obj_id; anything but an integer is named by place, never quoted."""
    value = gt.get("obj_id") if isinstance(gt, dict) else None
    if isinstance(value, bool) or not isinstance(value, int):
        raise ExportError(f"{img.chunk / 'scene_gt.json'}: image {img.im_id}: obj_id must be an integer")
    return value


def arrangement_of(out: Path) -> dict[str, int]:
    """rgb path (relative to OUT) -> arrangement, from the Parquet images table when it exists,
    so that a held-out split never shares an arrangement with the training split."""
    import pyarrow.parquet as pq

    found: dict[str, int] = {}
    for table in (out / "parquet" / "images.parquet", out / "parquet" / f"images{RIGHT}.parquet"):
        if table.is_file():
            try:
                t = pq.read_table(table, columns=["rgb", "arr"]).to_pydict()
            except (OSError, ValueError, KeyError) as e:  # pyarrow's ArrowInvalid is a ValueError
                raise ExportError(f"{table}: unreadable images table, or without its rgb and arr columns "
                                  f"({type(e).__name__})") from None
            found.update(zip(t["rgb"], t["arr"]))
    return found


def eye_base(split: str) -> str:
    """The split a stereo right eye belongs to (``train_pbr_right`` -> ``train_pbr``)."""
    return split.removesuffix(RIGHT)


def held_out(keys: Sequence[str], fraction: float) -> set[str]:
    """A deterministic ``fraction`` of ``keys`` (at least one when fraction > 0), by hash order."""
    if fraction <= 0 or not keys:
        return set()
    ranked = sorted(set(keys), key=lambda k: hashlib.sha256(k.encode()).hexdigest())
    n = max(1, round(fraction * len(ranked)))
    return set(ranked[:n])


def _yolo_split(img: BopImage, val_split: str | None, val_groups: set[str], group_of) -> str:
    split = img.chunk.parent.name
    if val_split is not None:
        return "val" if split in (val_split, val_split + RIGHT) else split
    return "val" if group_of(img) in val_groups else split


def _check_dest(dest: Path, out: Path) -> None:
    """DEST follows the rules of a build's --out: ours or empty, and nothing in it links elsewhere
    (``images -> /data`` would carry the copies and the stale-file deletes out of it)."""
    if dest.is_symlink():
        raise ExportError(f"{dest}: is a symbolic link; give a real folder")
    if dest.exists() and not dest.is_dir():
        raise ExportError(f"{dest}: is a file, not a folder; give a new or empty folder")
    if dest.resolve() == out.resolve() or out.resolve() in dest.resolve().parents:
        raise ExportError(f"{dest}: must not be inside the dataset folder {out}")
    if not dest.exists():
        return
    if any(dest.iterdir()) and not ((dest / "data.yaml").is_file() or (dest / MARKER).is_file()):
        raise ExportError(f"{dest}: exists and is not a YOLO export (no data.yaml); give an empty or new folder")
    try:
        refuse_links_out(dest)
    except UnsafeOutput as e:
        raise ExportError(str(e)) from None


def _check_options(min_visib: float, val_fraction: float) -> None:
    if not 0.0 <= val_fraction < 1.0:  # NaN fails both comparisons
        raise ExportError(f"--val-fraction {val_fraction}: must be in [0, 1)")
    if not (math.isfinite(min_visib) and 0.0 <= min_visib <= 1.0):
        raise ExportError(f"--min-visib {min_visib}: must be a fraction in [0, 1]")


def _check_rgb(missing: list[Path]) -> None:
    if missing:
        raise ExportError(f"{len(missing)} image(s) listed in scene_gt.json have no RGB file (the first: "
                          f"{missing[0]}.jpg or .png); rebuild the dataset (specsynth build restores them)")


def _check_own_files(images: list[BopImage], out: Path) -> None:
    """Export copies the dataset's own images only, before anything is written: a link out of the
    dataset would copy a file from elsewhere into the export (a FIFO is no image file to
    ``list_images``, so it is missing already)."""
    for img in images:
        if not inside(img.rgb, out):
            raise ExportError(f"{img.rgb}: a link out of the dataset folder {out} (to {os.path.realpath(img.rgb)}); "
                              "export copies only the dataset's own files")


def _check_training_left(splits: list[str], val_split: str | None, val_fraction: float, groups: int) -> None:
    """Refused before anything is written: an export whose every image is held out has no
    training split for data.yaml to name."""
    if any(s != "val" for s in splits):
        return
    why = (f"--val {val_split!r} is the only split" if val_split is not None else
           f"--val-fraction {val_fraction:g} of {groups} arrangement(s) holds out every one")
    raise ExportError(f"{why}: nothing is left to train on; hold out fewer, or build more arrangements")


def export_yolo(
    out: Path, dest: Path, *, min_visib: float = DEFAULT_MIN_VISIB, val_split: str | None = None,
    val_fraction: float = 0.0,
) -> YoloSummary:
    out, dest = Path(out), Path(dest)
    _check_options(min_visib, val_fraction)
    for path, what in ((out, "the dataset"), (dest, "the destination")):
        try:  # data.yaml names both; a name that is not UTF-8 would stop the export half-way
            os.fspath(path.resolve()).encode("utf-8")
        except UnicodeEncodeError:
            raise ExportError(f"{what}'s path is not valid UTF-8; rename it") from None
    if not (out / "bop").is_dir():
        raise ExportError(f"{out}: no bop/ folder (build with outputs.bop: true)")
    _check_dest(dest, out)
    return _export(out, dest, min_visib=min_visib, val_split=val_split, val_fraction=val_fraction)


def _export(out: Path, dest: Path, *, min_visib: float, val_split: str | None, val_fraction: float,
            names: dict[int, str] | None = None, dataset: Path | None = None) -> YoloSummary:
    """The export once its options and destination are known to be good; ``names``: obj_id ->
    class name (default: read from the dataset's models and COCO files); ``dataset``: the
    dataset's folder as data.yaml names it, when ``out`` is where it is being written."""
    missing: list[Path] = []
    images = list_images(out, missing)
    _check_rgb(missing)
    if not images:
        raise ExportError(f"{out / 'bop'}: no images")
    _check_own_files(images, out)
    splits = {img.chunk.parent.name for img in images}
    for split in splits:
        try:
            split.encode("utf-8")
        except UnicodeEncodeError:
            raise ExportError(f"{out / 'bop'}: a split folder's name is not valid UTF-8; rename it") from None
    if val_split is not None and val_split not in splits:
        raise ExportError(f"--val {val_split!r}: no such split in {out / 'bop'} (have {', '.join(sorted(splits))})")

    names = class_names(out, images) if names is None else names
    class_of = {obj_id: i for i, obj_id in enumerate(sorted(names))}
    arr = arrangement_of(out) if val_fraction > 0 else {}

    def group_of(img: BopImage) -> str:
        """Both eyes of a view, and every view of an arrangement, in one group."""
        split = eye_base(img.chunk.parent.name)
        rel = img.rgb.relative_to(out).as_posix()
        if rel in arr:
            return f"{split}/arr={arr[rel]}"
        return (out / "bop" / split / img.chunk.name / "rgb" / img.rgb.name).relative_to(out).as_posix()

    groups = [group_of(i) for i in images]
    val_groups = held_out(groups, val_fraction) if val_split is None else set()
    placed = [_yolo_split(img, val_split, val_groups, group_of) for img in images]
    _check_training_left(placed, val_split, val_fraction, len(set(groups)))
    summary = YoloSummary(names={class_of[i]: n for i, n in names.items()})
    labels = [label_text(img, class_of, min_visib) for img in images]  # a bad box stops it before any write
    keep: dict[str, set[str]] = defaultdict(set)
    dest.mkdir(parents=True, exist_ok=True)
    write_if_changed(dest / MARKER, b"specsynth export yolo\n")
    for img, split, (text, n, skipped) in zip(images, placed, labels):
        stem = f"{img.chunk.parent.name}_{int(img.chunk.name):06d}_{img.im_id:06d}"
        place_file(img.rgb, dest / "images" / split / (stem + img.rgb.suffix.lower()))
        write_if_changed(dest / "labels" / split / f"{stem}.txt", text.encode())
        keep[split] |= {stem + img.rgb.suffix.lower(), f"{stem}.txt"}
        summary.images[split] = summary.images.get(split, 0) + 1
        summary.boxes += n
        summary.skipped_low_visibility += skipped
    _remove_stale(dest, keep)
    write_if_changed(dest / "data.yaml", data_yaml(summary, out if dataset is None else dataset, min_visib))
    return summary


def data_yaml(summary: YoloSummary, out: Path, min_visib: float) -> bytes:
    splits = sorted(summary.images)
    train = [s for s in splits if s != "val"]
    val = "val" if "val" in splits else train[0]
    doc = {
        # No 'path': Ultralytics then resolves the folders against this file's own folder.
        "train": [f"images/{s}" for s in train] if len(train) > 1 else f"images/{train[0]}",
        "val": f"images/{val}",
        "nc": len(summary.names),
        "names": summary.names,
    }
    head = (
        f"# Written by specsynth export yolo from {out.name}: visible boxes of objects at least "
        f"{min_visib:g} visible.\n"
    )
    if "val" not in splits:
        head += "# No held-out split (see --val / --val-fraction): val is the training split.\n"
    return (head + yaml.safe_dump(doc, sort_keys=False)).encode()


def _remove_stale(dest: Path, keep: dict[str, set[str]]) -> None:
    """Files of a previous export that this one no longer has (only names this writer makes)."""
    for kind in ("images", "labels"):
        root = dest / kind
        if not root.is_dir():
            continue
        for folder in root.iterdir():
            if not folder.is_dir() or folder.is_symlink():
                continue
            for p in folder.iterdir():
                if _OURS.match(p.name) and p.name not in keep.get(folder.name, set()):
                    p.unlink()


class YoloWriter(DatasetWriter):
    name = "yolo"
    description = ("Ultralytics YOLO: yolo/data.yaml, images/ (copies) and labels/ of visible boxes, every split for "
                   "training (specsynth export yolo holds some out).")
    needs = ("bop",)  # it exports the BOP output just written

    def write(self, merge: Merge) -> dict[str, int]:
        s = _export(Path(merge.out), Path(merge.out) / "yolo", min_visib=DEFAULT_MIN_VISIB, val_split=None,
                    val_fraction=0.0, names={m.obj_id: m.name for m in sorted(merge.models, key=lambda m: m.obj_id)},
                    dataset=Path(merge.final_out))
        return {"yolo_images": sum(s.images.values()), "yolo_boxes": s.boxes}

    def owns(self, rel: str, merge: Merge) -> bool | None:
        return True if rel.split("/")[0] == "yolo" else None


WRITER = YoloWriter()
