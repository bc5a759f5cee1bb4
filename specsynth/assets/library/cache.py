"""Where derived assets live: ``$SPECSYNTH_CACHE`` or ``~/.cache/specsynth`` (never the repo)."""

from __future__ import annotations

import os
from pathlib import Path


def cache_dir() -> Path:
    env = os.environ.get("SPECSYNTH_CACHE")
    return Path(env).expanduser() if env else Path.home() / ".cache" / "specsynth"
