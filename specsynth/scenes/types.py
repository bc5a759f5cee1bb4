"""Resolved scene: geometry, lights, world and stages. Produced by ``specsynth.scenes.load_scene``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..model.ir import LightIR, MeshInstance, RenderScene, WorldIR


@dataclass(frozen=True)
class Stage:
    """A polygon (world XY, metres, counter-clockwise) at height ``height`` (world Z) to drop objects on."""

    name: str
    polygon: tuple[tuple[float, float], ...]
    height: float
    weight: float = 1.0  # relative chance of being drawn for an arrangement (focus areas raise it)
    focus: bool = False  # lies in one of the scene's focus areas (a dressed desk's free area)

    @property
    def area(self) -> float:
        p = np.asarray(self.polygon)
        x, y = p[:, 0], p[:, 1]
        return float(0.5 * abs(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))

    @property
    def centroid(self) -> np.ndarray:
        return np.asarray(self.polygon).mean(axis=0)

    def contains(self, xy: np.ndarray) -> np.ndarray:
        """Even-odd point-in-polygon test for points (..., 2)."""
        xy = np.asarray(xy, dtype=np.float64)
        p = np.asarray(self.polygon, dtype=np.float64)
        x, y = xy[..., 0], xy[..., 1]
        inside = np.zeros(x.shape, dtype=bool)
        for (x0, y0), (x1, y1) in zip(p, np.roll(p, -1, axis=0)):
            crosses = (y0 > y) != (y1 > y)
            with np.errstate(divide="ignore", invalid="ignore"):
                xc = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
            inside ^= crosses & (x < xc)
        return inside

    def sample_point(self, rng: np.random.Generator, margin: float = 0.0) -> np.ndarray:
        """Uniform point inside the polygon (rejection sampling in its bounding box)."""
        p = np.asarray(self.polygon)
        lo, hi = p.min(0) + margin, p.max(0) - margin
        if np.any(lo >= hi):
            lo, hi = p.min(0), p.max(0)
        for _ in range(10_000):
            q = rng.uniform(lo, hi)
            if self.contains(q):
                return q
        return self.centroid


@dataclass(frozen=True)
class SceneDesc:
    name: str
    meshes: tuple[MeshInstance, ...]  # scene geometry (obj_id None)
    lights: tuple[LightIR, ...]
    world: WorldIR
    stages: dict[str, Stage]
    # Names of meshes that physics collides with; default (None) all meshes.
    colliders: tuple[str, ...] | None = None
    # Third-party assets in the scene (furniture, textures): what a build's attribution lists.
    credits: tuple[dict, ...] = ()

    def collider_meshes(self) -> tuple[MeshInstance, ...]:
        if self.colliders is None:
            return self.meshes
        keep = set(self.colliders)
        return tuple(m for m in self.meshes if m.name in keep)

    def with_objects(self, objects: tuple[MeshInstance, ...]) -> RenderScene:
        return RenderScene(meshes=self.meshes + tuple(objects), lights=self.lights, world=self.world)
