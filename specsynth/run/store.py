"""Content-addressed store of finished job outputs under ``<out>/.specsynth/store``.

A job's outputs are written into a private temp folder and renamed into place as a whole, with
``record.json`` written last inside it: a job counts as done only when its folder exists with a
record, so a build killed at any moment never exposes half-written results.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import uuid
from pathlib import Path
from typing import Any

from ..atomic import atomic_write_bytes, disk_full
from ..plan.keys import canonical_json

RECORD = "record.json"


class CorruptRecord(ValueError):
    """A record that does not parse (a torn write, a full disk); the message names its path."""


def _complete(record: Path) -> bool:
    """Cheap check that a record was written whole: canonical JSON objects end with '}'. A torn
    record (power loss, full disk) fails it and its job simply runs again."""
    try:
        with open(record, "rb") as f:
            f.seek(-1, os.SEEK_END)
            return f.read(1) == b"}"
    except OSError:
        return False


class Store:
    def __init__(self, out: Path):
        self.root = Path(out) / ".specsynth" / "store"
        self.tmp = Path(out) / ".specsynth" / "tmp"

    def path(self, stage: str, key: str) -> Path:
        return self.root / stage / key[:2] / key

    def has(self, stage: str, key: str) -> bool:
        return _complete(self.path(stage, key) / RECORD)

    def load(self, stage: str, key: str) -> dict[str, Any]:
        path = self.path(stage, key) / RECORD
        try:
            return json.loads(path.read_bytes())
        except (ValueError, RecursionError) as e:
            raise CorruptRecord(f"{path}: corrupt job record ({type(e).__name__}); delete it to re-run the job") from None

    def keys(self, stage: str) -> set[str]:
        """All finished keys of a stage, listed once (cheap cache checks for big plans)."""
        base = self.root / stage
        if not base.is_dir():
            return set()
        return {p.name for d in base.iterdir() if d.is_dir() for p in d.iterdir() if _complete(p / RECORD)}

    def begin(self) -> Path:
        # The owner's pid in the name: a resumed build must not clean up after a worker of a
        # killed build that is still finishing its job (it commits whole folders or nothing).
        d = self.tmp / f"{os.getpid()}-{uuid.uuid4().hex}"
        d.mkdir(parents=True)
        return d

    def commit(self, stage: str, key: str, workdir: Path, record: dict[str, Any]) -> Path:
        data = canonical_json(record)
        try:
            with open(workdir / RECORD, "wb") as f:  # on disk before the rename makes it count
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
        except OSError as e:
            if e.errno == errno.ENOSPC:
                raise disk_full(workdir / RECORD, len(data)) from None
            raise
        final = self.path(stage, key)
        final.parent.mkdir(parents=True, exist_ok=True)
        if final.is_dir() and not _complete(final / RECORD):
            shutil.rmtree(final)  # a torn earlier attempt of this very job: ours to replace
        try:
            os.rename(workdir, final)
        except OSError:
            # Another worker finished the same job first (same key, same content): keep theirs.
            if not _complete(final / RECORD):
                raise
            shutil.rmtree(workdir, ignore_errors=True)
        return final

    def put(self, stage: str, key: str, record: dict[str, Any]) -> Path:
        return self.commit(stage, key, self.begin(), record)

    def clean_tmp(self) -> None:
        """Remove leftovers of killed jobs (holding the build lock); folders of processes still
        alive on this machine are left to them. Workers on other hosts are not visible here."""
        if not self.tmp.is_dir():
            return
        for d in self.tmp.iterdir():
            pid = d.name.split("-", 1)[0]
            if pid.isdigit() and int(pid) != os.getpid() and _alive(int(pid)):
                continue
            shutil.rmtree(d, ignore_errors=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def stored(record: dict[str, Any]) -> dict[str, Any]:
    """``record`` exactly as ``Store.load`` will return it (canonical JSON read back: tuples become
    lists, numpy numbers plain ones), for a caller that keeps what it committed."""
    return json.loads(canonical_json(record))


def write_json(path: Path, obj: Any, *, indent: int | None = 2) -> None:
    text = json.dumps(obj, indent=indent, sort_keys=True, allow_nan=False) + "\n"
    atomic_write_bytes(path, text.encode("utf-8"))
