"""The ``backend:`` block for Mitsuba 3 (pydantic only: never imports Mitsuba)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from specsynth.spec.models import BackendOptions


class MitsubaOptions(BackendOptions):
    name: Literal["mitsuba"] = "mitsuba"
    variant: Literal["auto", "llvm_ad_rgb", "scalar_rgb", "cuda_ad_rgb"] = "auto"
    sampler: Literal["independent", "ldsampler", "stratified", "multijitter", "orthogonal"] = Field(
        "stratified",
        description="Mitsuba sampler. stratified (jittered, needs a perfect square: the presets' 1/36/225 are) "
        "measured 3.4 dB less noise than independent at 225 spp for the same cost; ldsampler rounds up to 4^k, "
        "multijitter to a grid of isqrt(n) rows, orthogonal to the square of a prime (docs/backends/mitsuba.md).",
    )
    denoise_prefilter: Literal["none", "fast"] = Field(
        "none", description="How OpenImageDenoise treats the guides (albedo and normals from a pass of their own with "
        "the image's seed and 16x its samples, at most 64): 'none' takes them as clean, which they nearly are; 'fast' "
        "(OIDN's cleanAux off, as Cycles' 'fast') lets the filter denoise them with the image, 0.5 dB worse at 1 spp "
        "(docs/backends/mitsuba.md). Cycles' 'accurate' (separate guide passes) is not offered.",
    )
    emitter_sampling: Literal["uniform", "power"] = Field(
        "uniform",
        description="How a shadow ray picks the emitter it aims at: 'uniform' (Mitsuba's own: every emitter alike) or "
        "'power' (lamps and glowing surfaces by the power they emit, within the share uniform choice gives them; the "
        "environment and the sun keep theirs). Both are unbiased. 'power' took about a third off the error of 16 spp + "
        "OIDN on the demo's desks; the calibrated levels use it, the paper presets and error targets Mitsuba's own "
        "(docs/backends/mitsuba.md).",
    )
    match_cycles_bsdf: bool = Field(
        True,
        description="Calibrate Mitsuba's principled BSDF to Blender's per-bounce albedo (dielectrics), so the "
        "two backends render the same scene alike; false = Mitsuba's own principled.",
    )
