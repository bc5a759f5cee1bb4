"""Built-in HDRIs: the studio lights that the bpy wheel ships as data files (CC0, Blender).

Found through the installed distribution's files, never ``import bpy`` (a 300 MB renderer) nor
``find_spec``: once a process has imported bpy, its sys.path (which spawned workers inherit)
resolves ``bpy`` to a pure-Python package far from the data files. Knowing where a package keeps
its assets is the library's job, as for the Debian furniture and the robosuite textures.
"""

from __future__ import annotations

from importlib import metadata
from pathlib import Path

SOURCE = "the bpy wheel (pip install -e backends/cycles, or pip install bpy==5.0.1)"


def studiolights_dir() -> Path | None:
    try:
        root = Path(metadata.distribution("bpy").locate_file("bpy"))
    except metadata.PackageNotFoundError:
        return None
    hits = sorted(root.glob("*/datafiles/studiolights/world"))
    return hits[-1] if hits else None


def builtin_hdris() -> list[str]:
    d = studiolights_dir()
    return sorted(p.stem for p in d.glob("*.exr")) if d else []
