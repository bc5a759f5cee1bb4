"""A test backend whose worker process segfaults on one chosen render job."""

from __future__ import annotations

import ctypes
import os
from typing import Literal

import numpy as np

from specsynth.model.ir import RenderResult
from specsynth.plugins import BackendPlugin
from specsynth.spec.models import BackendOptions


class CrashyOptions(BackendOptions):
    name: Literal["crashy_backend:PLUGIN"] = "crashy_backend:PLUGIN"
    crash_seed: int = -1


class CrashyBackend:
    name = "crashy"

    def __init__(self, options, *, threads: int = 0):
        self.crash_seed = CrashyOptions.model_validate(dict(options)).crash_seed

    def version(self) -> str:
        return "crashy-1"

    def load(self, scene) -> None:
        self.n = len(scene.meshes)

    def render(self, camera, quality, seed, *, clamp=None) -> RenderResult:
        if seed == self.crash_seed:
            if os.environ.get("CRASHY_IN_PROCESS") == "1":
                raise RuntimeError("simulated renderer failure")
            ctypes.string_at(0)  # a real segfault, as a renderer bug would give
        v = (seed % 200) + 20
        return RenderResult(rgb=np.full((camera.height, camera.width, 3), v, dtype=np.uint8))

    def close(self) -> None:
        pass


PLUGIN = BackendPlugin(name="crashy_backend:PLUGIN", options=CrashyOptions, backend="crashy_backend:CrashyBackend")
