"""The photo baseline against specsynth's conformance suite (specsynth.testing.suite), plus a
check of its own: the seed draws the background photograph and the lights."""

from __future__ import annotations

from specsynth.testing.conformance import check_seed_matters
from specsynth.testing.suite import BackendConformanceTests


class TestPhotoConformance(BackendConformanceTests):
    """A rasteriser of base colours over photographs: no PBR maps, no thin lens, no motion blur
    (those two tests are skipped with the reason)."""

    backend = "photo"

    def test_seed_matters(self, conformance):
        check_seed_matters(conformance)
