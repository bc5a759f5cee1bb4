"""Every installed render backend against specsynth.testing.conformance.

One test per (backend, check); the backend instance is shared per module because PBR backends
take seconds to start. Every backend with an entry point is tested: one that is installed but
cannot be imported fails (PluginNotFound says what to reinstall); the path tracers are marked slow.
"""

from __future__ import annotations

import pytest

from specsynth.backend_api import available_backends, load_backend
from specsynth.testing.conformance import CHECKS, ConformanceContext, NotDeclared, not_applicable

SLOW_BACKENDS = {"cycles", "mitsuba"}
# Options for the conformance run, where a backend's defaults are not what the suite wants.
OPTIONS: dict[str, dict] = {}


def _params():
    for name in available_backends():
        marks = [pytest.mark.slow] if name in SLOW_BACKENDS else []
        yield pytest.param(name, id=name, marks=marks)


@pytest.fixture(scope="module", params=list(_params()))
def ctx(request, tmp_path_factory):
    name = request.param
    load_backend(name)  # installed (it has an entry point): it must load, not be skipped
    context = ConformanceContext(name, OPTIONS.get(name, {"name": name}), tmp_path_factory.mktemp(f"conf_{name}"))
    yield context
    context.close()


@pytest.mark.parametrize("check", list(CHECKS))
def test_conformance(ctx, check):
    """Checks of a capability the backend does not declare are reported as skipped with the reason,
    never as passes; every other check raises ConformanceError on a failure."""
    reason = not_applicable(ctx, check)
    if reason is not None:
        with pytest.raises(NotDeclared):  # a check that does not apply must not pass silently
            CHECKS[check](ctx)
        pytest.skip(reason)
    CHECKS[check](ctx)


# --------------------------------------------------------------------------- the suite catches bugs
# Deliberately broken variants of the photo backend: each must fail the check aimed at its bug.


def _broken_variants():
    from specsynth.model.ir import RenderResult
    from specsynth_photo.backend import PhotoBackend

    class UpsideDown(PhotoBackend):  # image rows in OpenGL order
        def render(self, camera, quality, seed, *, clamp=None):
            r = super().render(camera, quality, seed, clamp=clamp)
            return RenderResult(rgb=r.rgb[::-1].copy(), stats=r.stats)

    class Leaky(PhotoBackend):  # load() adds to the previous scene instead of replacing it
        def load(self, scene):
            from specsynth.model.ir import RenderScene

            prev = getattr(self, "_seen", ())
            self._seen = tuple({m.name: m for m in prev + scene.meshes}.values())
            super().load(RenderScene(meshes=self._seen))

    class Unseeded(PhotoBackend):  # randomness that does not come from the seed
        def render(self, camera, quality, seed, *, clamp=None):
            self._calls = getattr(self, "_calls", 0) + 1
            return super().render(camera, quality, seed + self._calls, clamp=clamp)

    class WrongShape(PhotoBackend):
        def render(self, camera, quality, seed, *, clamp=None):
            r = super().render(camera, quality, seed, clamp=clamp)
            return RenderResult(rgb=r.rgb[:, :-1].copy(), stats=r.stats)

    return [
        pytest.param(PhotoBackend, "depth_of_field", id="claims-depth-of-field"),  # declared, but a pinhole
        pytest.param(PhotoBackend, "motion_blur", id="claims-motion-blur"),  # declared, but a still camera
        pytest.param(UpsideDown, "silhouettes", id="upside-down"),
        pytest.param(Leaky, "reload", id="leaky-load"),
        pytest.param(Unseeded, "determinism", id="unseeded"),
        pytest.param(WrongShape, "render_shape", id="wrong-shape"),
        pytest.param(WrongShape, "discovery", id="not-the-registered-class"),
    ]


@pytest.fixture(scope="module")
def photo_available():
    assert load_backend("photo").__name__ == "PhotoBackend"


def _broken_params():
    return _broken_variants()  # the photo backend is part of this repository: an ImportError is a failure


@pytest.mark.parametrize("cls, check", _broken_params())
def test_suite_catches_broken_backend(photo_available, tmp_path, cls, check):
    from specsynth.testing.conformance import ConformanceError

    from dataclasses import replace

    from specsynth.plugins import backend_plugin

    claims = replace(backend_plugin("photo").capabilities, depth_of_field=True, motion_blur=True)
    context = ConformanceContext("photo", {"name": "photo"}, tmp_path, backend_class=cls, capabilities=claims)
    try:
        with pytest.raises(ConformanceError):
            CHECKS[check](context)
    finally:
        context.close()
