"""Files read or written on a user's behalf, checked before they are opened.

- A path is opened only once ``os.stat`` says it is a regular file: a FIFO blocks its reader for
  ever, ``/dev/zero`` never ends, and a folder or a link loop is not "missing" (:func:`not_a_file`).
- Nothing outside a folder given to write into is written, followed or deleted: a symbolic link in
  it that points elsewhere is refused before any work (:func:`refuse_links_out`).
"""

from __future__ import annotations

import errno
import json
import os
import re
import stat
from pathlib import Path

_KINDS = (
    (stat.S_ISDIR, "a folder, not a file"),
    (stat.S_ISFIFO, "a FIFO (named pipe), not a regular file"),
    (stat.S_ISCHR, "a character device, not a regular file"),
    (stat.S_ISBLK, "a block device, not a regular file"),
    (stat.S_ISSOCK, "a socket, not a regular file"),
)


class UnsafeOutput(RuntimeError):
    """A symbolic link inside an output folder would carry writes or deletes outside it, or the
    path given to write into is not a folder (or, for a file, not a regular file)."""


def output_folder(path: str | os.PathLike, what: str = "--out") -> Path:
    """``path`` as a folder a command may create and write into: refused when a file, a FIFO or a
    device is there, or when it is the file system's root (whose walk for links reaches /proc)."""
    p = Path(path)
    if os.path.exists(p) and not os.path.isdir(p):
        kind = (not_a_file(p) or "a file").removesuffix(", not a regular file")
        raise UnsafeOutput(f"{what} {p}: {kind}, not a folder; give a folder to write into")
    _refuse_a_file_on_the_way(p, what)
    real = Path(os.path.realpath(p))
    if real == real.parent:
        raise UnsafeOutput(f"{what} {p}: the root of the file system; give a folder of its own to write into")
    long = next((part for part in real.parts if len(os.fsencode(part)) > NAME_MAX), None)
    if long is not None:
        raise UnsafeOutput(f"{what}: a folder name of {len(os.fsencode(long))} bytes, over the file system's "
                           f"{NAME_MAX}; give a shorter one")
    if len(os.fsencode(str(real))) > PATH_MAX - PATH_ROOM:
        raise UnsafeOutput(f"{what}: a path of {len(os.fsencode(str(real))):,} bytes; the files written under it "
                           f"need up to {PATH_ROOM} more, within the system's {PATH_MAX:,}: give a shorter one")
    return p


NAME_MAX = 255  # bytes in one file or folder name (Linux, macOS)
PATH_MAX = 4096  # bytes in a whole path (Linux)
PATH_ROOM = 512  # what a build adds under its folder (store keys, staging, BOP's nested names), with room to spare


def output_file(path: str | os.PathLike, what: str) -> Path:
    """``path`` as a file a command may (re)write: refused when something other than a regular file
    is there (a FIFO would block the writer, a device swallow or fill it, a folder not be a file).
    Write it atomically (:mod:`specsynth.atomic`): a link there is then replaced, not followed."""
    p = Path(path)
    problem = not_a_file(p)
    if os.path.lexists(p) and problem not in (None, "not found"):
        raise UnsafeOutput(f"{what} {p}: {problem}; give the path of a regular file to write")
    _refuse_a_file_on_the_way(p.parent, what, p)
    return p


def _refuse_a_file_on_the_way(folder: Path, what: str, given: Path | None = None) -> None:
    """A folder to create must not have a file where one of its parents would be: the command would
    stop with NotADirectoryError after its work instead of now."""
    for parent in (folder, *folder.parents):
        if os.path.exists(parent):
            if not os.path.isdir(parent):
                raise UnsafeOutput(f"{what} {given or folder}: {parent} is a file, not a folder; give a folder to "
                                   "write into")
            return


def not_a_file(path: str | os.PathLike) -> str | None:
    """Why ``path`` cannot be read as a file ("not found", "a FIFO ...", "a symbolic link loop"),
    or None for a regular file. Links are followed, the file is never opened."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return "not found"
    except NotADirectoryError:
        return "not found (a folder on its path is a file)"
    except OSError as e:
        if e.errno == errno.ELOOP:
            return "a symbolic link loop"
        return f"cannot be read ({e.strerror or type(e).__name__})"
    if stat.S_ISREG(st.st_mode):
        return None
    return next((kind for test, kind in _KINDS if test(st.st_mode)), "not a regular file")


def read_regular(path: str | os.PathLike, limit: int | None = None) -> bytes:
    """The bytes of a regular file, at most ``limit`` of them; OSError (its strerror says why)
    for anything else. Opened without blocking and checked again on the open descriptor, so a
    FIFO put in the file's place after a check cannot hang the reader either."""
    problem = not_a_file(path)
    if problem is not None:
        raise OSError(errno.ENOENT if problem == "not found" else errno.EINVAL, problem)
    fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    with open(fd, "rb") as f:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise OSError(errno.EINVAL, "not a regular file")
        if limit is not None and st.st_size > limit:
            raise OSError(errno.EFBIG, f"{st.st_size:,} bytes, over the {limit:,}-byte limit")
        data = f.read() if limit is None else f.read(limit + 1)
    if limit is not None and len(data) > limit:
        raise OSError(errno.EFBIG, f"over the {limit:,}-byte limit")
    return data


def inside(path: str | os.PathLike, root: str | os.PathLike) -> bool:
    """Whether ``path`` is ``root`` or lies under it once every link on both is resolved."""
    p, r = Path(os.path.realpath(path)), Path(os.path.realpath(root))
    return p == r or r in p.parents


def plain_relative(rel) -> bool:
    """Whether ``rel``, read from a file, is a plain relative path: no absolute path, no ``..``,
    no empty or ``.`` part, no NUL (string checks only, cheap for a dataset's 10^5 names)."""
    if not isinstance(rel, str) or not rel or "\0" in rel or rel.startswith("/"):
        return False
    return not any(part in ("", ".", "..") for part in rel.split("/"))


def under(root: str | os.PathLike, rel: str) -> Path | None:
    """``root / rel`` for a path read from a file (a build's own index of its files): a plain
    relative path that stays under ``root`` once links are resolved; None for anything else (an
    absolute path, a ``..``, a link out), which a command then neither writes nor deletes."""
    if not plain_relative(rel):
        return None
    path = Path(root, *rel.split("/"))
    return path if inside(path.parent, root) else None


def refuse_links_out(folder: Path) -> None:
    """Every file a command writes or deletes lives under ``folder``: a symbolic link in there
    pointing elsewhere (``out/bop -> /data``) would carry writes and deletes out of it, so the
    command stops and names it instead. Links that stay inside ``folder`` are harmless."""
    root = Path(folder).resolve()
    todo = [os.fspath(folder)]
    while todo:  # scandir's entries know whether they are links without a stat each (a dataset: 10^5 files)
        try:
            entries = list(os.scandir(todo.pop()))
        except OSError:  # gone meanwhile, or unreadable: as os.walk, nothing to refuse there
            continue
        for entry in entries:
            if entry.is_symlink():
                if not inside(entry.path, root):
                    raise UnsafeOutput(f"{entry.path}: a symbolic link out of the output folder (to "
                                       f"{os.path.realpath(entry.path)}); remove it or give another folder")
            elif entry.is_dir(follow_symlinks=False):
                todo.append(entry.path)


class RepeatedKey(ValueError):
    """A JSON object that names one key twice (``json.loads`` keeps the last without a word)."""


def _once(pairs: list) -> dict:
    d = dict(pairs)
    if len(d) != len(pairs):
        raise RepeatedKey()
    return d


def loads_json_strict(data: bytes):
    """JSON read from a user's file, every key of an object once (:class:`RepeatedKey` otherwise)."""
    return json.loads(data, object_pairs_hook=_once)


_IMAGE_ID = re.compile(r"0|[1-9][0-9]{0,8}")  # as BOP writes them: "3" and "03" must not both name image 3


def is_image_id(key) -> bool:
    """Whether a BOP table's key is an image id as BOP writes it: ASCII digits, no leading zero."""
    return isinstance(key, str) and _IMAGE_ID.fullmatch(key) is not None
