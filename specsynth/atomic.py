"""Atomic file writing: the one way specsynth puts a file in place.

A file is written to a temp file beside its destination and renamed onto it, so a reader (or a
build killed half-way) sees the old file or the new one, never a part. Directories (the store's
job folders, unpacked libraries) are published the same way by renaming a finished temp folder.
"""

from __future__ import annotations

import errno
import os
import shutil
import uuid
from pathlib import Path
from typing import Callable


def new_temp_beside(path: Path, suffix: str = ".tmp") -> tuple[int, str]:
    """(fd, name) of a new, empty temp file next to ``path``, for an atomic rename onto it.

    Created with mode 0666 so the process umask applies (0644 by default): mkstemp's 0600 would
    make every dataset file unreadable to other users and containers."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    while True:
        tmp = str(path.parent / f".{path.name}.{uuid.uuid4().hex[:12]}{suffix}")
        try:
            return os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), 0o666), tmp
        except FileExistsError:
            continue


def atomic_write_bytes(path: Path, data: bytes) -> None:
    fd, tmp = new_temp_beside(path)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, path)
    except BaseException as e:
        if os.path.exists(tmp):
            os.unlink(tmp)
        if isinstance(e, OSError) and e.errno == errno.ENOSPC:
            raise disk_full(Path(path), len(data)) from None
        raise


def disk_full(path: Path, needed: int) -> OSError:
    """ENOSPC with what the bare error lacks: which file, how much was needed, how much is free."""
    try:
        free = shutil.disk_usage(path.parent).free
    except OSError:
        free = -1
    return OSError(errno.ENOSPC, f"no space left on the device of {path}: writing {needed:,} bytes, "
                                 f"{free:,} bytes free; free some space and run the build again (finished jobs are kept)")


def atomic_write_via(path: Path, write: Callable[[str], None], suffix: str = ".tmp") -> None:
    """Put ``path`` in place atomically when a library writes the file itself, by name (OpenEXR)
    or through its own file object: ``write(tmp)`` fills the temp file, which is then renamed."""
    fd, tmp = new_temp_beside(path, suffix)
    os.close(fd)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
