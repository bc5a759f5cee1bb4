"""A test backend whose worker process segfaults on one chosen render job.

``crash_times``: how many of that job's renders crash (-1: every one). With ``CRASHY_LOG`` set,
every render of that job first appends the pid of its process to that file, so a test can count
how often the job ran, and in how many processes.
"""

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
    crash_times: int = -1


class CrashyBackend:
    name = "crashy"

    def __init__(self, options, *, threads: int = 0):
        opts = CrashyOptions.model_validate(dict(options))
        self.crash_seed, self.crash_times = opts.crash_seed, opts.crash_times

    def version(self) -> str:
        return "crashy-1"

    def load(self, scene) -> None:
        self.n = len(scene.meshes)

    def render(self, camera, quality, seed, *, clamp=None) -> RenderResult:
        if seed == self.crash_seed:
            runs = 0
            if os.environ.get("CRASHY_LOG"):
                with open(os.environ["CRASHY_LOG"], "a+") as log:
                    log.write(f"{os.getpid()}\n")
                    log.seek(0)
                    runs = len(log.read().split())
            if 0 <= self.crash_times < runs:  # this job has crashed often enough: render it
                return RenderResult(rgb=np.full((camera.height, camera.width, 3), 7, dtype=np.uint8))
            if os.environ.get("CRASHY_IN_PROCESS") == "1":
                raise RuntimeError("simulated renderer failure")
            ctypes.string_at(0)  # a real segfault, as a renderer bug would give
        v = (seed % 200) + 20
        return RenderResult(rgb=np.full((camera.height, camera.width, 3), v, dtype=np.uint8))

    def close(self) -> None:
        pass


PLUGIN = BackendPlugin(name="crashy_backend:PLUGIN", options=CrashyOptions, backend="crashy_backend:CrashyBackend")
