"""The one linear -> display transform shared by every backend, so images are comparable."""

from __future__ import annotations

import numpy as np


class NonFiniteRender(RuntimeError):
    pass


def check_finite(linear: np.ndarray, what: str) -> None:
    bad = ~np.isfinite(linear)
    if bad.any():
        n = int(bad.any(axis=-1).sum()) if linear.ndim == 3 else int(bad.sum())
        raise NonFiniteRender(f"{what}: {n} pixel(s) are NaN or Inf")


def linear_to_srgb(linear: np.ndarray) -> np.ndarray:
    """IEC 61966-2-1 sRGB encoding of linear values, clipped to [0, 1] first (Blender 'Standard')."""
    x = np.clip(np.asarray(linear, dtype=np.float32), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055).astype(np.float32)


def srgb_to_linear(srgb: np.ndarray) -> np.ndarray:
    x = np.clip(np.asarray(srgb, dtype=np.float32), 0.0, 1.0)
    return np.where(x <= 0.04045, x / 12.92, np.power((x + 0.055) / 1.055, 2.4)).astype(np.float32)


def linear_to_srgb8(linear: np.ndarray) -> np.ndarray:
    return np.round(linear_to_srgb(linear) * 255.0).astype(np.uint8)
