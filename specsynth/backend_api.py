"""What a render backend is, and how the core finds one by name.

Backends are plugins in the ``specsynth.backends`` entry-point group (fsspec-style): the core
never imports a renderer. A backend class is constructed once per worker process (the expensive
``import bpy`` / ``mi.set_variant`` happen there) and then used as:

    backend = BackendClass(options, threads=n)   # options: the spec's ``backend`` block
    backend.load(scene)                           # once per arrangement
    for cam in cameras: backend.render(cam, quality, seed)   # only the camera moves
    backend.close()

Every backend must pass ``specsynth.testing.conformance`` (see tests/test_backend_conformance.py).
"""

from __future__ import annotations

from importlib import metadata
from typing import Any, ClassVar, Protocol, runtime_checkable

from .ir import CameraIR, RenderResult, RenderScene
from .spec import QualityPreset

BACKEND_GROUP = "specsynth.backends"
EXECUTOR_GROUP = "specsynth.executors"

# What each known plugin needs installed, for a friendly error.
INSTALL_HINTS = {
    "cycles": "pip install 'specsynth[cycles]'  (the bpy==5.0.1 wheel)",
    "mitsuba": "pip install 'specsynth[mitsuba]'  and, for the LLVM variant, apt-get install libllvm19",
    "photo": "pip install 'specsynth[photo]'  and apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri",
    "dask": "pip install 'specsynth[dask]'",
}


class PluginNotFound(RuntimeError):
    pass


@runtime_checkable
class RenderBackend(Protocol):
    name: ClassVar[str]
    # False for backends that draw only the dataset objects (the photo baseline): the annotation
    # engine then uses the objects alone as occluders so annotations describe what the image shows.
    draws_scene: ClassVar[bool]

    def __init__(self, options: Any, *, threads: int = 0) -> None: ...

    def version(self) -> str:
        """Renderer name and version; part of every render job's content key."""

    def load(self, scene: RenderScene) -> None:
        """Build the renderer's scene; called once per arrangement."""

    def render(self, camera: CameraIR, quality: QualityPreset, seed: int, *, clamp: float | None = None) -> RenderResult:
        """Render one view. Same inputs and seed -> identical pixels on the same machine."""

    def close(self) -> None: ...


def _load(group: str, name: str):
    if ":" in name:
        # "package.module:Class": a plugin used without installing it (tests, experiments).
        import importlib

        mod, _, attr = name.partition(":")
        try:
            return getattr(importlib.import_module(mod), attr)
        except (ImportError, AttributeError) as e:
            raise PluginNotFound(f"cannot load {name!r}: {e}") from e
    eps = metadata.entry_points(group=group)
    matches = [ep for ep in eps if ep.name == name]
    if not matches:
        known = sorted(ep.name for ep in eps)
        hint = INSTALL_HINTS.get(name)
        msg = f"no {group.split('.')[-1][:-1]} named {name!r} is installed (installed: {', '.join(known) or 'none'})"
        raise PluginNotFound(msg + (f"; install it with: {hint}" if hint else ""))
    try:
        return matches[0].load()
    except ImportError as e:
        hint = INSTALL_HINTS.get(name, f"install the package that provides {name!r}")
        raise PluginNotFound(f"{group.split('.')[-1][:-1]} {name!r} cannot be imported ({e}); {hint}") from e


def load_backend(name: str) -> type:
    return _load(BACKEND_GROUP, name)


def load_executor(name: str) -> type:
    return _load(EXECUTOR_GROUP, name)


def available_backends() -> list[str]:
    return sorted(ep.name for ep in metadata.entry_points(group=BACKEND_GROUP))
