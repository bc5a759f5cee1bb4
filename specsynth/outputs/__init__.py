"""Merge-step writers: BOP, Parquet and COCO from render records and their store files.

``write_outputs`` is the one entry point the build runner calls; the per-format functions are
usable on their own. Worker-side per-view encoders live in :mod:`specsynth.outputs.images`.
"""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Iterable, Sequence

from ..assets.resolve import ObjectAsset
from ..spec.models import DatasetSpec
from .bop import write_bop
from .coco import all_visible_rles, write_coco
from .dataset import ImageEntry, sorted_images
from .parquet import write_parquet

__all__ = ["write_outputs", "write_bop", "write_coco", "write_parquet"]


def write_outputs(
    out: Path, spec: DatasetSpec, images: Sequence[ImageEntry], models: Sequence[ObjectAsset],
    previous: Iterable[str] = (),
) -> dict[str, int]:
    """Write every output the spec enables into ``out``; returns counts by name. A stereo build's
    right eye is a dataset of its own beside the left: split ``<split>_right``, parquet ``*_right``.
    ``previous``: the files the last build wrote (relative paths), of which those this spec no
    longer writes are removed."""
    _remove_stale(Path(out), spec, previous)
    right = sorted_images(e for e in images if e[0].eye == "right")
    counts = _write_eye(Path(out), spec, sorted_images(e for e in images if e[0].eye != "right"), models, spec.split, "")
    if right:
        for k, v in _write_eye(Path(out), spec, right, models, f"{spec.split}_right", "_right").items():
            counts[k] = counts.get(k, 0) + v
    else:  # an earlier stereo build's right eye must not outlive its spec
        _remove_right_eye(Path(out), spec.split)
    return counts


def _remove_stale(out: Path, spec: DatasetSpec, previous: Iterable[str]) -> None:
    """A format turned off or a split renamed since the last build: its files go with it, as a
    clean build of this spec would not have them (files the last build did not write stay)."""
    o, splits = spec.outputs, {spec.split, f"{spec.split}_right"}

    def kept(rel: str) -> bool:
        parts = rel.split("/")
        if parts[0] == "bop":
            return o.bop and (len(parts) < 3 or parts[1] == "models" or parts[1] in splits)
        if parts[0] == "coco":
            return o.coco and parts[-1].removesuffix(".json") in splits
        return parts[0] != "parquet" or o.parquet

    for rel in previous:
        if kept(rel):
            continue
        (out / rel).unlink(missing_ok=True)
        folder = (out / rel).parent
        while folder != out and folder.is_dir() and not any(folder.iterdir()):  # left empty
            folder.rmdir()
            folder = folder.parent


def _remove_right_eye(out: Path, split: str) -> None:
    shutil.rmtree(out / "bop" / f"{split}_right", ignore_errors=True)
    for stale in [out / "coco" / f"{split}_right.json", *(out / "parquet").glob("*_right.parquet")]:
        stale.unlink(missing_ok=True)


def _write_eye(out: Path, spec: DatasetSpec, images, models, split: str, suffix: str) -> dict[str, int]:
    o = spec.outputs
    # Visible-mask RLEs feed three files; decode each mask PNG once.
    rles = all_visible_rles(images) if (o.coco or o.parquet) else None
    counts: dict[str, int] = {"images": len(images), "instances": sum(len(r.instances) for r, _ in images)}
    if o.bop:
        counts |= write_bop(
            out, split, images, models, spec.intrinsics, o, coco=o.coco, rles=rles, dataset_name=spec.name,
            meta=spec.metadata,
        )
    if o.parquet:
        counts |= write_parquet(out, split, images, o.chunk_size, bop_layout=o.bop, rles=rles, suffix=suffix)
    if o.coco:
        counts |= write_coco(
            out, split, images, models, o.chunk_size, bop_layout=o.bop, rles=rles, dataset_name=spec.name,
            meta=spec.metadata,
        )
    return counts
