"""Asset resolution: BOP model folders, mesh files, pybullet_data built-ins, bundled HDRIs.

Everything is converted once into the normalised form of ``specsynth.meshio`` (metres) and cached
by content hash; backends and the annotation engine read only that form. No network, ever.
(Skeleton: the functions below are implemented in the assets work.)
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from .ir import MaterialIR


class AssetError(ValueError):
    """A missing, empty, corrupt or absurd asset; the message names the asset."""


@dataclass(frozen=True)
class ObjectAsset:
    obj_id: int
    name: str  # built-in name, or obj_XXXXXX for BOP/mesh objects
    mesh_path: str  # normalised PLY, metres
    mesh_key: str  # content hash of the normalised mesh
    material: MaterialIR
    diameter: float  # metres, max distance between two vertices (BOP definition)
    bbox_min: tuple[float, float, float]  # metres, model frame
    extents: tuple[float, float, float]  # metres, bounding-box size
    source: str  # where it came from (path or 'pybullet_data:duck')
