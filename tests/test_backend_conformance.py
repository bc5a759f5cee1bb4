"""The conformance suite itself (specsynth.testing.conformance and the base classes of
specsynth.testing.suite), on the example plugin ``flat``: it passes, and deliberately broken
variants of it each fail the check aimed at their bug. Each built-in backend runs the suite in its
own tests (backends/<name>/tests), by subclassing the same base classes.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from specsynth.model.ir import RenderResult, RenderScene
from specsynth.plugins import backend_plugin, load_backend
from specsynth.testing.conformance import CHECKS, ConformanceContext, ConformanceError
from specsynth.testing.suite import BackendConformanceTests


class TestFlatConformance(BackendConformanceTests):
    """flat draws unlit base colours through a pinhole: the thin-lens and motion-blur tests are
    skipped with the reason (and a rasteriser has no PBR maps: no MaterialChannelTests)."""

    backend = "flat"


def test_the_base_class_runs_every_check():
    tests = {name.removeprefix("test_") for name in vars(BackendConformanceTests) if name.startswith("test_")}
    assert tests == set(CHECKS)


# --------------------------------------------------------------------------- the suite catches bugs
# Deliberately broken variants of the flat backend: each must fail the check aimed at its bug.


def _broken_variants():
    flat = load_backend("flat")  # the example plugin (make install installs it): an ImportError is a failure

    class UpsideDown(flat):  # image rows in OpenGL order
        def render(self, camera, quality, seed, *, clamp=None):
            r = super().render(camera, quality, seed, clamp=clamp)
            return RenderResult(rgb=r.rgb[::-1].copy(), stats=r.stats)

    class Leaky(flat):  # load() adds to the previous scene instead of replacing it
        def load(self, scene):
            prev = getattr(self, "_seen", ())
            self._seen = tuple({m.name: m for m in prev + scene.meshes}.values())
            super().load(RenderScene(meshes=self._seen))

    class Unseeded(flat):  # noise from a generator made once per backend, not from each render's seed
        def render(self, camera, quality, seed, *, clamp=None):
            r = super().render(camera, quality, seed, clamp=clamp)
            self._rng = getattr(self, "_rng", None) or np.random.default_rng(0)
            noise = self._rng.integers(0, 8, r.rgb.shape, dtype=np.uint8)
            return RenderResult(rgb=np.maximum(r.rgb, 8) - noise, stats=r.stats)

    class CentredPrincipalPoint(flat):  # the principal point at the image's centre, whatever K says
        def render(self, camera, quality, seed, *, clamp=None):
            K = np.array(camera.K)
            K[0, 2], K[1, 2] = (camera.width - 1) / 2, (camera.height - 1) / 2
            return super().render(replace(camera, K=tuple(map(tuple, K))), quality, seed, clamp=clamp)

    class WrongShape(flat):
        def render(self, camera, quality, seed, *, clamp=None):
            r = super().render(camera, quality, seed, clamp=clamp)
            return RenderResult(rgb=r.rgb[:, :-1].copy(), stats=r.stats)

    class GuidesWithoutDenoise(flat):  # hands the core denoiser guides it cannot use
        def render(self, camera, quality, seed, *, clamp=None):
            r = super().render(camera, quality, seed, clamp=clamp)
            lin = r.rgb.astype(np.float32) / 255
            return RenderResult(rgb=r.rgb, linear=lin, stats=r.stats, noisy=lin,
                                guides=np.concatenate([lin, np.zeros_like(lin)], axis=-1))

    class NegativeDenoise(GuidesWithoutDenoise):
        def denoise(self, linear, guides):
            return linear - 1.0

    return [
        pytest.param(GuidesWithoutDenoise, "render_shape", id="guides-without-denoise"),
        pytest.param(NegativeDenoise, "render_shape", id="negative-denoise"),
        pytest.param(flat, "depth_of_field", id="claims-depth-of-field"),  # declared, but a pinhole
        pytest.param(flat, "motion_blur", id="claims-motion-blur"),  # declared, but a still camera
        pytest.param(UpsideDown, "silhouettes", id="upside-down"),
        pytest.param(Leaky, "reload", id="leaky-load"),
        pytest.param(CentredPrincipalPoint, "window", id="centred-principal-point"),
        pytest.param(Unseeded, "determinism", id="unseeded"),
        pytest.param(WrongShape, "render_shape", id="wrong-shape"),
        pytest.param(WrongShape, "discovery", id="not-the-registered-class"),
    ]


@pytest.mark.parametrize("cls, check", _broken_variants())
def test_suite_catches_broken_backend(tmp_path, cls, check):
    claims = replace(backend_plugin("flat").capabilities, depth_of_field=True, motion_blur=True)
    context = ConformanceContext("flat", {"name": "flat"}, tmp_path, backend_class=cls, capabilities=claims)
    try:
        with pytest.raises(ConformanceError):
            CHECKS[check](context)
    finally:
        context.close()


def test_a_backend_with_guides_and_its_denoise_passes(tmp_path):
    flat = load_backend("flat")

    class Guided(flat):
        def render(self, camera, quality, seed, *, clamp=None):
            r = super().render(camera, quality, seed, clamp=clamp)
            lin = r.rgb.astype(np.float32) / 255
            return RenderResult(rgb=r.rgb, linear=lin, stats=r.stats, noisy=lin,
                                guides=np.concatenate([lin, np.zeros_like(lin)], axis=-1))

        def denoise(self, linear, guides):
            return np.clip(linear, 0, None)

    context = ConformanceContext("flat", {"name": "flat"}, tmp_path, backend_class=Guided)
    try:
        CHECKS["render_shape"](context)
    finally:
        context.close()


def _denoising_variants():
    flat = load_backend("flat")
    from scipy.ndimage import uniform_filter

    class Denoising(flat):  # seeded noise, guides, a 3 x 3 box filter as its denoiser
        def render(self, camera, quality, seed, *, clamp=None, skip_denoiser=False):
            r = super().render(camera, quality, seed, clamp=clamp)
            clean = r.rgb.astype(np.float32) / 255
            noisy = np.clip(clean + np.random.default_rng(seed).normal(0.0, 0.05, clean.shape), 0, None).astype(np.float32)
            guides = np.concatenate([clean, np.zeros_like(clean)], axis=-1)
            linear = noisy if skip_denoiser else self.denoise(noisy, guides)
            return RenderResult(rgb=r.rgb, linear=linear, stats=r.stats, noisy=noisy, guides=guides)

        def denoise(self, linear, guides):
            return uniform_filter(linear, size=(3, 3, 1), mode="nearest")

    class DenoisesAnyway(Denoising):  # skip_denoiser taken, but the image denoised all the same
        def render(self, camera, quality, seed, *, clamp=None, skip_denoiser=False):
            return super().render(camera, quality, seed, clamp=clamp)

    return Denoising, DenoisesAnyway


def _check_variant(tmp_path, cls, check: str, passes: bool, match: str | None = None, **claims) -> None:
    """Run one check on a flat variant that claims ``claims``: it passes, or fails with ``match``."""
    caps = replace(backend_plugin("flat").capabilities, **claims)
    context = ConformanceContext("flat", {"name": "flat"}, tmp_path, backend_class=cls, capabilities=caps)
    try:
        if passes:
            CHECKS[check](context)
        else:
            with pytest.raises(ConformanceError, match=match):
                CHECKS[check](context)
    finally:
        context.close()


@pytest.mark.parametrize("variant, passes", [(0, True), (1, False)], ids=["skips-its-denoiser", "denoises-anyway"])
def test_a_render_that_skips_its_denoiser_is_checked(tmp_path, variant, passes):
    _check_variant(tmp_path, _denoising_variants()[variant], "denoiser_guides", passes, "skip_denoiser", denoise=True)


def _continuing_variants():
    flat = load_backend("flat")

    class Continuing(flat):  # per-sample noise from the seed and the sample's index: ranges continue
        def render(self, camera, quality, seed, *, clamp=None, sample_offset=0):
            r = super().render(camera, quality, seed, clamp=clamp)
            lin = r.rgb.astype(np.float64) / 255
            noise = np.mean([self.sample(seed, k, lin.shape) for k in range(sample_offset, sample_offset + quality.aa)], axis=0)
            return RenderResult(rgb=r.rgb, linear=(lin + noise).astype(np.float32), stats=r.stats)

        def sample(self, seed, k, shape):
            return np.random.default_rng((seed, k)).normal(0.0, 0.05, shape)

    class IgnoresTheOffset(Continuing):
        def render(self, camera, quality, seed, *, clamp=None, sample_offset=0):
            return super().render(camera, quality, seed, clamp=clamp)

    class RestartsEachRange(Continuing):  # a new sequence per offset: the ranges are not one render
        def render(self, camera, quality, seed, *, clamp=None, sample_offset=0):
            return super().render(camera, quality, seed + sample_offset, clamp=clamp)

    return Continuing, IgnoresTheOffset, RestartsEachRange


@pytest.mark.parametrize("variant, passes", [(0, True), (1, False), (2, False)],
                         ids=["continues", "ignores-the-offset", "restarts-each-range"])
def test_sample_continuation_is_checked(tmp_path, variant, passes):
    _check_variant(tmp_path, _continuing_variants()[variant], "sample_continuation", passes, continues_samples=True)


# --------------------------------------------------------------------------- the slow mark tells the truth
# A backend whose renderer draws nothing, loaded by "module:attribute" (not installed), declared slow.

SLOW_PLUGIN = """
from specsynth.plugins import BackendPlugin
from specsynth.spec.models import BackendOptions

PLUGIN = BackendPlugin(name="sleepy", options=BackendOptions, backend="sleepy_renderer:Renderer")
"""
SLOW_RENDERER = """
class Renderer:
    def render(self, camera=None, quality=None, seed=0):
        return None
"""
GUARDED = """
import pytest
from sleepy_renderer import Renderer


def test_renders_unmarked():
    Renderer().render()


@pytest.mark.slow
def test_renders_marked():
    Renderer().render()


def test_renders_nothing():
    Renderer()
"""


def test_a_test_that_renders_with_a_slow_backend_without_the_mark_fails(tmp_path):
    """specsynth.testing.pytest_plugin, told that a backend is slow (the repository tells it cycles
    and mitsuba): the unmarked test that renders with it fails, the marked one passes."""
    import subprocess
    import sys

    for name, text in (("sleepy_plugin.py", SLOW_PLUGIN), ("sleepy_renderer.py", SLOW_RENDERER), ("test_guarded.py", GUARDED)):
        (tmp_path / name).write_text(text)
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "specsynth.testing.pytest_plugin",
                        "-o", "specsynth_slow_backends=sleepy_plugin:PLUGIN", "-o", "markers=slow: renders", "test_guarded.py"],
                       cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert "test_renders_unmarked rendered 1 image(s) with ['Renderer'] but is not marked slow" in r.stdout, r.stdout
    assert "3 passed, 1 error in" in r.stdout, r.stdout
