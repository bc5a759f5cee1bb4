"""Seed-locked photometric augmentation of 8-bit sRGB images (BL or PBR alike).

All randomness comes from the generator the caller passes in, so an image job's seed fixes its
augmentation too. The scalar parameters are always drawn, in a fixed order, whether or not the
corresponding augmentation is enabled: turning one augmentation on then leaves the others' draws
(and the caller's later draws) unchanged.

Order of operations follows an imaging pipeline: optical blur, then colour (brightness, contrast,
saturation, hue, all folded into one affine colour transform), then sensor noise.
"""

from __future__ import annotations

import math

import numpy as np
from PIL import Image
from scipy.ndimage import gaussian_filter
from scipy.special import ndtri

from ..spec.models import Augment

# Rec. 601 luma weights: the grey that contrast and saturation pull towards.
_LUMA = np.array([0.299, 0.587, 0.114], dtype=np.float64)
# Standard normal quantiles at the centres of 256 equal-probability bins (a constant table).
_NORMAL_QUANTILES = ndtri((np.arange(256) + 0.5) / 256.0)
_NORMAL_QUANTILES.setflags(write=False)


def is_identity(params: Augment) -> bool:
    return (
        params.brightness == 0
        and params.contrast == 0
        and params.hue == 0
        and params.saturation == 0
        and params.noise_std == 0
        and params.blur_sigma[1] == 0
    )


def _hue_rotation(turns: float) -> np.ndarray:
    """Rotation of RGB about the grey axis: shifts hue, keeps greys grey and the mean intensity."""
    a = 2.0 * math.pi * turns
    c, s = math.cos(a), math.sin(a)
    k = 1.0 / 3.0
    r = math.sqrt(k)
    # Rodrigues' formula for the unit axis (1,1,1)/sqrt(3).
    cross = np.array([[0, -r, r], [r, 0, -r], [-r, r, 0]])
    return c * np.eye(3) + s * cross + (1 - c) * np.full((3, 3), k)


def draw(params: Augment, rng: np.random.Generator) -> dict[str, float]:
    """The per-image scalar parameters; always consumes the same number of draws."""
    u = rng.uniform(-1.0, 1.0, size=4)
    lo, hi = params.blur_sigma
    blur = float(rng.uniform(lo, hi)) if hi > lo else float(lo)
    return {
        "brightness": 1.0 + params.brightness * float(u[0]),
        "contrast": 1.0 + params.contrast * float(u[1]),
        "saturation": 1.0 + params.saturation * float(u[2]),
        "hue": params.hue * float(u[3]),
        "blur_sigma": blur,
        "noise_std": float(params.noise_std),
    }


# einsum without optimisation runs numpy's own loops, never BLAS: BLAS may pick kernels (FMA or
# not) by alignment and thread count, and a last-bit change in M can flip a rounded pixel.
def _mm(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.einsum("ij,jk->ik", a, b)


def _mv(a: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.einsum("ij,j->i", a, v)


def augment(rgb: np.ndarray, params: Augment, rng: np.random.Generator) -> np.ndarray:
    """Augmented copy of an HxWx3 uint8 image (the input itself when ``params`` is all zero)."""
    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"augment expects an HxWx3 uint8 image, got {rgb.dtype} {rgb.shape}")
    p = draw(params, rng)
    if is_identity(params):
        return rgb
    img = rgb

    if p["blur_sigma"] > 0:
        blurred = gaussian_filter(img.astype(np.float32), sigma=(p["blur_sigma"], p["blur_sigma"], 0), mode="reflect", truncate=3.0)
        img = np.clip(np.rint(blurred), 0, 255).astype(np.uint8)

    # Affine colour transform x' = M x + o, composed in float64 (3x3, cheap) and applied once.
    M = np.eye(3) * p["brightness"]
    o = np.zeros(3)
    c = p["contrast"]
    if c != 1.0:
        # Contrast about the image's mean grey after brightness, as image editors do.
        mean_grey = float(np.einsum("i,i->", img.reshape(-1, 3).mean(axis=0), _LUMA)) * p["brightness"]
        M = c * M
        o = c * o + (1 - c) * mean_grey
    s = p["saturation"]
    if s != 1.0:
        S = s * np.eye(3) + (1 - s) * np.outer(np.ones(3), _LUMA)
        M, o = _mm(S, M), _mv(S, o)
    if p["hue"] != 0.0:
        H = _hue_rotation(p["hue"])
        M, o = _mm(H, M), _mv(H, o)
    if not (np.allclose(M, np.eye(3)) and np.allclose(o, 0)):
        # PIL's matrix conversion works on uint8 in C (rounds and clips): ~5x cheaper than float32
        # numpy on a VGA frame, and this runs on every image.
        matrix = tuple(float(x) for row in np.hstack([M, o[:, None]]) for x in row)
        img = np.asarray(Image.fromarray(img).convert("RGB", matrix), dtype=np.uint8)

    if p["noise_std"] > 0:
        # Gaussian noise by inverse-CDF lookup of random bytes: 256 equiprobable normal quantiles,
        # several times cheaper than standard_normal per pixel, and exact enough once the result
        # is rounded to 8-bit levels anyway (std 0.3 % low, tails cut at 2.9 sigma).
        table = np.rint(_NORMAL_QUANTILES * (p["noise_std"] * 255.0)).astype(np.int16)
        out = img.astype(np.int16)
        out += table[rng.integers(0, 256, size=img.shape, dtype=np.uint8)]
        img = np.clip(out, 0, 255).astype(np.uint8)

    return img if img is not rgb else rgb.copy()
