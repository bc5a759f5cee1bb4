"""What every dataset writer shares: the image listing (records in index order, their chunk ids and
relative paths), BOP-unit conversions, and the two ways a file lands in ``--out`` (atomic write of
bytes, independent copy of a store file). BOP, COCO, Parquet, YOLO and the attribution file import
this module; none imports another writer's privates.
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

ImageEntry = tuple[ImageRecord, Path]  # record + the store folder holding its files

# A rotation further than this from orthonormal is a corrupt record, not float noise.
ORTHONORMAL_TOL = 1e-5


def chunk_and_im_id(index: int, chunk_size: int) -> tuple[int, int]:
    return index // chunk_size, index % chunk_size


def image_relpaths(split: str, rec: ImageRecord, chunk_size: int) -> dict[str, str | None]:
    """Paths (relative to ``<out>``) of an image's files in the BOP layout."""
    chunk, im_id = chunk_and_im_id(rec.index, chunk_size)
    base = f"bop/{split}/{chunk:06d}"
    return {
        "rgb": f"{base}/rgb/{im_id:06d}{Path(rec.rgb_file).suffix.lower()}",
        "depth": f"{base}/depth/{im_id:06d}.png" if rec.depth_file else None,
        "exr": f"{base}/exr/{im_id:06d}.exr" if rec.exr_file else None,
        "normals": f"{base}/normals/{im_id:06d}.exr" if rec.normals_file else None,
        "nocs": f"{base}/nocs/{im_id:06d}.exr" if rec.nocs_file else None,
        "depth_noisy": f"{base}/depth_noisy/{im_id:06d}.png" if rec.depth_noisy_file else None,
        "albedo": f"{base}/albedo/{im_id:06d}.png" if rec.albedo_file else None,
    }


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
    if rec.mask_files and len(rec.mask_files) != n:
        raise ValueError(f"image {rec.index}: {len(rec.mask_files)} mask files for {n} instances")
    if rec.mask_visib_files and len(rec.mask_visib_files) != n:
        raise ValueError(f"image {rec.index}: {len(rec.mask_visib_files)} mask_visib files for {n} instances")
    if np.asarray(rec.K).shape != (3, 3):
        raise ValueError(f"image {rec.index}: K must be 3x3")


def sorted_images(images: Iterable[ImageEntry]) -> list[ImageEntry]:
    """Images in index order; duplicates are a merge bug that would silently overwrite files."""
    out = sorted(((r, Path(s)) for r, s in images), key=lambda e: e[0].index)
    for (a, _), (b, _) in zip(out, out[1:]):
        if a.index == b.index:
            raise ValueError(f"two render records for image index {a.index}")
    return out
