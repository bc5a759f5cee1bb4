"""Distractors drawn from BOP models folders (``arrangements.distractors.paths``): each folder is
read as ``objects.path`` is, and its models are named ``bop/<k>/obj_XXXXXX`` after the folder's
place ``k`` in the list, so an arrangement record names what it dropped without a path."""

from __future__ import annotations

import re
from dataclasses import replace
from pathlib import Path

from ..spec.models import Objects
from .resolve import AssetError, ObjectAsset, bop_folder_ids, object_fingerprints, object_size_problems, resolve_objects

PREFIX = "bop/"
_NAME = re.compile(r"bop/(\d+)/obj_(\d{6})")


def model_name(k: int, obj_id: int) -> str:
    return f"{PREFIX}{k}/obj_{obj_id:06d}"


def parse(name: str) -> tuple[int, int]:
    """(folder index, obj id) of a model name."""
    m = _NAME.fullmatch(name)
    if m is None:
        raise ValueError(f"{name!r} is not a BOP distractor's name")
    return int(m.group(1)), int(m.group(2))


def _field(k: int) -> str:
    return f"arrangements.distractors.paths.{k}"


def _located(e: AssetError, k: int) -> AssetError:
    """An error about a folder, named at its entry of the list (the reader names objects.path)."""
    return AssetError(str(e).replace("objects.path", _field(k)).replace("objects.ids", _field(k)), field=_field(k))


def model_names(paths: list[str], spec_dir: Path) -> list[str]:
    """Every model of every folder, in list order then by obj id: what the draw picks from."""
    out = []
    for k, path in enumerate(paths):
        try:
            out += [model_name(k, i) for i in bop_folder_ids(Objects(path=path), spec_dir)]
        except AssetError as e:
            raise _located(e, k) from None
    return out


def fingerprints(paths: list[str], spec_dir: Path) -> tuple[dict[str, str], list[AssetError]]:
    """(model name -> content hash, the folders' problems): their bytes key the arrangements, and a
    folder in the wrong unit is refused at its entry, as objects.path is."""
    found, problems = {}, []
    for k, path in enumerate(paths):
        objects = Objects(path=path)
        try:
            prints = object_fingerprints(objects, spec_dir)
            problems += [_located(e, k) for e in object_size_problems(objects, spec_dir, prints)]
        except AssetError as e:
            problems.append(_located(e, k))
            continue
        found.update({f"{PREFIX}{k}/{name}": fp for name, fp in prints.items()})
    return found, problems


def assets(names: list[str], paths: list[str], spec_dir: Path) -> dict[str, ObjectAsset]:
    """The models ``names`` (distinct), converted (cached) and named as drawn."""
    wanted: dict[int, set[int]] = {}
    for name in names:
        k, obj_id = parse(name)
        wanted.setdefault(k, set()).add(obj_id)
    out = {}
    for k, ids in sorted(wanted.items()):
        for a in resolve_objects(Objects(path=paths[k], ids=sorted(ids)), spec_dir):
            out[model_name(k, a.obj_id)] = replace(a, name=model_name(k, a.obj_id))
    return out
