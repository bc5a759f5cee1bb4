"""URDF (pybullet_data's objects and props) -> its visual elements: meshes or primitives, with their
link-frame transforms, scales and colours. Only what specsynth draws is read (``<visual>``)."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...model.conventions import rpy_matrix
from .part import MeshFileError, read_file, referenced_file


@dataclass(frozen=True)
class Visual:
    mesh: Path | None  # None for a primitive
    primitive: tuple | None  # ('box', (sx, sy, sz)) | ('cylinder', (r, h)) | ('sphere', (r,))
    scale: tuple[float, float, float]
    matrix: np.ndarray  # 4x4 link-from-visual
    rgba: tuple[float, float, float, float] | None


def _floats(s: str | None, n: int, default: float, where: str = "URDF") -> tuple[float, ...]:
    if not s:
        return (default,) * n
    try:
        v = tuple(float(x) for x in s.split())
    except ValueError:
        raise MeshFileError(f"{where}: expected {n} numbers") from None
    v = v * n if len(v) == 1 else v
    if len(v) != n or not all(np.isfinite(v)):
        raise MeshFileError(f"{where}: expected {n} finite numbers")
    return v


def parse_urdf(path: Path) -> list[Visual]:
    """Visual geometry of a single-link URDF (what pybullet_data objects and tables are)."""

    try:
        root = ET.fromstring(read_file(path))
    except ET.ParseError as e:  # its position, not the text around it
        raise MeshFileError(f"{path}: cannot parse URDF (XML error at line {e.position[0]})") from None
    named = {}
    for m in root.findall("material"):
        c = m.find("color")
        if c is not None:
            named[m.get("name")] = _floats(c.get("rgba"), 4, 1.0, f"{path}: material rgba")
    links = root.findall("link")
    if len(links) != 1:
        raise MeshFileError(f"{path}: only single-link URDFs are supported, this one has {len(links)} links")
    visuals = []
    for vis in links[0].findall("visual"):
        T = np.eye(4)
        o = vis.find("origin")
        if o is not None:
            T[:3, :3] = rpy_matrix(*_floats(o.get("rpy"), 3, 0.0, f"{path}: visual origin rpy"))
            T[:3, 3] = _floats(o.get("xyz"), 3, 0.0, f"{path}: visual origin xyz")
        rgba = None
        mat = vis.find("material")
        if mat is not None:
            c = mat.find("color")
            rgba = _floats(c.get("rgba"), 4, 1.0, f"{path}: visual rgba") if c is not None else named.get(mat.get("name"))
        g = vis.find("geometry")
        if g is None or len(g) == 0:
            continue
        geo = g[0]
        where = f"{path}: visual {geo.tag}"
        if geo.tag == "mesh":
            visuals.append(Visual(_mesh_file(path, geo.get("filename", ""), where), None,
                                  _floats(geo.get("scale"), 3, 1.0, where), T, rgba))
        elif geo.tag == "box":
            visuals.append(Visual(None, ("box", _floats(geo.get("size"), 3, 1.0, where)), (1.0, 1.0, 1.0), T, rgba))
        elif geo.tag == "cylinder":
            radius, length = _floats(f"{geo.get('radius')} {geo.get('length')}", 2, 0.0, where)
            visuals.append(Visual(None, ("cylinder", (radius, length)), (1.0, 1.0, 1.0), T, rgba))
        elif geo.tag == "sphere":
            visuals.append(Visual(None, ("sphere", _floats(geo.get("radius"), 1, 0.0, where)), (1.0, 1.0, 1.0), T, rgba))
    if not visuals:
        raise MeshFileError(f"{path}: URDF has no visual geometry")
    return visuals


def _mesh_file(path: Path, filename: str, where: str) -> Path:
    """A visual's mesh, in the URDF's folder; a missing one is returned as the path it would have
    (the caller says it is missing)."""
    return referenced_file(path, filename, where) or path.parent / filename
