"""A test backend whose worker process segfaults on one chosen render job."""

from __future__ import annotations

import ctypes
import os

import numpy as np

from specsynth.ir import RenderResult


class CrashyBackend:
    name = "crashy"
    draws_scene = True

    def __init__(self, options, *, threads: int = 0):
        opts = options.options if hasattr(options, "options") else dict(options.get("options", {}))
        self.crash_seed = int(opts.get("crash_seed", -1))

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
