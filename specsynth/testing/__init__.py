"""Test helpers shipped with specsynth for plugin authors: ``conformance`` (the checks every backend
passes), ``suite`` (them as base test classes a backend's tests subclass), ``materials`` (PBR map
checks) and ``pytest_plugin`` (the slow-mark guard)."""
