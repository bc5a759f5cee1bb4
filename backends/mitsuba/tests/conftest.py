from __future__ import annotations

import pytest


@pytest.fixture(scope="module")
def mitsuba_backend():
    """One warm Mitsuba backend per test module (variant probe and kernel cache are per process)."""
    pytest.importorskip("mitsuba")
    from specsynth_mitsuba.backend import MitsubaBackend

    b = MitsubaBackend({"variant": "auto"}, threads=2)
    yield b
    b.close()
