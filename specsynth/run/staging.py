"""A new dataset written aside and swapped in, so that a failed or killed merge never leaves half
of one in ``--out``: at every instant each top-level entry of the folder (``bop/``, ``coco/``,
``parquet/``, ``ATTRIBUTION.md``, ...) is the last complete dataset's or the new complete one's,
and a build killed while swapping is finished by the next build before it does anything else.

Under ``<out>/.specsynth/staging/``:

- ``new/`` the dataset being written: hard links of the current dataset's files (no bytes copied),
  brought up to date by the writers. Writers put every file in place by renaming a new file over
  the old name, so a write never reaches the current dataset through a link; a file they remove
  is only unlinked from ``new/``. ``new/.specsynth/`` holds the manifest, the record of the files
  and the completion mark that go with it.
- ``swap.json`` the journal, written once ``new/`` is complete: the top-level entries to swap (each
  with the identity of its new version) and the metadata that goes with them. A build that finds
  it finishes the swap (``finish``); without it, ``new/`` is an unfinished merge and is discarded.
- ``old/`` what the swap took out, removed at the end.

Everything stays inside ``--out`` (same filesystem: renames, never copies): links are made, never
followed, and a symbolic link copied into ``new/`` that would point out of ``--out`` is refused.
"""

from __future__ import annotations

import ctypes
import errno
import json
import os
import shutil
import stat
from pathlib import Path

from ..files import UnsafeOutput, inside
from .store import write_json
from .verify import INDEX

STAGING = Path(".specsynth") / "staging"
# The mark of a dataset merged without failures (swapped in with it, removed while a swap runs):
# one a failing rebuild must not replace; and the failures such a rebuild spared it.
COMPLETE = Path(".specsynth") / "complete.json"
KEPT_FAILURES = Path(".specsynth") / "failures.json"
# The files of ``.specsynth`` that describe the dataset in place: each is the new dataset's after
# a swap, or absent when the new one has none (a merge with failures is not marked complete; the
# failures a kept dataset was spared were the last build's only). The mark goes last.
META = ("manifest.json", INDEX.name, KEPT_FAILURES.name, COMPLETE.name)


class Staging:
    def __init__(self, out: Path):
        self.out = Path(out)
        self.root = self.out / STAGING
        self.new = self.root / "new"
        self.old = self.root / "old"
        self.journal = self.root / "swap.json"
        self._seeded: list[str] = []

    def recover(self) -> None:
        """Finish a swap a killed build left half-done, or discard the merge it left unfinished
        (the next merge's writers start again from the dataset in place)."""
        if not self.finish():
            _remove(self.root)

    def begin(self) -> Path:
        """A fresh ``new/`` holding the current dataset as hard links; its path."""
        self.recover()
        (self.new / ".specsynth").mkdir(parents=True)
        self._seeded = sorted(n for n in os.listdir(self.out) if n != ".specsynth")
        for name in self._seeded:
            _link_tree(self.out / name, self.new / name, self.out)
        return self.new

    def commit(self) -> None:
        """Swap ``new/`` in: the journal first, so a build killed while swapping is finished by
        the next one."""
        entries = {name: _identity(self.new / name) for name in os.listdir(self.new) if name != ".specsynth"}
        entries |= {name: None for name in self._seeded if name not in entries}  # removed by the writers
        meta = sorted(n for n in META if (self.new / ".specsynth" / n).is_file())
        write_json(self.journal, {"entries": entries, "meta": meta})
        self.finish()

    def finish(self) -> bool:
        """Finish the swap the journal describes, if there is one (idempotent: a kill at any point
        of it leaves what the next call completes); whether there was one."""
        try:
            journal = json.loads(self.journal.read_bytes())
        except FileNotFoundError:
            return False
        if not (COMPLETE.name in journal["meta"] and not (self.new / COMPLETE).exists()):  # not the new mark yet
            (self.out / COMPLETE).unlink(missing_ok=True)  # between datasets until the end
        self.old.mkdir(parents=True, exist_ok=True)
        for name, ident in sorted(journal["entries"].items()):
            self._swap(name, None if ident is None else tuple(ident))
        for name in META:
            self._place_meta(name, name in journal["meta"])
        self.journal.unlink()
        _remove(self.root)
        return True

    def _swap(self, name: str, ident: tuple[int, int] | None) -> None:
        """Put the new version of top-level entry ``name`` in place (or take it out when the new
        dataset has none), the old one into ``old/``."""
        staged, live, gone = self.new / name, self.out / name, self.old / name
        if ident is None:
            if os.path.lexists(live):
                os.rename(live, gone)
        elif os.path.lexists(live) and _identity(live) == ident:  # swapped before a kill
            if os.path.lexists(staged):
                os.rename(staged, gone)  # what the exchange took out (or a link of the same file)
        elif not os.path.lexists(live):
            os.rename(staged, live)
        elif not (_is_dir(staged) or _is_dir(live)):
            os.replace(staged, live)  # a file: renamed over the old one
        elif _exchange(staged, live):
            os.rename(staged, gone)
        else:  # no atomic exchange here: the old one out, then the new one in
            os.rename(live, gone)
            os.rename(staged, live)

    def _place_meta(self, name: str, new_has_it: bool) -> None:
        staged, live = self.new / ".specsynth" / name, self.out / ".specsynth" / name
        if not new_has_it:
            live.unlink(missing_ok=True)
        elif staged.is_file():
            os.replace(staged, live)


def _identity(path: Path) -> tuple[int, int]:
    st = os.lstat(path)
    return st.st_dev, st.st_ino


def _is_dir(path: Path) -> bool:
    return stat.S_ISDIR(os.lstat(path).st_mode)


def _link_tree(src: Path, dst: Path, root: Path) -> None:
    """``dst`` as a copy of ``src`` made of hard links (folders made, links copied as links, never
    followed)."""
    st = os.lstat(src)
    if stat.S_ISDIR(st.st_mode):
        os.mkdir(dst)
        for name in sorted(os.listdir(src)):
            _link_tree(src / name, dst / name, root)
        os.chmod(dst, stat.S_IMODE(st.st_mode))
    elif stat.S_ISLNK(st.st_mode):
        os.symlink(os.readlink(src), dst)
        if not inside(dst, root):  # relative, it would point elsewhere from its new place
            raise UnsafeOutput(f"{src}: a symbolic link that would point out of the output folder from "
                               f"{dst}; make it absolute or remove it")
    elif stat.S_ISREG(st.st_mode):
        try:
            os.link(src, dst, follow_symlinks=False)
        except OSError as e:  # a file another user owns (protected_hardlinks), a mount point
            if e.errno not in (errno.EPERM, errno.EXDEV, errno.EMLINK):
                raise
            shutil.copy2(src, dst, follow_symlinks=False)  # its mtime kept: the index's hash stays valid
    else:
        raise UnsafeOutput(f"{src}: not a file, folder or link (a FIFO, socket or device); the dataset's "
                           "folder cannot keep it across a rebuild: move it elsewhere")


def _remove(path: Path) -> None:
    """Remove ``path`` and what is under it (links removed, never followed)."""
    if path.is_symlink() or path.is_file():
        path.unlink()
    elif path.is_dir():
        shutil.rmtree(path)


_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux renameat2 RENAME_EXCHANGE); False where the system or the
    filesystem has no such call."""
    try:
        renameat2 = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return False
    if renameat2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE) == 0:
        return True
    err = ctypes.get_errno()
    if err in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP):
        return False
    raise OSError(err, os.strerror(err), str(b))
