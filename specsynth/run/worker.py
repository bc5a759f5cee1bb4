"""What a worker process keeps between jobs and its steps share: an arrangement's world rebuilt
from its record (``World``), the image's optics (``Optics``) and renderers that keep the
arrangement they hold (``Held``). Each is built from explicit inputs and only caches what those
inputs determine, so no result depends on which step asked for it first."""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path
from typing import Any, Callable, Mapping

import numpy as np

from ..assets import bopdistractors
from ..assets.resolve import ObjectAsset, resolve_objects
from ..model import lens
from ..model.ir import CameraIR, MeshInstance, RenderScene, as_tuple
from ..model.records import ArrangementRecord, PlacedObject
from ..plan import seeds
from ..plan.compiler import arr_id
from ..plan.inputs import ArrangeInputs, BuildInputs
from ..scenes import load_scene
from ..scenes.types import SceneDesc
from ..spec.models import Intrinsics, Material, SceneRef
from ..views import cameras

PROCEDURAL_KEPT = 2  # procedural rooms a worker keeps loaded (one per arrangement in flight)
Materials = Mapping[str, Material] | None  # the spec's objects.materials, a render input


@dataclass(frozen=True)
class BuildContext:
    """Everything a worker needs; small and picklable. Of the spec, only what the stages read."""

    inputs: BuildInputs
    spec_dir: Path
    out: Path
    threads: int = 0  # renderer threads per worker; 0 = the executor decides (its cores per worker)

    def with_threads(self, threads: int) -> "BuildContext":
        """This context with ``threads`` unless the user gave a count."""
        return self if self.threads else replace(self, threads=max(1, int(threads)))


@dataclass(frozen=True)
class Framed:
    """An arrangement as the views and renders draw it: the scene re-centred on its objects, the
    offset to apply to cameras, and the assets of its annotated objects by obj_id. Annotations are
    invariant (poses relative to the camera), so records keep world poses."""

    record: ArrangementRecord
    scene: RenderScene
    origin: np.ndarray
    assets: dict[int, ObjectAsset]


class World:
    """Arrangements' scenes rebuilt from their records with one stage's ``ArrangeInputs`` (every
    step rebuilds them alike): the spec's objects resolved once (per set of materials: the
    renders' are theirs, ``RenderInputs.materials``; without, each model's own look), the drawn
    distractors once each, scenes loaded once (the last few procedural rooms)."""

    def __init__(self, inputs: ArrangeInputs, spec_dir: Path):
        self.inputs = inputs
        self.spec_dir = spec_dir
        self._assets: dict[str, list[ObjectAsset]] = {}
        self._scenes: dict[tuple[str, int | None], SceneDesc] = {}
        self._distractors: dict[str, ObjectAsset] = {}
        self._has_uv: dict[str, bool] = {}
        self._folder_models: list[str] | None = None

    def assets(self, materials: Materials = None) -> list[ObjectAsset]:
        """The spec's objects, dressed in ``materials`` (the spec's ``objects.materials``)."""
        key = json.dumps({k: m.model_dump(mode="json") for k, m in (materials or {}).items()}, sort_keys=True)
        if key not in self._assets:
            self._assets[key] = resolve_objects(self.inputs.objects.with_materials(materials or {}), self.spec_dir)
        return self._assets[key]

    def scene(self, ref: SceneRef, variant: int | None = None) -> SceneDesc:
        key = (ref.model_dump_json(), variant)  # the whole reference: stages, room, clutter all shape the scene
        if key not in self._scenes:
            if variant is not None:  # procedural rooms: keep the last few, so memory stays flat
                rooms = [k for k in self._scenes if k[1] is not None]
                for old in rooms[: max(0, len(rooms) - PROCEDURAL_KEPT + 1)]:
                    del self._scenes[old]
            draws = self.inputs.arrangements
            fall = draws.drop_height[1] if draws.placement == "drop" else 0.0  # a standing object only needs its size
            clearance = fall + max((a.diameter for a in self.assets()), default=0.0)
            self._scenes[key] = load_scene(ref, self.spec_dir, clearance=clearance, variant=variant)
        return self._scenes[key]

    def scene_ref(self, name: str) -> SceneRef:
        for ref in self.inputs.scenes:
            if ref.ref == name:
                return ref
        raise KeyError(name)

    def render_scene(self, arr: ArrangementRecord, materials: Materials = None) -> RenderScene:
        """The arrangement in world coordinates, its objects in ``materials`` (see ``frame`` for
        what renderers get)."""
        by_id = self.assets_by_id(arr, materials)
        objects = tuple(
            MeshInstance(name=f"obj_{o.obj_id:06d}_{o.inst:03d}", mesh_path=by_id[o.obj_id].mesh_path,
                         mesh_key=by_id[o.obj_id].mesh_key, pose=as_tuple(np.asarray(o.pose)),
                         material=by_id[o.obj_id].material.painted(o.color), obj_id=o.obj_id, inst=o.inst)
            for o in arr.objects
        )
        name, variant = arr.scene_ref
        ref = self.scene_ref(name)
        scene = self.scene(ref, variant).with_objects(objects)
        if arr.distractors:
            scene = RenderScene(meshes=scene.meshes + self._distractor_meshes(arr.distractors), lights=scene.lights,
                                world=scene.world)
        return _painted(self._randomized(scene, ref, arr.arr), arr.distractors)

    def frame(self, arr: ArrangementRecord, materials: Materials = None) -> Framed:
        """The arrangement re-centred on its objects (renderers work in float32 near the origin)."""
        scene = self.render_scene(arr, materials)
        objs = scene.objects()
        origin = np.mean([o.matrix[:3, 3] for o in objs], axis=0) if objs else np.zeros(3)
        return Framed(arr, scene.translated(origin), origin, self.assets_by_id(arr, materials))

    def assets_by_id(self, arr: ArrangementRecord, materials: Materials = None) -> dict[int, ObjectAsset]:
        """The dataset's objects and, when annotated, the arrangement's distractors, by obj_id."""
        by_id = {a.obj_id: a for a in self.assets(materials)}
        extra = sorted({o.name for o in arr.objects if o.obj_id not in by_id})
        d, n = self.inputs.arrangements.distractors, len(by_id)
        for a in self.distractor_assets(extra):
            by_id[d.obj_id(a.name, n)] = replace(a, obj_id=d.obj_id(a.name, n))
        return by_id

    def distractor_assets(self, names: list[str]) -> list[ObjectAsset]:
        """The assets of the drawn distractors, in order; a name drawn twice is one asset twice
        (resolved once: resolving a list that names a model twice is refused)."""
        missing = list(dict.fromkeys(n for n in names if n not in self._distractors))
        folder = [n for n in missing if n.startswith(bopdistractors.PREFIX)]
        builtin = [n for n in missing if not n.startswith(bopdistractors.PREFIX)]
        if folder:
            self._distractors.update(bopdistractors.assets(folder, self.inputs.arrangements.distractors.paths,
                                                           self.spec_dir))
        if builtin:
            from ..spec.models import Objects

            for a in resolve_objects(Objects(builtin=builtin), self.spec_dir):
                self._distractors[a.name] = a
        return [self._distractors[n] for n in names]

    def distractor_folder_models(self) -> list[str]:
        """The models of the BOP folders distractors are drawn from (listed once per worker)."""
        if self._folder_models is None:
            self._folder_models = bopdistractors.model_names(self.inputs.arrangements.distractors.paths,
                                                             self.spec_dir)
        return self._folder_models

    def _distractor_meshes(self, placed: list[PlacedObject]) -> tuple[MeshInstance, ...]:
        """Distractors are scene geometry (``obj_id`` None): drawn, occluding, never annotated."""
        found = {a.name: a for a in self.distractor_assets(sorted({d.name for d in placed}))}
        return tuple(MeshInstance(name=distractor_name(k), mesh_path=found[d.name].mesh_path,
                                  mesh_key=found[d.name].mesh_key, pose=as_tuple(np.asarray(d.pose)),
                                  material=found[d.name].material)
                     for k, d in enumerate(placed))

    def _randomized(self, scene: RenderScene, ref: SceneRef, arr: int) -> RenderScene:
        if not ref.randomize.active:
            return scene
        from ..assets.library import textures
        from ..assets.library.cache import cache_dir
        from ..assets.meshio import read_mesh
        from ..scenes.randomize import randomize_scene

        library = textures.available(cache_dir()) if ref.randomize.materials else []
        rng = np.random.default_rng(seeds.job_seed(self.inputs.seed, f"{arr_id(arr)}/randomize"))

        def has_uv(path: str) -> bool:
            if path not in self._has_uv:
                self._has_uv[path] = read_mesh(path).uv is not None
            return self._has_uv[path]

        return randomize_scene(scene, ref.randomize, rng, library, has_uv)


class Optics:
    """The image's camera model from one step's intrinsics: its cameras and the lens warp
    (computed once; None without distortion)."""

    def __init__(self, intrinsics: Intrinsics):
        self.intrinsics = intrinsics

    @cached_property
    def warp(self) -> lens.Warp | None:
        k = self.intrinsics.distortion
        if k is None:
            return None
        intr = self.intrinsics
        return lens.warp_for(cameras.intrinsics_matrix(intr), intr.width, intr.height, k)

    @property
    def canvas(self) -> tuple[int, int]:
        """(width, height) a renderer draws: through a lens, the pinhole window the image is warped from."""
        warp = self.warp
        return (warp.width, warp.height) if warp else (self.intrinsics.width, self.intrinsics.height)

    def camera(self, R_w2c, t_w2c, origin=None) -> CameraIR:
        cam = cameras.camera_ir(self.intrinsics, np.asarray(R_w2c), np.asarray(t_w2c))
        return cam if origin is None else cam.translated(origin)


class Held:
    """A renderer (the annotator, a backend, the albedo pass) made on first use and kept, with
    the arrangement it holds: consecutive calls for one arrangement (its view group, then its
    render groups) load its scene once."""

    def __init__(self, make: Callable[[], Any]):
        self._make = make
        self._obj: Any = None
        self._held: tuple[str, float] | None = None  # (arrangement key, seconds its load took)

    @property
    def held(self) -> str | None:
        """The key of the arrangement loaded now, None before a load (or after one that raised)."""
        return None if self._held is None else self._held[0]

    def get(self) -> Any:
        if self._obj is None:
            self._obj = self._make()
        return self._obj

    def load(self, key: str, scene: RenderScene) -> float:
        """Hold arrangement ``key`` (its ``scene``) unless held already; the seconds its load took."""
        if self._held is None or self._held[0] != key:
            self._held = None  # a load that raises leaves nothing marked as loaded
            target = self.get()
            t0 = time.perf_counter()
            target.load(scene)
            self._held = (key, time.perf_counter() - t0)
        return self._held[1]

    def close(self) -> None:
        if self._obj is not None:
            self._obj.close()
        self._obj = self._held = None


def _painted(scene: RenderScene, distractors: list[PlacedObject]) -> RenderScene:
    """``scene`` with its distractors (``distractor_<k>``, after any randomisation, which would
    otherwise swap a painted one's colour for a library texture) in their paint."""
    colour = {distractor_name(k): d.color for k, d in enumerate(distractors) if d.color is not None}
    if not colour:
        return scene
    meshes = tuple(replace(m, material=m.material.painted(colour[m.name])) if m.name in colour else m
                   for m in scene.meshes)
    return RenderScene(meshes=meshes, lights=scene.lights, world=scene.world)


def distractor_name(k: int) -> str:
    """The scene mesh of an arrangement's ``k``-th distractor."""
    return f"distractor_{k:03d}"
