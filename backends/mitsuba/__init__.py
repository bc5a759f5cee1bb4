"""Mitsuba 3 render backend plugin (entry point ``mitsuba``).

Importing this package does not import Mitsuba: the variant is chosen, and Mitsuba imported, when
a :class:`MitsubaBackend` is constructed (once per worker process).
"""

from .backend import MitsubaBackend

__all__ = ["MitsubaBackend"]
