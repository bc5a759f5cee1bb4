"""Every installed render backend against specsynth.testing.conformance.

One test per (backend, check); the backend instance is shared per module because PBR backends
take seconds to start. Backends that cannot be imported here are skipped with the PluginNotFound
message (which says what to install); the path tracers are marked slow.
"""

from __future__ import annotations

import pytest

from specsynth.backend_api import PluginNotFound, available_backends, load_backend
from specsynth.testing.conformance import CHECKS, ConformanceContext

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
    try:
        load_backend(name)
    except PluginNotFound as e:
        pytest.skip(str(e))
    context = ConformanceContext(name, OPTIONS.get(name, {"name": name}), tmp_path_factory.mktemp(f"conf_{name}"))
    yield context
    context.close()


@pytest.mark.parametrize("check", list(CHECKS))
def test_conformance(ctx, check):
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
        pytest.param(UpsideDown, "silhouettes", id="upside-down"),
        pytest.param(Leaky, "reload", id="leaky-load"),
        pytest.param(Unseeded, "determinism", id="unseeded"),
        pytest.param(WrongShape, "render_shape", id="wrong-shape"),
        pytest.param(WrongShape, "discovery", id="not-the-registered-class"),
    ]


@pytest.fixture(scope="module")
def photo_available():
    try:
        load_backend("photo")
    except PluginNotFound as e:
        pytest.skip(str(e))


def _broken_params():
    try:
        return _broken_variants()
    except ImportError:  # photo backend not installed: the photo_available fixture reports why
        return []


@pytest.mark.parametrize("cls, check", _broken_params())
def test_suite_catches_broken_backend(photo_available, tmp_path, cls, check):
    from specsynth.testing.conformance import ConformanceError

    context = ConformanceContext("photo", {"name": "photo"}, tmp_path, backend_class=cls)
    try:
        with pytest.raises(ConformanceError):
            CHECKS[check](context)
    finally:
        context.close()
