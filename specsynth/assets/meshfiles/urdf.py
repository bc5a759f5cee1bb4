"""URDF (pybullet_data's objects and props) -> its visual elements: meshes or primitives, with their
link-frame transforms, scales and colours. Only what specsynth draws is read (``<visual>``)."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...model.conventions import rpy_matrix
from .part import MeshFileError


@dataclass(frozen=True)
class Visual:
    mesh: Path | None  # None for a primitive
    primitive: tuple | None  # ('box', (sx, sy, sz)) | ('cylinder', (r, h)) | ('sphere', (r,))
    scale: tuple[float, float, float]
    matrix: np.ndarray  # 4x4 link-from-visual
    rgba: tuple[float, float, float, float] | None


def _floats(s: str | None, n: int, default: float) -> tuple[float, ...]:
    if not s:
        return (default,) * n
    v = tuple(float(x) for x in s.split())
    return v * n if len(v) == 1 else v


def parse_urdf(path: Path) -> list[Visual]:
    """Visual geometry of a single-link URDF (what pybullet_data objects and tables are)."""

    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as e:
        raise MeshFileError(f"{path}: cannot parse URDF: {e}") from e
    named = {}
    for m in root.findall("material"):
        c = m.find("color")
        if c is not None:
            named[m.get("name")] = _floats(c.get("rgba"), 4, 1.0)
    links = root.findall("link")
    if len(links) != 1:
        raise MeshFileError(f"{path}: only single-link URDFs are supported, this one has {len(links)} links")
    visuals = []
    for vis in links[0].findall("visual"):
        T = np.eye(4)
        o = vis.find("origin")
        if o is not None:
            T[:3, :3] = rpy_matrix(*_floats(o.get("rpy"), 3, 0.0))
            T[:3, 3] = _floats(o.get("xyz"), 3, 0.0)
        rgba = None
        mat = vis.find("material")
        if mat is not None:
            c = mat.find("color")
            rgba = _floats(c.get("rgba"), 4, 1.0) if c is not None else named.get(mat.get("name"))
        g = vis.find("geometry")
        if g is None or len(g) == 0:
            continue
        geo = g[0]
        if geo.tag == "mesh":
            visuals.append(Visual(path.parent / geo.get("filename", ""), None,
                                   _floats(geo.get("scale"), 3, 1.0), T, rgba))
        elif geo.tag == "box":
            visuals.append(Visual(None, ("box", _floats(geo.get("size"), 3, 1.0)), (1.0, 1.0, 1.0), T, rgba))
        elif geo.tag == "cylinder":
            visuals.append(Visual(None, ("cylinder", (float(geo.get("radius")), float(geo.get("length")))),
                                   (1.0, 1.0, 1.0), T, rgba))
        elif geo.tag == "sphere":
            visuals.append(Visual(None, ("sphere", (float(geo.get("radius")),)), (1.0, 1.0, 1.0), T, rgba))
    if not visuals:
        raise MeshFileError(f"{path}: URDF has no visual geometry")
    return visuals
