"""The merge's dataset writers, and ``write_outputs``, which runs those the spec switches on.

Writers are plugins (``specsynth.writers``: BOP, COCO, Parquet, YOLO here, any other package's
alike; see :mod:`specsynth.output_api`), each a module that imports only the shared ones
(``dataset.py``, ``masks.py``, ``images.py``). Worker-side encoders live in
:mod:`specsynth.outputs.images`; the per-view products in :mod:`specsynth.products`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Iterable, Sequence

from ..assets.resolve import ObjectAsset
from ..files import under
from ..output_api import DatasetWriter, ImageEntry, Merge, in_order, products, writers
from ..spec.models import DatasetSpec
from .dataset import parts

__all__ = ["write_outputs"]


def write_outputs(
    out: Path, spec: DatasetSpec, images: Sequence[ImageEntry], models: Sequence[ObjectAsset],
    previous: Iterable[str] = (), final: Path | None = None,
) -> dict[str, int]:
    """Write every format the spec switches on into ``out``; counts by name. ``images``: the
    views' records; another image of a view (a stereo right eye) is a split of its own beside
    them (``<split>_right``, Parquet ``*_right``). ``previous``: the files the last build wrote
    (relative paths), of which those no writer writes now are removed. ``final``: the folder
    ``out`` becomes once in place (a build writes aside and swaps), when it is another."""
    found = writers()
    enabled = frozenset(spec.outputs.selected("writer"))
    kinds = frozenset({"rgb"}) | {k for p in products().values() for k in p.file_kinds()}
    merge = Merge(Path(out), spec, parts(spec.split, images), tuple(models), enabled, kinds, final)
    _remove_stale(merge, found, previous)
    counts: dict[str, int] = {}
    for part in merge.parts:
        counts["images"] = counts.get("images", 0) + len(part.images)
        counts["instances"] = counts.get("instances", 0) + sum(len(r.instances) for r, _ in part.images)
    for writer in in_order(found, enabled):
        counts |= writer.write(merge)
    return counts


def _remove_stale(merge: Merge, found: dict[str, DatasetWriter], previous: Iterable[str]) -> None:
    """A format switched off, a split renamed, a stereo rig removed since the last build: the files
    of the last build that some writer owns and none writes now go, as a clean build of this spec
    would not have them (files no writer owns, a user's, stay)."""
    out = merge.out
    for rel in previous:
        path = under(out, rel)  # the index is a file in the folder: data, never a path out of it
        if path is None:
            continue
        said = [_current(w, rel, merge) for w in found.values()]
        if True in said or False not in said:
            continue
        path.unlink(missing_ok=True)
        folder = path.parent
        while folder != out and out in folder.parents and folder.is_dir() and not any(folder.iterdir()):  # left empty
            folder.rmdir()
            folder = folder.parent


def _current(writer: DatasetWriter, rel: str, merge: Merge) -> bool | None:
    """Whether ``writer`` writes ``rel`` now (None: not its file); a writer switched off writes none."""
    owned = writer.owns(rel, merge)
    return owned if owned is None or writer.name in merge.enabled else False
