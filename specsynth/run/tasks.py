"""What a worker process does with jobs: arrange, view (camera + visibility), render.

Work arrives grouped per arrangement so the expensive state (assets, pyrender scene, the
renderer's scene) is built once per arrangement and only the camera moves. A ``Worker`` holds that
state for one process; renderers are found by name through entry points, never imported here.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
from threadpoolctl import threadpool_limits

from ..assets.resolve import ObjectAsset, resolve_objects
from ..model import lens
from ..model.colour import check_finite, linear_to_srgb8
from ..model.ir import MeshInstance, RenderResult, RenderScene, as_tuple
from ..model.records import ArrangementRecord, ImageRecord, PlacedObject, ViewRecord
from ..plan import seeds
from ..plan.compiler import Job, arr_id
from ..plugins import backend_plugin
from ..scenes import load_scene, procedural_name
from ..scenes.types import SceneDesc
from ..spec.models import DatasetSpec, SceneRef
from ..views import cameras
from ..views.sensor import jpeg_quality, sensor_depth, sensor_rgb
from .store import Store

PROCEDURAL_KEPT = 2  # procedural rooms a worker keeps loaded (one per arrangement in flight)


@dataclass(frozen=True)
class BuildContext:
    """Everything a worker needs; small and picklable."""

    spec: DatasetSpec
    spec_dir: Path
    out: Path
    threads: int = 0  # renderer threads per worker; 0 = the executor decides (its cores per worker)

    def with_threads(self, threads: int) -> "BuildContext":
        """This context with ``threads`` unless the user gave a count."""
        return self if self.threads else replace(self, threads=max(1, int(threads)))


class Worker:
    def __init__(self, ctx: BuildContext):
        self.ctx = ctx
        self.spec = ctx.spec
        self.store = Store(ctx.out)
        self._assets: list[ObjectAsset] | None = None
        self._scenes: dict[tuple[str, int | None], SceneDesc] = {}
        self._annotator = None
        self._backend = None
        self._draws_scene = True
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
            self._assets = resolve_objects(self.spec.objects, self.ctx.spec_dir)
        return self._assets

    def scene(self, ref: SceneRef, variant: int | None = None) -> SceneDesc:
        key = (ref.ref, variant, ref.room.model_dump_json() if getattr(ref, "room", None) else None)
        if key not in self._scenes:
            if variant is not None:  # procedural rooms: keep the last few, so memory stays flat
                rooms = [k for k in self._scenes if k[1] is not None]
                for old in rooms[: max(0, len(rooms) - PROCEDURAL_KEPT + 1)]:
                    del self._scenes[old]
            clearance = self.spec.arrangements.drop_height[1] + max((a.diameter for a in self.assets()), default=0.0)
            self._scenes[key] = load_scene(ref, self.ctx.spec_dir, clearance=clearance, variant=variant)
        return self._scenes[key]

    def lens_warp(self):
        """The lens warp of the spec's intrinsics (computed once per worker), None without distortion."""
        k = self.spec.intrinsics.distortion
        if k is None:
            return None
        if self._warp is None:
            intr = self.spec.intrinsics
            self._warp = lens.warp_for(cameras.intrinsics_matrix(intr), intr.width, intr.height, k)
        return self._warp

    def albedo(self, arrange_key: str, scene: RenderScene):
        """The albedo renderer with this arrangement loaded (once per arrangement)."""
        if self._albedo is None:
            from ..annotate.albedo import AlbedoRenderer

            warp = self.lens_warp()  # through a lens, the albedo is drawn like the colour: pinhole, then warped
            size = (warp.width, warp.height) if warp else (self.spec.intrinsics.width, self.spec.intrinsics.height)
            self._albedo = AlbedoRenderer(*size)
            self._albedo_key = None
        if self._albedo_key != arrange_key:
            self._albedo.load(scene if self._draws_scene else scene.objects_only())
            self._albedo_key = arrange_key
        return self._albedo

    def annotator(self):
        if self._annotator is None:
            from ..annotate.engine import Annotator

            self._annotator = Annotator(self.spec.intrinsics.width, self.spec.intrinsics.height)
        return self._annotator

    def backend(self):
        if self._backend is None:
            plugin = backend_plugin(self.spec.backend.name)
            # Paths in a spec are relative to the spec file (as the compiler hashes them), never
            # to wherever the build was started.
            options = plugin.options_for(self.spec.backend.relative_to(self.ctx.spec_dir), self.spec.quality)
            self._backend = plugin.load_class()(options, threads=self.ctx.threads)
            self._draws_scene = plugin.capabilities.draws_scene
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
        for ref in self.spec.scenes:
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
        d, n = self.spec.arrangements.distractors, len(self.assets())
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
        missing = [n for n in names if n not in self._distractors]
        if missing:
            from ..spec.models import Objects

            for a in resolve_objects(Objects(builtin=missing), self.ctx.spec_dir):
                self._distractors[a.name] = a
        return [self._distractors[n] for n in names]

    def _geometry_maps(self, wd: Path, cam, ann, by_id: dict[int, ObjectAsset]) -> tuple[str | None, str | None]:
        """normals.exr and nocs.exr from the annotation's depth, when the spec asks for them."""
        from ..annotate.maps import nocs_map, normals_from_depth
        from ..outputs.images import write_exr

        out = self.spec.outputs
        warp = self.lens_warp()
        rays = warp.rays if warp else None  # through a lens, each pixel's own ray instead of K
        normals_file = nocs_file = None
        if out.normals:
            normals_file = "normals.exr"
            write_exr(wd / normals_file, normals_from_depth(ann.depth, cam.K_array, rays))
        if out.nocs:
            diagonals = [float(np.linalg.norm(by_id[g.obj_id].extents)) for g in ann.instances]
            poses = [(g.R_m2c, g.t_m2c) for g in ann.instances]
            nocs_file = "nocs.exr"
            write_exr(wd / nocs_file, nocs_map(ann.depth, cam.K_array, ann.masks_visib, poses, diagonals, rays))
        return normals_file, nocs_file

    def _swapped_credits(self, rec: ArrangementRecord, ref: SceneRef) -> list[dict]:
        """Credits of the library textures that randomisation puts into this arrangement's scene
        (exactly what its renders will show: the same function of the same seed)."""
        if not ref.randomize.materials:
            return []
        from ..assets.library import textures
        from ..assets.library.cache import cache_dir

        by_path = {str(t.path): t for t in textures.available(cache_dir())}
        used = sorted({m.material.texture for m in self.render_scene(rec).meshes if m.material.texture in by_path})
        return [by_path[t].credit for t in used]

    def _randomized(self, scene: RenderScene, ref: SceneRef, arr: int) -> RenderScene:
        if not ref.randomize.active:
            return scene
        from ..assets.library import textures
        from ..assets.library.cache import cache_dir
        from ..assets.meshio import read_mesh
        from ..scenes.randomize import randomize_scene

        library = textures.available(cache_dir()) if ref.randomize.materials else []
        rng = np.random.default_rng(seeds.job_seed(self.spec.seed, f"{arr_id(arr)}/randomize"))

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
        cam = cameras.camera_ir(self.spec.intrinsics, np.asarray(R_w2c), np.asarray(t_w2c))
        return cam if origin is None else cam.translated(origin)

    # ------------------------------------------------------------------ stages
    def run_arrange(self, job: Job) -> dict[str, Any]:
        from ..physics import arrange

        if self.store.has("arrange", job.key):
            return {"id": job.id, "cached": True}
        spec = self.spec
        index, rng = seeds.scene_draw(spec.seed, job.id, [s.weight for s in spec.scenes])
        ref = spec.scenes[index]
        variant = seeds.job_seed(spec.seed, f"{job.id}/scene") if procedural_name(ref) else None
        scene = self.scene(ref, variant)
        names = ref.stages or sorted(scene.stages)
        missing = [n for n in names if n not in scene.stages]
        if missing:
            raise ValueError(f"scene {ref.ref!r} has no stage(s) {missing}; it has {sorted(scene.stages)}")
        stage = scene.stages[names[int(rng.integers(len(names)))]]

        models = self.assets()
        if spec.objects.models_per_arrangement is not None:
            lo, hi = spec.objects.models_per_arrangement
            k = min(int(rng.integers(lo, hi + 1)), len(models))
            chosen = sorted(rng.choice(len(models), size=k, replace=False))
            models = [models[i] for i in chosen]
        lo, hi = spec.objects.instances
        drop: list[ObjectAsset] = []
        for m in models:
            drop += [m] * int(rng.integers(lo, hi + 1))

        distractors = self.distractor_assets(draw_distractors(spec.arrangements.distractors, rng))
        result = arrange(scene, stage, drop + distractors, spec.arrangements, spec.objects.orientation, rng)
        targets = [(i, pose) for i, pose in result.placed if i < len(drop)]
        placed = [
            PlacedObject(obj_id=drop[i].obj_id, inst=n, name=drop[i].name, pose=np.asarray(pose).tolist())
            for n, (i, pose) in enumerate(targets)
        ]
        others = [
            PlacedObject(obj_id=0, inst=n, name=distractors[i - len(drop)].name, pose=np.asarray(pose).tolist())
            for n, (i, pose) in enumerate((i, pose) for i, pose in result.placed if i >= len(drop))
        ]
        if spec.arrangements.distractors.annotate:  # objects like the others, after them in gt order
            n_obj = len(self.assets())
            placed += [PlacedObject(obj_id=spec.arrangements.distractors.obj_id(o.name, n_obj), inst=len(placed) + k,
                                    name=o.name, pose=o.pose) for k, o in enumerate(others)]
            others = []
        rec = ArrangementRecord(
            arr=job.arr, scene=ref.ref if variant is None else f"{ref.ref}#{variant}", stage=stage.name,
            objects=placed, dropped=len(drop), removed=result.removed, redropped=result.redropped,
            settled=result.settled, sim_seconds=result.sim_seconds, seed=job.seed,
            credits=list(scene.credits) + [a.credit for a in models if a.credit]
            + [a.credit for a in {d.name: d for d in distractors}.values() if a.credit],
            distractors=others,
        )
        rec.credits += self._swapped_credits(rec, ref)
        self.store.put("arrange", job.key, rec.to_json())
        return {"id": job.id, "removed": rec.removed, "redropped": rec.redropped, "objects": len(placed)}

    def run_views(self, arrange_key: str, jobs: list[Job]) -> list[dict[str, Any]]:
        spec = self.spec
        arr = ArrangementRecord.from_json(self.store.load("arrange", arrange_key))
        scene, origin = self.frame(arr)
        objects = scene.objects()
        annot = self.annotator()
        if objects:
            self.load("annotator", arrange_key, scene)
        by_id = self.assets_by_id(arr)
        warp = self.lens_warp()  # through a lens, the fraction is the distorted image's
        out = []
        for job in jobs:
            if self.store.has("view", job.key):  # finished before a retry
                continue
            rng = seeds.job_rng(spec.seed, job.id)
            rec = ViewRecord(arr=job.arr, cam=job.cam, index=job.arr * spec.cameras.per_arrangement + job.cam,
                             accepted=False, tries=0, seed=job.seed)
            rejected = 0.0
            for _ in range(spec.cameras.max_tries if objects else 0):
                focus = objects[int(rng.integers(len(objects)))]
                a = by_id[focus.obj_id]
                centre = np.asarray(a.bbox_min) + 0.5 * np.asarray(a.extents)
                target = (focus.matrix @ np.append(centre, 1.0))[:3] + origin  # world frame
                s = cameras.sample_camera(rng, target, spec.cameras)
                t0 = time.perf_counter()
                cam = self.camera(s.R_w2c, s.t_w2c, origin)
                vf = (annot.visib_fract_lens(cam, warp, spec.intrinsics.distortion, focus.inst, spec.visibility.delta)
                      if warp else annot.visib_fract(cam, focus.inst, spec.visibility.delta))
                rec.tries += 1
                if vf >= spec.visibility.threshold and self._in_free_space(annot, s, origin):
                    rec.accepted = True
                    rec.focus_inst, rec.focus_visib_fract = focus.inst, float(vf)
                    rec.R_w2c, rec.t_w2c = np.asarray(s.R_w2c).tolist(), np.asarray(s.t_w2c).tolist()
                    rec.azimuth, rec.elevation, rec.distance = float(s.azimuth), float(s.elevation), float(s.distance)
                    break
                rejected += time.perf_counter() - t0
            rec.rejected_seconds = rejected
            self.store.put("view", job.key, rec.to_json())
            out.append({"id": job.id, "accepted": rec.accepted, "tries": rec.tries, "rejected_seconds": rejected})
        return out

    def _in_free_space(self, annot, s, origin: np.ndarray) -> bool:
        """The camera stands in the open, ``cameras.clearance`` from every surface: not inside a
        wall, a piece of furniture or an object (where a renderer shows the inside of it)."""
        if self.spec.cameras.clearance <= 0:
            return True
        eye = -np.asarray(s.R_w2c, np.float64).T @ np.asarray(s.t_w2c, np.float64)  # world frame
        return annot.free_distance(eye - origin) >= self.spec.cameras.clearance

    def _focused(self, cam, scene: RenderScene, focus_inst: int, job: Job):
        """``cam`` with its thin lens: an aperture drawn for this image, focused on the centre of
        the object the camera aims at (its model origin, BOP's bounding-box centre)."""
        dof = self.spec.cameras.depth_of_field
        rng = np.random.default_rng(seeds.job_seed(self.spec.seed, f"{job.id}/lens"))
        aperture_m = float(rng.uniform(*dof.aperture)) / 1000.0
        jitter = float(rng.uniform(-dof.focus_jitter, dof.focus_jitter))
        focus = next((o for o in scene.objects() if o.inst == focus_inst), None)
        z = float((cam.T_w2c @ focus.matrix)[2, 3]) if focus is not None else 1.0
        return replace(cam, aperture=aperture_m, focus_distance=max(z + jitter, 2.0 * cam.near))

    def _write_image(self, wd: Path, job: Job, res, ann, cam, cam_r, ctx: "_Render") -> dict[str, Any]:
        """Every file of one image into the store folder ``wd`` (sensor effects applied to the colour
        image, each from its own seeded stream) -> the record's file fields and depth scale."""
        from ..outputs.coco import write_visible_rles
        from ..outputs.images import encode_depth, write_exr, write_jpg, write_mask, write_png

        spec, warp = self.spec, self.lens_warp()
        ext = spec.outputs.image_format
        rgb_file = f"rgb.{ext}"
        rng_rgb, rng_jpeg, rng_depth = (np.random.default_rng(ss) for ss in np.random.SeedSequence(
            seeds.job_seed(spec.seed, f"{job.id}/sensor")).spawn(3))
        albedo8 = None
        if spec.outputs.albedo or spec.sensor.auto_white_balance:
            albedo8 = self.albedo(ctx.arrange_key, ctx.scene).render(cam_r)
            albedo8 = lens.remap_nearest(albedo8, warp) if warp else albedo8
        rgb = sensor_rgb(res.linear, res.rgb, spec.sensor, rng_rgb, albedo8)
        if ext == "jpg":
            write_jpg(wd / rgb_file, rgb, jpeg_quality(spec.sensor, spec.outputs.jpeg_quality, rng_jpeg))
        else:
            write_png(wd / rgb_file, rgb)
        depth_file, scale = None, spec.outputs.depth_scale
        if spec.outputs.depth:
            depth16, scale = encode_depth(ann.depth, spec.outputs.depth_scale)
            depth_file = "depth.png"
            write_png(wd / depth_file, depth16)
        if scale == "auto":
            scale = 1.0
        depth_noisy_file = None
        if spec.outputs.depth and spec.sensor.depth is not None:
            depth_noisy_file = "depth_noisy.png"
            write_png(wd / depth_noisy_file, encode_depth(sensor_depth(ann.depth, spec.sensor.depth, rng_depth), scale)[0])
        masks, masks_visib = [], []
        if spec.outputs.masks:
            for gt, (m, mv) in enumerate(zip(ann.masks, ann.masks_visib)):
                masks.append(f"mask_{gt:06d}.png")
                masks_visib.append(f"mask_visib_{gt:06d}.png")
                write_mask(wd / masks[-1], m)
                write_mask(wd / masks_visib[-1], mv)
            write_visible_rles(wd, ann.masks_visib)
        exr_file = None
        if spec.outputs.exr and res.linear is not None:
            exr_file = "rgb.exr"
            write_exr(wd / exr_file, res.linear)
        normals_file, nocs_file = self._geometry_maps(wd, cam, ann, ctx.by_id)
        albedo_file = None
        if spec.outputs.albedo:
            albedo_file = "albedo.png"
            write_png(wd / albedo_file, albedo8)
        return dict(rgb_file=rgb_file, depth_file=depth_file, depth_scale=float(scale), mask_files=masks,
                    mask_visib_files=masks_visib, exr_file=exr_file, normals_file=normals_file, nocs_file=nocs_file,
                    depth_noisy_file=depth_noisy_file, albedo_file=albedo_file)

    def _render_eye(self, wd: Path, job: Job, view: ViewRecord, t_w2c, ctx: "_Render", load_phase: float) -> ImageRecord:
        """One camera's image of the arrangement, its files written into ``wd``: render, annotate,
        lens and sensor, outputs; -> its record (both eyes of a stereo rig share the job's seed)."""
        spec, warp = self.spec, self.lens_warp()
        cam = self.camera(view.R_w2c, t_w2c, ctx.origin)
        cam_r = lens.render_camera(cam, warp) if warp else cam
        if spec.cameras.depth_of_field is not None:
            cam_r = self._focused(cam_r, ctx.scene, view.focus_inst, job)
        if spec.cameras.motion_blur is not None:
            cam_r = replace(cam_r, motion=camera_motion(spec.cameras.motion_blur, seeds.job_seed(spec.seed, f"{job.id}/motion")))
        t1 = time.perf_counter()
        res = ctx.backend.render(cam_r, ctx.preset, job.seed, clamp=spec.quality.clamp)
        seconds = time.perf_counter() - t1
        if res.linear is not None:
            check_finite(res.linear, f"{spec.backend.name} render of {job.id}")
        t2 = time.perf_counter()
        if warp:
            ann = ctx.annot.annotate_lens(cam, warp, spec.intrinsics.distortion, spec.visibility.delta, ctx.occluders)
            res = through_lens(res, warp)
        else:
            ann = ctx.annot.annotate(cam, spec.visibility.delta, ctx.occluders)
        t3 = time.perf_counter()
        files = self._write_image(wd, job, res, ann, cam, cam_r, ctx)
        stats = dict(res.stats)
        stats["load_seconds"] = ctx.load_seconds
        stats["phases"] = render_phases(res.stats.get("phases"), seconds, load=load_phase,
                                        annotate=t3 - t2, encode=time.perf_counter() - t3)
        return ImageRecord(
            arr=job.arr, cam=job.cam, index=view.index, scene=ctx.arr.scene, stage=ctx.arr.stage,
            backend=spec.backend.name, backend_version=ctx.backend.version(), quality=spec.quality.level,
            seed=job.seed, width=cam.width, height=cam.height, K=cam.K_array.tolist(),
            R_w2c=view.R_w2c, t_w2c=list(t_w2c), instances=ann.instances, render_seconds=seconds, stats=stats,
            **files, distortion=list(spec.intrinsics.distortion) if warp else None,
        )

    def run_renders(self, arrange_key: str, pairs: list[tuple[Job, Job]]) -> list[dict[str, Any]]:
        spec = self.spec
        arr = ArrangementRecord.from_json(self.store.load("arrange", arrange_key))
        scene, origin = self.frame(arr)
        backend = self.backend()
        annot = self.annotator()
        load_seconds = self.load("backend", arrange_key, scene) + self.load("annotator", arrange_key, scene)
        load_phase = load_seconds
        occluders = "scene" if self._draws_scene else "objects"
        preset = spec.quality.resolved()
        ctx = _Render(arr, scene, origin, arrange_key, backend, annot, occluders, preset, load_seconds,
                      self.assets_by_id(arr))
        out = []
        for view_job, job in pairs:
            if self.store.has("render", job.key):  # finished before a retry
                continue
            view = ViewRecord.from_json(self.store.load("view", view_job.key))
            wd = self.store.begin()
            rec = self._render_eye(wd, job, view, view.t_w2c, ctx, load_phase)
            stereo = spec.cameras.stereo
            if stereo is not None:  # the right eye: the rig moved by the baseline along the camera's x
                t_right = (np.asarray(view.t_w2c, np.float64) - [stereo.baseline, 0.0, 0.0]).tolist()
                (wd / "right").mkdir()
                right = self._render_eye(wd / "right", job, view, t_right, ctx, 0.0)
                rec = replace(rec, eye="left", baseline=stereo.baseline,
                              right_eye=replace(right, eye="right", baseline=stereo.baseline).to_json())
            t5 = time.perf_counter()
            self.store.commit("render", job.key, wd, rec.to_json())
            out.append({"id": job.id, "seconds": rec.render_seconds,
                        "phases": {**rec.stats["phases"], "write": round(time.perf_counter() - t5, 5)}})
            load_phase = 0.0  # the scene load is paid by the first render of the call
        return out


@dataclass(frozen=True)
class _Render:
    """What every image of one render call shares."""

    arr: ArrangementRecord
    scene: RenderScene
    origin: Any
    arrange_key: str
    backend: Any
    annot: Any
    occluders: str
    preset: Any
    load_seconds: float
    by_id: dict  # obj_id -> ObjectAsset of every annotated object


def render_phases(backend_phases: dict | None, render_seconds: float, **core: float) -> dict[str, float]:
    """Where one image's time went: the backend's own phases (prefixed ``render.``; what it does
    not account for is ``render.other``) and the core's (scene load, annotation, encoding). The
    store commit (``write``) happens after the record is made and is summed by the build."""
    phases = {f"render.{k}": float(v) for k, v in (backend_phases or {}).items()}
    phases["render.other"] = max(0.0, render_seconds - sum(phases.values()))
    phases.update({k: float(v) for k, v in core.items()})
    return {k: round(v, 5) for k, v in phases.items()}


def camera_motion(blur, seed: int) -> tuple[float, ...]:
    """One image's camera motion over the exposure (CameraIR.motion): a direction of travel and an
    axis of turn uniform on the sphere, speed and rate uniform in the spec's ranges."""
    rng = np.random.default_rng(seed)
    direction, axis = (v / np.linalg.norm(v) for v in rng.standard_normal((2, 3)))
    speed, rate = float(rng.uniform(*blur.speed)), np.radians(float(rng.uniform(*blur.rotation)))
    return tuple(float(x) for x in (*(direction * speed * blur.shutter), *(axis * rate * blur.shutter)))


def through_lens(res: RenderResult, warp) -> RenderResult:
    """A pinhole render warped into the distorted image: radiance interpolated (bilinear), then
    encoded by the same sRGB transform every backend uses; an 8-bit-only render interpolated as is."""
    if res.linear is not None:
        linear = np.maximum(lens.remap_bilinear(res.linear, warp), 0.0).astype(np.float32)
        return replace(res, linear=linear, rgb=linear_to_srgb8(linear))
    rgb = np.clip(np.rint(lens.remap_bilinear(res.rgb, warp)), 0, 255).astype(np.uint8)
    return replace(res, rgb=rgb)


def draw_distractors(d, rng: np.random.Generator) -> list[str]:
    """The built-in objects dropped as distractors in one arrangement."""
    lo, hi = d.count
    n = int(rng.integers(lo, hi + 1)) if hi > 0 else 0
    pool = [o for o in d.objects if o != "random_urdfs/*"]
    wild = "random_urdfs/*" in d.objects
    out = []
    for _ in range(n):
        k = int(rng.integers(len(pool) + (1000 if wild else 0)))
        out.append(pool[k] if k < len(pool) else f"random_urdfs/{k - len(pool):03d}")
    return out


# Worker state per output folder, created by the pool initializer (or a Dask WorkerPlugin): the
# warm renderer must outlive a job, and one Dask worker process may serve several builds at once.
_workers: dict[str, Worker] = {}


def die_with_parent(parent: int) -> None:
    """Ask Linux to kill this process when ``parent``, the build that started it, dies
    (PR_SET_PDEATHSIG): a build killed with SIGKILL otherwise leaves its pool workers rendering
    for minutes."""
    import ctypes
    import signal

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL, 0, 0, 0)  # PR_SET_PDEATHSIG = 1
    except (OSError, AttributeError):
        return  # not Linux: workers then exit when their task pipe closes
    if os.getppid() != parent:  # the build died while this worker started: nobody will signal it
        os._exit(1)


def init_pool_worker(ctx: BuildContext, parent: int) -> None:
    """Initializer of the local pool's worker processes."""
    die_with_parent(parent)
    init_worker(ctx)


def init_worker(ctx: BuildContext) -> None:
    # Renderers must not oversubscribe the cores the pool already splits between workers: OpenMP
    # (Blender, OIDN) and Mesa's llvmpipe (annotation engine, photo backend) read these before
    # their first context is created in this process.
    if ctx.threads:
        os.environ["OMP_NUM_THREADS"] = str(ctx.threads)
        os.environ["LP_NUM_THREADS"] = str(ctx.threads)
    os.environ["OPENBLAS_NUM_THREADS"] = "1"  # BLAS libraries loaded later (see Worker._blas)
    old = _workers.get(str(ctx.out))
    if old is not None:
        old.close()
    _workers[str(ctx.out)] = Worker(ctx)


def available_cores() -> int:
    """Cores this process may run on: a container or a batch system may give fewer than cpu_count."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover - non-Linux
        return os.cpu_count() or 1


def current_worker(out: str) -> Worker:
    try:
        return _workers[str(out)]
    except KeyError:
        raise RuntimeError(f"worker not initialised for {out}") from None


def close_worker(out: str) -> None:
    w = _workers.pop(str(out), None)
    if w is not None:
        w.close()


def timed(fn, *args):
    """Run a task; (worker seconds, result, (worker pid, start as epoch seconds)), so a build can
    say where worker time went and draw its timeline."""
    start, t0 = time.time(), time.perf_counter()
    res = fn(*args)
    return time.perf_counter() - t0, res, (os.getpid(), start)


def task_arrange(out: str, job: Job):
    return current_worker(out).run_arrange(job)


def task_views(out: str, arrange_key: str, jobs: list[Job]):
    return current_worker(out).run_views(arrange_key, jobs)


def task_renders(out: str, arrange_key: str, pairs: list[tuple[Job, Job]]):
    return current_worker(out).run_renders(arrange_key, pairs)
