"""Supersampling (``backend.supersample``): an image rendered at ``f`` times its resolution, each
f x f block of pixels averaged in linear radiance. With a box pixel filter of one pixel, as every
backend here renders, the mean of a block is the pixel the camera at its own resolution renders
(``CameraIR.scaled``), so annotations made at that resolution stay exact. What it buys: a denoiser
run on the larger image sees each feature over more pixels and keeps more of it, and averaging
its output takes out what it leaves at the finest scale (docs/quality.md, "Supersampling")."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from .colour import linear_to_srgb8, srgb_to_linear
from .ir import RenderResult


def block_mean(image: np.ndarray, factor: int) -> np.ndarray:
    """HxWxC (or HxW) -> (H/f)x(W/f)x..., the mean of each f x f block, as float32."""
    h, w = image.shape[:2]
    if h % factor or w % factor:
        raise ValueError(f"an image of {w}x{h} is not made of {factor}x{factor} blocks")
    blocks = np.asarray(image, np.float64).reshape(h // factor, factor, w // factor, factor, *image.shape[2:])
    return blocks.mean(axis=(1, 3)).astype(np.float32)


def downsampled(res: RenderResult, factor: int) -> RenderResult:
    """A render at ``factor`` times the image's resolution, brought to it: radiance (and the raw
    radiance and guides beside it) averaged over blocks, then encoded by the sRGB transform every
    backend uses; an 8-bit-only render averaged in linear and encoded again."""
    if factor == 1:
        return res
    linear = block_mean(res.linear if res.linear is not None else srgb_to_linear(res.rgb / 255.0), factor)
    extra = {k: block_mean(getattr(res, k), factor) for k in ("noisy", "guides") if getattr(res, k) is not None}
    return replace(res, rgb=linear_to_srgb8(linear), linear=linear if res.linear is not None else None,
                   stats={**res.stats, "supersample": factor}, **extra)
