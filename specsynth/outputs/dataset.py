"""What every dataset writer shares: the image listing (records in index order, their chunk ids and
relative paths, a view's other images as parts of their own), BOP-unit and box conversions, and the
two ways a file lands in ``--out`` (atomic write of bytes, independent copy of a store file). BOP,
COCO, Parquet, YOLO and the attribution file import this module; none imports another writer
(an import-linter contract).
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np

from ..atomic import atomic_write_bytes, atomic_write_via
from ..model.conventions import m_to_mm
from ..model.records import ImageRecord
from ..output_api import ImageEntry, Merge, Part

# The writer whose layout (bop/<split>/<chunk>/<kind>/) the other formats' file names point into
# when it is on; without it they point at the store's files.
LAYOUT = "bop"

# A rotation further than this from orthonormal is a corrupt record, not float noise.
ORTHONORMAL_TOL = 1e-5


def chunk_and_im_id(index: int, chunk_size: int) -> tuple[int, int]:
    return index // chunk_size, index % chunk_size


def image_relpaths(split: str, rec: ImageRecord, chunk_size: int) -> dict[str, str]:
    """Paths (relative to ``<out>``) of an image's one-per-image files in the BOP layout, by kind:
    ``bop/<split>/<chunk>/<kind>/<im_id><suffix>``."""
    chunk, im_id = chunk_and_im_id(rec.index, chunk_size)
    base = f"bop/{split}/{chunk:06d}"
    return {kind: f"{base}/{kind}/{im_id:06d}{Path(name).suffix.lower()}"
            for kind, name in sorted(rec.files.items()) if isinstance(name, str)}


def file_paths(merge: Merge, split: str, rec: ImageRecord, store: Path) -> dict[str, str]:
    """An image's one-per-image files by kind, relative to ``<out>``: in the BOP layout when that
    writer is on, else the store's own files."""
    if LAYOUT in merge.enabled:
        return image_relpaths(split, rec, merge.spec.outputs.chunk_size)
    return {kind: os.path.relpath(Path(store) / name, merge.final_out).replace(os.sep, "/")
            for kind, name in sorted(rec.files.items()) if isinstance(name, str)}


def parts(split: str, images: Iterable[ImageEntry]) -> tuple[Part, ...]:
    """The views' images as split ``split``, and each other image of a view (``companions``: a
    stereo rig's right eye) as split ``<split>_<name>``, its files under ``<store>/<name>``."""
    own = sorted_images(images)
    others: dict[str, list[ImageEntry]] = {}
    for rec, store in own:
        for name, sub in rec.companions.items():
            others.setdefault(name, []).append((ImageRecord.from_json(sub), Path(store) / name))
    return (Part(split, "", tuple(own)),
            *(Part(f"{split}_{name}", f"_{name}", tuple(sorted_images(others[name]))) for name in sorted(others)))


def coco_box(bbox_visib: Sequence[int]) -> list[int]:
    """BOP box (w = xmax - xmin) -> COCO box (w = xmax - xmin + 1); an empty box stays as it is.
    COCO, YOLO and whoever reads COCO's convention share it."""
    x, y, w, h = (int(v) for v in bbox_visib)
    if w < 0 or h < 0:
        return [x, y, w, h]
    return [x, y, w + 1, h + 1]


def plain(x: Any) -> Any:
    """numpy scalars/arrays -> Python, so json output does not depend on where a number came from."""
    if isinstance(x, dict):
        return {k: plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return plain(x.tolist())
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        return float(x)
    return x


def write_if_changed(path: Path, data: bytes) -> bool:
    """Atomic write that skips identical content, so re-merging keeps inodes and mtimes."""
    path = Path(path)
    try:
        if path.stat().st_size == len(data) and path.read_bytes() == data:
            return False
    except FileNotFoundError:
        pass
    atomic_write_bytes(path, data)
    return True


def _no_follow(path: str, flags: int) -> int:
    return os.open(path, flags | os.O_NOFOLLOW)  # the temp file is ours: never a link put in its place


def place_file(src: Path, dst: Path) -> bool:
    """Copy ``src`` to ``dst`` atomically, keeping its mtime; False when ``dst`` is already that
    copy (same size and mtime: a later edit of ``dst`` changes them and is repaired here)."""
    src, dst = Path(src), Path(dst)
    if not src.is_file():
        raise FileNotFoundError(f"store file missing: {src}")
    st = src.stat()
    if dst.is_file() and not dst.is_symlink():
        dt = dst.stat()
        if dt.st_size == st.st_size and dt.st_mtime_ns == st.st_mtime_ns and dt.st_ino != st.st_ino:
            return False

    def copy(tmp: str) -> None:
        with open(tmp, "wb", opener=_no_follow) as out, open(src, "rb") as inp:
            if not _reflink(inp.fileno(), out.fileno()):
                shutil.copyfileobj(inp, out, 1 << 20)
        os.utime(tmp, ns=(st.st_atime_ns, st.st_mtime_ns))

    atomic_write_via(dst, copy)
    return True


def _reflink(src_fd: int, dst_fd: int) -> bool:
    """Share the source's blocks copy-on-write (btrfs, XFS); False where unsupported (ext4)."""
    import fcntl

    try:
        fcntl.ioctl(dst_fd, 0x40049409, src_fd)  # FICLONE
        return True
    except OSError:
        return False


def rotation_list(R: Sequence[Sequence[float]], what: str) -> list[float]:
    a = np.asarray(R, dtype=np.float64)
    if a.shape != (3, 3) or not np.isfinite(a).all():
        raise ValueError(f"{what}: rotation must be a finite 3x3 matrix, got shape {a.shape}")
    err = float(np.abs(a @ a.T - np.eye(3)).max())
    if err > ORTHONORMAL_TOL or np.linalg.det(a) < 0:
        raise ValueError(f"{what}: rotation is not orthonormal (|R R^T - I| = {err:.2e}, det {np.linalg.det(a):.3f})")
    return a.reshape(-1).tolist()


def vec_mm(t: Sequence[float], what: str) -> list[float]:
    a = np.asarray(t, dtype=np.float64)
    if a.shape != (3,) or not np.isfinite(a).all():
        raise ValueError(f"{what}: translation must be 3 finite numbers, got {t!r}")
    return m_to_mm(a).tolist()


def check_image(rec: ImageRecord) -> None:
    n = len(rec.instances)
    if not rec.file("rgb"):
        raise ValueError(f"image {rec.index}: no rgb file")
    for kind, names in sorted(rec.files.items()):
        if isinstance(names, list) and names and len(names) != n:
            raise ValueError(f"image {rec.index}: {len(names)} {kind} files for {n} instances")
    if np.asarray(rec.K).shape != (3, 3):
        raise ValueError(f"image {rec.index}: K must be 3x3")


def sorted_images(images: Iterable[ImageEntry]) -> list[ImageEntry]:
    """Images in index order; duplicates are a merge bug that would silently overwrite files."""
    out = sorted(((r, Path(s)) for r, s in images), key=lambda e: e[0].index)
    for (a, _), (b, _) in zip(out, out[1:]):
        if a.index == b.index:
            raise ValueError(f"two render records for image index {a.index}")
    return out
