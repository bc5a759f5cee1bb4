"""The ``backend:`` block for Cycles (pydantic only: imported by the compiler, never imports bpy)."""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from specsynth.spec import BackendOptions


class CyclesOptions(BackendOptions):
    name: Literal["cycles"] = "cycles"
    threads: int = Field(0, ge=0, le=1024, description="Render threads; 0 = one per core.")
    adaptive_threshold: float | None = Field(None, gt=0, description="Adaptive sampling noise threshold.")
    light_path_budget: bool = Field(
        True, description="No glossy / transmission bounces when no material in the scene needs them."
    )
