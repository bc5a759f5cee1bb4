"""Test helpers shipped with specsynth for plugin authors (see ``specsynth.testing.conformance``)."""
