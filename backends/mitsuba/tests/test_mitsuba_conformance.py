"""Mitsuba against specsynth's conformance suite and PBR material checks (specsynth.testing.suite),
plus a check of its own: the seed changes the path tracer's noise."""

from __future__ import annotations

import pytest

from specsynth.testing.conformance import check_seed_matters
from specsynth.testing.suite import BackendConformanceTests, MaterialChannelTests

pytestmark = pytest.mark.slow  # a path tracer: every test renders


class TestMitsubaConformance(BackendConformanceTests, MaterialChannelTests):
    backend = "mitsuba"

    def test_seed_matters(self, conformance):
        check_seed_matters(conformance)
