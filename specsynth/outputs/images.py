"""Per-view file encoding, run inside render jobs (worker side).

Every writer encodes into memory first and lands the file with one atomic rename, so a worker
killed mid-write never leaves a truncated image that a later merge would hard-link into the
dataset. Encoders are pinned (compression level, chroma subsampling, no metadata) because the
bytes of these files must be identical between two builds of the same spec.
"""

from __future__ import annotations

import io
import math
from pathlib import Path
from typing import Literal

import numpy as np
from PIL import Image

from ..atomic import atomic_write_bytes, atomic_write_via

# Scales a user would recognise (BOP datasets use 0.1 and 1.0); "auto" takes the finest that fits
# so near-range data keeps sub-millimetre resolution.
DEPTH_SCALE_LADDER: tuple[float, ...] = (0.1, 0.25, 0.5, 1.0, 2.0, 5.0, 10.0)
UINT16_MAX = 65535

# zlib level 3 as in the BOP toolkit's save_im: much faster than 9 for a few % more bytes.
PNG_COMPRESS_LEVEL = 3


class DepthOverflowError(ValueError):
    """The depth range does not fit a uint16 PNG at the requested depth_scale."""


def _fitting_scale(max_mm: float) -> float | None:
    for s in DEPTH_SCALE_LADDER:
        if round(max_mm / s) <= UINT16_MAX:
            return s
    return None


def encode_depth(
    depth_m: np.ndarray, depth_scale: float | Literal["auto"]
) -> tuple[np.ndarray, float]:
    """Depth in metres -> BOP uint16 depth (``value * scale = mm``) and the scale used.

    0 and +inf mean "no surface" and encode as 0; any surface point encodes as >= 1 so it can
    never be confused with background.
    """
    d = np.asarray(depth_m, dtype=np.float64)
    if d.ndim != 2:
        raise ValueError(f"depth must be a HxW array, got shape {d.shape}")
    if np.isnan(d).any():
        raise ValueError("depth contains NaN (renderer bug?); background must be 0 or +inf")
    if (d < 0).any():
        raise ValueError(f"depth contains negative values (min {d.min():.6g} m)")
    valid = np.isfinite(d) & (d > 0)
    mm = np.where(valid, d, 0.0) * 1000.0
    max_mm = float(mm.max()) if mm.size else 0.0

    if depth_scale == "auto":
        scale = _fitting_scale(max_mm)
        if scale is None:
            raise DepthOverflowError(
                f"depth up to {max_mm:.1f} mm exceeds uint16 even at the largest depth_scale "
                f"{DEPTH_SCALE_LADDER[-1]} (max {UINT16_MAX * DEPTH_SCALE_LADDER[-1]:.0f} mm); "
                "reduce the far clip or the camera distance"
            )
    else:
        scale = float(depth_scale)
        if not (math.isfinite(scale) and scale > 0):
            raise ValueError(f"depth_scale must be > 0, got {depth_scale!r}")
        if round(max_mm / scale) > UINT16_MAX:
            suggested = _fitting_scale(max_mm)
            hint = (
                f"use depth_scale: {suggested} (or 'auto')"
                if suggested is not None
                else f"exceeds even depth_scale {DEPTH_SCALE_LADDER[-1]}; reduce the far clip"
            )
            raise DepthOverflowError(
                f"depth up to {max_mm:.1f} mm does not fit uint16 at depth_scale {scale} "
                f"(max {UINT16_MAX * scale:.1f} mm); {hint}"
            )

    q = np.rint(mm / scale)
    q[valid] = np.maximum(q[valid], 1.0)
    return q.astype(np.uint16), scale


def _encode(img: Image.Image, fmt: str, **kw) -> bytes:
    buf = io.BytesIO()
    img.save(buf, format=fmt, **kw)
    return buf.getvalue()


def png_bytes(array: np.ndarray) -> bytes:
    a = np.asarray(array)
    if a.dtype == np.uint16:
        if a.ndim != 2:
            raise ValueError(f"16-bit PNG must be single-channel HxW, got shape {a.shape}")
        img = Image.fromarray(a)  # mode I;16, what BOP depth readers expect
    elif a.dtype == np.uint8:
        if not (a.ndim == 2 or (a.ndim == 3 and a.shape[2] in (3, 4))):
            raise ValueError(f"8-bit PNG must be HxW, HxWx3 or HxWx4, got shape {a.shape}")
        img = Image.fromarray(a)
    else:
        raise ValueError(f"PNG arrays must be uint8 or uint16, got {a.dtype}")
    return _encode(img, "PNG", compress_level=PNG_COMPRESS_LEVEL, optimize=False)


def jpg_bytes(rgb: np.ndarray, quality: int) -> bytes:
    a = np.asarray(rgb)
    if a.dtype != np.uint8 or a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"JPEG needs a uint8 HxWx3 array, got {a.dtype} {a.shape}")
    if not 1 <= int(quality) <= 100:
        raise ValueError(f"jpeg quality must be in [1, 100], got {quality}")
    # Subsampling pinned (4:2:0) so a Pillow default change cannot change dataset bytes.
    return _encode(Image.fromarray(a), "JPEG", quality=int(quality), subsampling=2, optimize=False)


def write_png(path: str | Path, array: np.ndarray) -> None:
    atomic_write_bytes(Path(path), png_bytes(array))


def write_jpg(path: str | Path, rgb: np.ndarray, quality: int = 95) -> None:
    atomic_write_bytes(Path(path), jpg_bytes(rgb, quality))


def write_mask(path: str | Path, mask: np.ndarray) -> None:
    """Binary mask as an 8-bit 0/255 PNG, the BOP mask / mask_visib convention."""
    m = np.asarray(mask)
    if m.ndim != 2:
        raise ValueError(f"mask must be HxW, got shape {m.shape}")
    write_png(path, np.where(m.astype(bool), 255, 0).astype(np.uint8))


def write_exr(path: str | Path, rgb_linear: np.ndarray) -> None:
    """Linear float32 HxWx3 beauty pass as a ZIP-compressed scanline OpenEXR (R, G, B channels)."""
    import OpenEXR  # only render jobs with outputs.exr pay for the import

    a = np.ascontiguousarray(rgb_linear, dtype=np.float32)
    if a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"EXR needs a HxWx3 array, got shape {a.shape}")
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}

    def write(tmp: str) -> None:  # OpenEXR writes by file name only
        with OpenEXR.File(header, {"RGB": a}) as f:
            f.write(tmp)

    atomic_write_via(Path(path), write, ".exr")
