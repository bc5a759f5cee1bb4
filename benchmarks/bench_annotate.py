"""Time the annotation engine: 15 objects on a floor in front of a wall, 640x480, LM-O intrinsics.

    PYOPENGL_PLATFORM=egl .venv/bin/python benchmarks/bench_annotate.py [--views 20] [--objects 15]

Prints median seconds per call of ``Annotator.visib_fract`` (the camera-acceptance pre-check) and
``Annotator.annotate`` (the full BOP gt_info for every object) over sampled cameras, plus the
first ``load`` (mesh reads + GPU upload) and a reload of the same meshes (cache hits).
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh

from specsynth.annotate.engine import Annotator
from specsynth.assets.meshio import MeshData, write_mesh
from specsynth.model.ir import MeshInstance, RenderScene, as_tuple
from specsynth.spec.models import Cameras, Intrinsics
from specsynth.views.cameras import camera_ir, sample_camera


def ycb_like_meshes(rng: np.random.Generator) -> list[trimesh.Trimesh]:
    """Boxes, cans and lumpy ~20k-face blobs, 4-15 cm: the size and density of YCB models."""
    meshes = []
    for i in range(6):
        meshes.append(trimesh.creation.box(extents=rng.uniform(0.04, 0.15, 3)))
        meshes.append(trimesh.creation.cylinder(radius=rng.uniform(0.02, 0.05), height=rng.uniform(0.05, 0.15), sections=96))
        blob = trimesh.creation.icosphere(subdivisions=5, radius=1.0)
        bumps = 1 + 0.08 * np.sin(5 * blob.vertices[:, [0]] + 3 * blob.vertices[:, [1]])
        blob.vertices = blob.vertices * bumps * rng.uniform(0.02, 0.07, 3)
        meshes.append(blob)
    return meshes


def build_scene(folder: Path, rng: np.random.Generator, n_objects: int) -> RenderScene:
    def instance(name, mesh, T, obj_id=None, inst=None):
        path = folder / f"{name}.ply"
        data = MeshData(vertices=np.asarray(mesh.vertices, np.float32), faces=np.asarray(mesh.faces, np.int32))
        write_mesh(path, data)
        return MeshInstance(name, str(path), f"key-{name}", as_tuple(T), obj_id=obj_id, inst=inst)

    meshes = [
        instance("floor", trimesh.creation.box(extents=[4, 4, 0.02]), _pose([0, 0, -0.01])),
        instance("wall", trimesh.creation.box(extents=[4, 0.02, 2]), _pose([0, 0.6, 1.0])),
    ]
    shapes = ycb_like_meshes(rng)
    for i in range(n_objects):
        mesh = shapes[i % len(shapes)]
        angle = rng.uniform(0, 2 * np.pi)
        R = trimesh.transformations.rotation_matrix(angle, [0, 0, 1])[:3, :3]
        xy = rng.uniform(-0.2, 0.2, 2)
        T = _pose([xy[0], xy[1], -mesh.bounds[0, 2]], R)
        meshes.append(instance(f"obj{i:02d}", mesh, T, obj_id=1 + i % len(shapes), inst=i))
    return RenderScene(meshes=tuple(meshes))


def _pose(t, R=np.eye(3)) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--views", type=int, default=20)
    ap.add_argument("--objects", type=int, default=15)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()

    rng = np.random.default_rng(args.seed)
    intr = Intrinsics()  # 640x480
    cams = Cameras()
    with tempfile.TemporaryDirectory() as tmp:
        scene = build_scene(Path(tmp), rng, args.objects)
        t0 = time.perf_counter()
        ann = Annotator(intr.width, intr.height)
        t_init = time.perf_counter() - t0
        t0 = time.perf_counter()
        ann.load(scene)
        cameras = []
        for _ in range(args.views):
            focus = scene.objects()[int(rng.integers(args.objects))]
            s = sample_camera(rng, focus.matrix[:3, 3], cams)
            cameras.append((camera_ir(intr, s.R_w2c, s.t_w2c), focus.inst))
        ann.annotate(*cameras[0][:1], 0.005)  # first render compiles shaders and uploads meshes
        t_load = time.perf_counter() - t0
        t0 = time.perf_counter()
        ann.load(scene)
        t_reload = time.perf_counter() - t0

        t_pre, t_ann, fracs, truncated = [], [], [], []
        for cam, inst in cameras:
            t0 = time.perf_counter()
            fracs.append(ann.visib_fract(cam, inst, 0.005))
            t_pre.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            a = ann.annotate(cam, 0.005)
            t_ann.append(time.perf_counter() - t0)
            assert abs(a.instances[inst].visib_fract - fracs[-1]) < 1e-6
            truncated.append(sum(g.px_count_all > m.sum() for g, m in zip(a.instances, a.masks)))
        ann.close()

    print(f"{args.objects} objects + floor + wall, {intr.width}x{intr.height}, {args.views} views")
    print(f"Annotator init      {t_init:.3f} s")
    print(f"first load+annotate {t_load:.3f} s   reload (cached meshes) {t_reload * 1e3:.2f} ms")
    print(f"visib_fract median  {statistics.median(t_pre):.4f} s   (min {min(t_pre):.4f}, max {max(t_pre):.4f})")
    print(f"annotate    median  {statistics.median(t_ann):.4f} s   (min {min(t_ann):.4f}, max {max(t_ann):.4f})")
    print(f"focus visib_fract median {statistics.median(fracs):.2f}; truncated objects per view median {statistics.median(truncated)}")


if __name__ == "__main__":
    main()
