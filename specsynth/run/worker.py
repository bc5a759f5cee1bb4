"""The state a worker process keeps between jobs (see ``Worker``)."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from ..assets.resolve import ObjectAsset, resolve_objects
from ..model import lens
from ..model.ir import MeshInstance, RenderScene, as_tuple
from ..model.records import ArrangementRecord, PlacedObject
from ..plan import seeds
from ..plan.compiler import arr_id
from ..plugins import backend_plugin
from ..scenes import load_scene
from ..scenes.types import SceneDesc
from ..plan.inputs import ArrangeInputs, BuildInputs
from ..spec.models import SceneRef
from ..views import cameras
from .store import Store

PROCEDURAL_KEPT = 2  # procedural rooms a worker keeps loaded (one per arrangement in flight)


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


class Worker:
    """One process's loaded state, kept between jobs: assets, scenes, the annotator, the backend
    and the albedo renderer, each with the arrangement it holds; and the arrangement's scene as the
    renderers get it (``render_scene``, ``frame``). The steps (``arrange``, ``views``, ``render``)
    are functions of a worker."""

    def __init__(self, ctx: BuildContext):
        self.ctx = ctx
        # What every step reads to rebuild an arrangement's scene, and the image's intrinsics (the
        # view's and the render's are the same field of the spec).
        self.world: ArrangeInputs = ctx.inputs.arrange
        self.intrinsics = ctx.inputs.view.intrinsics
        self.store = Store(ctx.out)
        self._assets: list[ObjectAsset] | None = None
        self._scenes: dict[tuple[str, int | None], SceneDesc] = {}
        self._annotator = None
        self._backend = None
        self.draws_scene = True
        self._albedo = None
        self._albedo_key: str | None = None
        self._warp = None
        self._distractors: dict[str, ObjectAsset] = {}
        self._has_uv: dict[str, bool] = {}
        # What the annotator / backend hold now: (arrangement key, seconds its load took).
        self._loaded: dict[str, tuple[str, float]] = {}
        # One BLAS thread: our products are 4x4 poses and Nx3 vertex arrays, too small to gain from
        # threads, and an idle OpenBLAS thread spins in sched_yield after every call. Measured on a
        # photo build: 28 CPU-s in 19 s of wall with numpy's default 2 threads, 17.5 in 17.5 with 1;
        # with two workers that spinning is taken from the other worker. Undone by ``close``.
        self._blas = threadpool_limits(limits=1, user_api="blas")

    # ------------------------------------------------------------------ lazily built state
    def assets(self) -> list[ObjectAsset]:
        if self._assets is None:
            self._assets = resolve_objects(self.world.objects, self.ctx.spec_dir)
        return self._assets

    def scene(self, ref: SceneRef, variant: int | None = None) -> SceneDesc:
        key = (ref.model_dump_json(), variant)  # the whole reference: stages, room, clutter all shape the scene
        if key not in self._scenes:
            if variant is not None:  # procedural rooms: keep the last few, so memory stays flat
                rooms = [k for k in self._scenes if k[1] is not None]
                for old in rooms[: max(0, len(rooms) - PROCEDURAL_KEPT + 1)]:
                    del self._scenes[old]
            clearance = self.world.arrangements.drop_height[1] + max((a.diameter for a in self.assets()), default=0.0)
            self._scenes[key] = load_scene(ref, self.ctx.spec_dir, clearance=clearance, variant=variant)
        return self._scenes[key]

    def lens_warp(self):
        """The lens warp of the spec's intrinsics (computed once per worker), None without distortion."""
        k = self.intrinsics.distortion
        if k is None:
            return None
        if self._warp is None:
            intr = self.intrinsics
            self._warp = lens.warp_for(cameras.intrinsics_matrix(intr), intr.width, intr.height, k)
        return self._warp

    def albedo(self, arrange_key: str, scene: RenderScene):
        """The albedo renderer with this arrangement loaded (once per arrangement)."""
        if self._albedo is None:
            from ..annotate.albedo import AlbedoRenderer

            warp = self.lens_warp()  # through a lens, the albedo is drawn like the colour: pinhole, then warped
            size = (warp.width, warp.height) if warp else (self.intrinsics.width, self.intrinsics.height)
            self._albedo = AlbedoRenderer(*size)
            self._albedo_key = None
        if self._albedo_key != arrange_key:
            self._albedo.load(scene if self.draws_scene else scene.objects_only())
            self._albedo_key = arrange_key
        return self._albedo

    def annotator(self):
        if self._annotator is None:
            from ..annotate.engine import Annotator

            self._annotator = Annotator(self.intrinsics.width, self.intrinsics.height)
        return self._annotator

    def backend(self):
        if self._backend is None:
            inp = self.ctx.inputs.render
            plugin = backend_plugin(inp.backend.name)
            # Paths in a spec are relative to the spec file (as the compiler hashes them), never
            # to wherever the build was started.
            options = plugin.options_for(inp.backend.relative_to(self.ctx.spec_dir), inp.quality)
            self._backend = plugin.load_class()(options, threads=self.ctx.threads)
            self.draws_scene = plugin.capabilities.draws_scene
        return self._backend

    def close(self) -> None:
        for obj in (self._backend, self._annotator, self._albedo):
            if obj is not None:
                obj.close()
        self._backend = self._annotator = self._albedo = None
        self._loaded.clear()
        self._blas.restore_original_limits()

    def load(self, what: str, arrange_key: str, scene: RenderScene) -> float:
        """Load an arrangement into the annotator or the backend unless it is there already
        (consecutive view and render calls of one arrangement); the seconds its load took."""
        held = self._loaded.get(what)
        if held is None or held[0] != arrange_key:
            self._loaded.pop(what, None)  # a load that raises leaves nothing marked as loaded
            target = self.annotator() if what == "annotator" else self.backend()
            t0 = time.perf_counter()
            target.load(scene)
            held = self._loaded[what] = (arrange_key, time.perf_counter() - t0)
        return held[1]

    # ------------------------------------------------------------------ helpers
    def _scene_ref(self, name: str) -> SceneRef:
        for ref in self.world.scenes:
            if ref.ref == name:
                return ref
        raise KeyError(name)

    def render_scene(self, arr: ArrangementRecord) -> RenderScene:
        """The arrangement in world coordinates (see ``frame`` for what renderers get)."""
        by_id = self.assets_by_id(arr)
        objects = tuple(
            MeshInstance(
                name=f"obj_{o.obj_id:06d}_{o.inst:03d}",
                mesh_path=by_id[o.obj_id].mesh_path,
                mesh_key=by_id[o.obj_id].mesh_key,
                pose=as_tuple(np.asarray(o.pose)),
                material=by_id[o.obj_id].material,
                obj_id=o.obj_id,
                inst=o.inst,
            )
            for o in arr.objects
        )
        name, variant = arr.scene_ref
        ref = self._scene_ref(name)
        scene = self.scene(ref, variant).with_objects(objects)
        if arr.distractors:
            scene = RenderScene(meshes=scene.meshes + self._distractor_meshes(arr.distractors), lights=scene.lights,
                                world=scene.world)
        return self._randomized(scene, ref, arr.arr)

    def assets_by_id(self, arr: ArrangementRecord) -> dict[int, ObjectAsset]:
        """The dataset's objects and, when annotated, the arrangement's distractors, by obj_id."""
        by_id = {a.obj_id: a for a in self.assets()}
        extra = sorted({o.name for o in arr.objects if o.obj_id not in by_id})
        d, n = self.world.arrangements.distractors, len(self.assets())
        for a in self.distractor_assets(extra):
            by_id[d.obj_id(a.name, n)] = replace(a, obj_id=d.obj_id(a.name, n))
        return by_id

    def _distractor_meshes(self, placed: list[PlacedObject]) -> tuple[MeshInstance, ...]:
        """Distractors are scene geometry (``obj_id`` None): drawn, occluding, never annotated."""
        found = {a.name: a for a in self.distractor_assets(sorted({d.name for d in placed}))}
        return tuple(MeshInstance(name=f"distractor_{k:03d}", mesh_path=found[d.name].mesh_path,
                                  mesh_key=found[d.name].mesh_key, pose=as_tuple(np.asarray(d.pose)),
                                  material=found[d.name].material)
                     for k, d in enumerate(placed))

    def distractor_assets(self, names: list[str]) -> list[ObjectAsset]:
        """The assets of the drawn distractors, in order; a name drawn twice is one asset twice
        (resolved once: resolving a list that names a model twice is refused)."""
        missing = list(dict.fromkeys(n for n in names if n not in self._distractors))
        if missing:
            from ..spec.models import Objects

            for a in resolve_objects(Objects(builtin=missing), self.ctx.spec_dir):
                self._distractors[a.name] = a
        return [self._distractors[n] for n in names]

    def _randomized(self, scene: RenderScene, ref: SceneRef, arr: int) -> RenderScene:
        if not ref.randomize.active:
            return scene
        from ..assets.library import textures
        from ..assets.library.cache import cache_dir
        from ..assets.meshio import read_mesh
        from ..scenes.randomize import randomize_scene

        library = textures.available(cache_dir()) if ref.randomize.materials else []
        rng = np.random.default_rng(seeds.job_seed(self.world.seed, f"{arr_id(arr)}/randomize"))

        def has_uv(path: str) -> bool:
            if path not in self._has_uv:
                self._has_uv[path] = read_mesh(path).uv is not None
            return self._has_uv[path]

        return randomize_scene(scene, ref.randomize, rng, library, has_uv)

    def frame(self, arr: ArrangementRecord) -> tuple[RenderScene, np.ndarray]:
        """The scene re-centred on its objects, and the offset to apply to cameras.

        Annotations are invariant (poses relative to the camera), so records keep world poses.
        """
        scene = self.render_scene(arr)
        objs = scene.objects()
        origin = np.mean([o.matrix[:3, 3] for o in objs], axis=0) if objs else np.zeros(3)
        return scene.translated(origin), origin

    def camera(self, R_w2c, t_w2c, origin=None):
        cam = cameras.camera_ir(self.intrinsics, np.asarray(R_w2c), np.asarray(t_w2c))
        return cam if origin is None else cam.translated(origin)
