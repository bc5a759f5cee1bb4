"""Compiling: spec to a lazy, deterministic job graph; content keys and seeds. Never touches a renderer."""
