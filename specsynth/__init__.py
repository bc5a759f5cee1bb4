"""specsynth: a declarative dataset-spec compiler for photorealistic synthetic images of object instances."""

__version__ = "0.1.0"
