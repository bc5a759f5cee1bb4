"""Base test classes a backend's own tests subclass (like fsspec's abstract tests and dbt's adapter
test classes): the conformance suite, and the PBR material channels, as pytest tests.

In the backend's tests folder (pytest finds classes named ``Test*``)::

    from specsynth.testing.conformance import check_seed_matters
    from specsynth.testing.suite import BackendConformanceTests

    class TestMineConformance(BackendConformanceTests):
        backend = "mine"                  # the entry point's name: found and loaded as the core does
        options = {"name": "mine", "samples": 4}    # when its defaults do not suit the suite

        def test_seed_matters(self, conformance):        # a check of its own
            check_seed_matters(conformance)

One backend instance serves every test of the class (``conformance``, a ``ConformanceContext``).
A check of a capability or material channel the backend does not declare is reported as skipped
with the reason, never as a pass. Mark the class ``pytestmark = pytest.mark.slow`` when its
renders take seconds. Needs pytest (``specsynth[test]``); ``specsynth.testing.conformance`` alone
does not.
"""

from __future__ import annotations

from typing import Any, ClassVar

import pytest

from ..plugins import load_backend
from . import materials
from .conformance import CHECKS, ConformanceContext, NotDeclared, not_applicable


class BackendTestBase:
    """The backend under test and its ``conformance`` context, one per test class."""

    backend: ClassVar[str] = ""  # the backend's entry-point name
    options: ClassVar[dict[str, Any] | None] = None  # the spec's backend block; {"name": backend} when None
    threads: ClassVar[int] = 1

    @pytest.fixture(scope="class")
    def conformance(self, request, tmp_path_factory):
        cls = request.cls
        if not cls.backend:
            pytest.fail(f"{cls.__name__} does not say which backend it tests (set backend = '<entry-point name>')")
        load_backend(cls.backend)  # installed (its tests run): it must load, not be skipped
        ctx = ConformanceContext(cls.backend, cls.options, tmp_path_factory.mktemp(f"conformance_{cls.backend}"),
                                 threads=cls.threads)
        yield ctx
        ctx.close()


def run_check(ctx: ConformanceContext, name: str) -> None:
    """Run conformance check ``name``; one that does not apply must say so (NotDeclared), and is skipped."""
    reason = not_applicable(ctx, name)
    if reason is not None:
        with pytest.raises(NotDeclared):  # a check that does not apply must not pass silently
            CHECKS[name](ctx)
        pytest.skip(reason)
    CHECKS[name](ctx)


class BackendConformanceTests(BackendTestBase):
    """Every check of ``specsynth.testing.conformance.CHECKS``, one test each; they raise
    ConformanceError, which names the backend and what it got wrong."""

    def test_discovery(self, conformance):
        run_check(conformance, "discovery")

    def test_version(self, conformance):
        run_check(conformance, "version")

    def test_render_shape(self, conformance):
        run_check(conformance, "render_shape")

    def test_determinism(self, conformance):
        run_check(conformance, "determinism")

    def test_fresh_process_determinism(self, conformance):
        run_check(conformance, "fresh_process_determinism")

    def test_camera_moves(self, conformance):
        run_check(conformance, "camera_moves")

    def test_silhouettes(self, conformance):
        run_check(conformance, "silhouettes")

    def test_reload(self, conformance):
        run_check(conformance, "reload")

    def test_window(self, conformance):
        run_check(conformance, "window")

    def test_depth_of_field(self, conformance):
        run_check(conformance, "depth_of_field")

    def test_motion_blur(self, conformance):
        run_check(conformance, "motion_blur")

    def test_denoiser_guides(self, conformance):
        run_check(conformance, "denoiser_guides")

    def test_sample_continuation(self, conformance):
        run_check(conformance, "sample_continuation")


def _declared(ctx: ConformanceContext, channel: str) -> None:
    if channel not in ctx.plugin.capabilities.material_channels:
        pytest.skip(f"{ctx.name} does not declare the material channel {channel!r}")


class MaterialChannelTests(BackendTestBase):
    """Each PBR material map the backend declares (``Capabilities.material_channels``), rendered
    for real (``specsynth.testing.materials``): for backends that shade, not for rasterisers."""

    @pytest.mark.parametrize("axis", [0, 1])  # 0: red = +u = +x; 1: green = +v = +y (OpenGL maps)
    def test_normal_map_turns_the_surface_towards_its_vectors(self, conformance, axis):
        _declared(conformance, "normal")
        materials.check_normal_map(conformance, axis)

    def test_roughness_map_sharpens_a_highlight(self, conformance):
        _declared(conformance, "roughness")
        materials.check_roughness_map(conformance)

    def test_emission_map_lights_the_floor(self, conformance):
        _declared(conformance, "emission")
        materials.check_emission_map(conformance)

    def test_opacity_map_cuts_holes_in_the_image_and_the_labels(self, conformance):
        _declared(conformance, "opacity")
        materials.check_opacity_map(conformance)
