"""The one linear -> display transform shared by every backend, so images are comparable."""

from __future__ import annotations

import math

import numpy as np

REC709_LUMA = np.array([0.2126, 0.7152, 0.0722])  # luminance of linear Rec.709 / sRGB primaries


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


def kelvin_rgb(kelvin: float) -> tuple[float, float, float]:
    """Approximate linear RGB of a black body (normalised so the brightest channel is 1); good
    enough for light colour jitter between 2700 K (warm bulbs) and 6500 K (daylight)."""
    t = kelvin / 100.0
    r = 1.0 if t <= 66 else min(1.0, 1.292936186 * (t - 60) ** -0.1332047592)
    g = (0.390081578 * math.log(t) - 0.631841443) if t <= 66 else 1.129890861 * (t - 60) ** -0.0755148492
    b = 1.0 if t >= 66 else (0.0 if t <= 19 else 0.543206789 * math.log(t - 10) - 1.196254089)
    rgb = np.clip(np.array([r, g, b]), 0.0, 1.0) ** 2.2  # the fit is in sRGB-ish units
    return tuple(float(c) for c in rgb / rgb.max())
