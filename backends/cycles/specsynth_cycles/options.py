"""The ``backend:`` block for Cycles (pydantic only: imported by the compiler, never imports bpy)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from specsynth.spec.models import BackendOptions


class CyclesOptions(BackendOptions):
    name: Literal["cycles"] = "cycles"
    threads: int = Field(0, ge=0, le=1024, description="Render threads; 0 = one per core.")
    device: Literal["cpu", "auto", "cuda", "optix", "hip", "oneapi"] = Field(
        "cpu", description="Where Cycles traces (and OIDN denoises): 'cpu'; a GPU kind, an error if Blender finds "
        "none; or 'auto': OptiX, else CUDA, else HIP, else oneAPI, else the CPU. A GPU's pixels differ from the "
        "CPU's in the last bits, so 'cpu' (the default) keeps builds identical across machines.",
    )
    adaptive_threshold: float | None = Field(None, gt=0, description="Adaptive sampling noise threshold.")
    guiding: bool = Field(
        False, description="Path guiding (Open PGL, CPU only): learns where light comes from while rendering and "
        "sends paths there; deterministic, so a build stays reproducible. Measured in docs/backends/cycles.md.",
    )
    denoise_prefilter: Literal["none", "fast", "accurate"] = Field(
        "none", description="OIDN's treatment of the albedo/normal guides. Measured (docs/backends/cycles.md): "
        "'accurate' (Blender's default) gives the same error as 'none' (35.09 vs 35.08 dB at medium) for 1.45 s "
        "instead of 0.55 s of denoising per VGA image on 2 cores; 'fast' costs 0.29 s and 0.4 dB.",
    )
    persistent: bool = Field(
        True, description="Keep the synced scene (BVH, textures) between renders of one arrangement while no "
        "setting changes (Blender's persistent data; any change of settings re-syncs in full).",
    )
    light_path_budget: bool = Field(
        True, description="No glossy / transmission bounces when no material in the scene needs them."
    )
