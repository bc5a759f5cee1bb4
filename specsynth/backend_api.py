"""What a render backend is, and how the core finds one by name.

Backends are plugins in the ``specsynth.backends`` entry-point group (see ``plugins.py``): the
core never imports a renderer. A backend class is constructed once per worker process (the expensive
``import bpy`` / ``mi.set_variant`` happen there) and then used as:

    backend = BackendClass(options, threads=n)   # options: the spec's ``backend`` block
    backend.load(scene)                           # once per arrangement
    for cam in cameras: backend.render(cam, quality, seed)   # only the camera moves
    backend.close()

Every backend must pass ``specsynth.testing.conformance``: its own tests subclass the base classes of
``specsynth.testing.suite`` (docs/plugins.md).
"""

from __future__ import annotations

from typing import Any, ClassVar, Protocol, runtime_checkable

from .model.ir import CameraIR, RenderResult, RenderScene
from .plugins import (  # the discovery half of the plugin API, re-exported
    BackendPlugin,
    Capabilities,
    PluginNotFound,
    available_backends,
    backend_plugin,
    load_backend,
    load_executor,
)

__all__ = ["RenderBackend", "BackendPlugin", "Capabilities", "PluginNotFound", "available_backends",
           "backend_plugin", "load_backend", "load_executor", "render_takes"]
from .spec.models import QualityPreset


@runtime_checkable
class RenderBackend(Protocol):
    name: ClassVar[str]

    def __init__(self, options: Any, *, threads: int = 0) -> None: ...

    def version(self) -> str:
        """Renderer name and version; part of every render job's content key."""

    def load(self, scene: RenderScene) -> None:
        """Build the renderer's scene; called once per arrangement."""

    def render(self, camera: CameraIR, quality: QualityPreset, seed: int, *, clamp: float | None = None) -> RenderResult:
        """Render one view. Same inputs and seed -> identical pixels on the same machine. A backend
        whose plugin declares ``Capabilities.continues_samples`` also takes ``sample_offset=k``:
        the samples k to k + n of the sequence that ``seed`` starts (0, the default: a render)."""

    def close(self) -> None: ...

    # Optional: a backend that denoises and returns its denoiser's guides (RenderResult.guides) may
    # also offer ``denoise(linear, guides) -> linear``, which denoises an image as a render of its
    # own would be: under ``quality.control: error`` the core then denoises the samples of all of an
    # image's renders together (specsynth.model.error) instead of the last pair alone, and asks
    # each render for ``render(..., skip_denoiser=True)``: the render before its denoiser (as
    # ``linear`` and ``noisy``) with its guides, the denoiser not run (a ``render`` that does not
    # take the keyword, written before it was added, is not given it: ``render_takes``).


def render_takes(backend: Any, keyword: str) -> bool:
    """The backend's ``render`` takes the optional keyword ``keyword`` (``sample_offset``,
    ``skip_denoiser``): a backend written before it was added is not given it."""
    import inspect

    params = inspect.signature(backend.render).parameters
    return keyword in params or any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values())
