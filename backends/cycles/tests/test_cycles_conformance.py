"""Cycles against specsynth's conformance suite and PBR material checks (specsynth.testing.suite),
plus a check of its own: the seed changes the path tracer's noise."""

from __future__ import annotations

from dataclasses import replace

import pytest

from specsynth.plugins import backend_plugin
from specsynth.testing.conformance import ConformanceContext, check_sample_continuation, check_seed_matters
from specsynth.testing.suite import BackendConformanceTests, MaterialChannelTests

pytestmark = pytest.mark.slow  # a path tracer: every test renders


class TestCyclesConformance(BackendConformanceTests, MaterialChannelTests):
    backend = "cycles"

    def test_seed_matters(self, conformance):
        check_seed_matters(conformance)


def test_cycles_continues_a_renders_samples(tmp_path):
    """Cycles renders ``sample_offset`` (not declared for error targets yet: see its plugin)."""
    claims = replace(backend_plugin("cycles").capabilities, continues_samples=True)
    context = ConformanceContext("cycles", {"name": "cycles"}, tmp_path, capabilities=claims)
    try:
        check_sample_continuation(context)
    finally:
        context.close()
