"""What a build wrote, by content: ``<out>/.specsynth/outputs.json`` and checks against it.

Every merge records each output file's size, mtime and sha256 (a file whose size and mtime are
the recorded ones is not hashed again). ``specsynth diff`` then compares two datasets by their
files' recorded hashes and verifies each side's files against its own record, so an output
edited or deleted after its build is reported instead of going unnoticed.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

from ..files import inside, plain_relative, read_regular
from .store import write_json

INDEX = Path(".specsynth") / "outputs.json"
# The files two builds of one spec differ in: render seconds per image (a stereo build's right eye
# has its own).
TIMINGS = ("timings.parquet", "timings_right.parquet")


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def output_files(out: Path) -> list[Path]:
    """Every file of the dataset: all of ``out`` but specsynth's own ``.specsynth`` folder."""
    return sorted(p for p in out.rglob("*") if p.is_file() and not p.is_symlink()
                  and p.relative_to(out).parts[0] != ".specsynth")


def read_index(out: Path) -> dict[str, list]:
    """The last build's index of its files: {relative path: [size, mtime_ns, sha256]}. A file in the
    folder, so it is read as data: what is not that shape (a damaged or edited index) is left out,
    as an index that cannot be read is, and its files are hashed again."""
    try:
        index = json.loads(read_regular(Path(out) / INDEX))
    except (OSError, ValueError, RecursionError):
        return {}
    if not isinstance(index, dict):
        return {}
    return {rel: entry for rel, entry in index.items() if _an_entry(entry) and plain_relative(rel)}


def _an_entry(entry) -> bool:
    return (isinstance(entry, list) and len(entry) == 3 and all(type(x) is int for x in entry[:2])
            and isinstance(entry[2], str))


def write_index(out: Path) -> dict[str, list]:
    """Record every output file; unchanged ones (same size and mtime) keep their hash."""
    index = index_of(Path(out), read_index(out))
    write_json(Path(out) / INDEX, index, indent=None)
    return index


def index_of(folder: Path, old: dict[str, list]) -> dict[str, list]:
    """Every output file of ``folder`` by relative path: [size, mtime, sha256]. A file whose size
    and mtime are those ``old`` records for its path keeps its hash (a merge's staging folder
    holds hard links of the current dataset's files: same size and mtime)."""
    index = {}
    for p in output_files(folder):
        rel = p.relative_to(folder).as_posix()
        st = p.stat()
        prev = old.get(rel)
        if prev and prev[0] == st.st_size and prev[1] == st.st_mtime_ns:
            index[rel] = prev
        else:
            index[rel] = [st.st_size, st.st_mtime_ns, _sha256(p)]
    return index


def verify(out: Path) -> dict[str, list[str]]:
    """Files that changed or vanished since the build recorded them (every file is re-hashed)."""
    out = Path(out)
    index = read_index(out)
    changed, missing = [], []
    for rel, (_, _, sha) in sorted(index.items()):
        p = out.joinpath(*rel.split("/"))  # read_index keeps plain relative paths only
        if not inside(p, out) or not p.is_file():  # a link out is not followed: what it named counts as gone
            missing.append(rel)
        elif _sha256(p) != sha:
            changed.append(rel)
    return {"changed": changed, "missing": missing}


def compare(a: Path, b: Path, skip: tuple[str, ...] = TIMINGS) -> dict[str, Any]:
    """Two datasets by their recorded file hashes (but for ``TIMINGS``: wall-clock seconds),
    plus each side verified against its own record."""
    ia, ib = read_index(a), read_index(b)
    keep = lambda rel: rel.rsplit("/", 1)[-1] not in skip  # noqa: E731
    only_a = sorted(r for r in ia if r not in ib and keep(r))
    only_b = sorted(r for r in ib if r not in ia and keep(r))
    differ = sorted(r for r in ia if r in ib and keep(r) and ia[r][2] != ib[r][2])
    return {"only_in_a": only_a, "only_in_b": only_b, "differ": differ,
            "a_since_built": verify(a), "b_since_built": verify(b), "recorded": bool(ia) and bool(ib)}
