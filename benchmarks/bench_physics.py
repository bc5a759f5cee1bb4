"""Benchmark of specsynth.physics.arrange: CPU seconds per arrangement and invalid-drop rates.

15 LM-sized objects (boxes, cylinders and the two YCB-V models of the shared test data) dropped
onto a table-top stage, N arrangements with consecutive seeds. Goal: <= 1 s CPU per arrangement.

    .venv/bin/python benchmarks/bench_physics.py [--n 50] [--orientation canonical|random]
        [--collision convex_hull|decomposition] [--objects 15]
"""

from __future__ import annotations

import argparse
import hashlib
import statistics
import tempfile
import time
from collections import Counter
from pathlib import Path

import numpy as np
import trimesh

from specsynth.assets import meshio
from specsynth.assets.resolve import ObjectAsset
from specsynth.model.ir import MaterialIR, MeshInstance, WorldIR, as_tuple
from specsynth.physics import ArrangeError, ShapeCache, arrange, build_collision_model
from specsynth.scenes.types import SceneDesc, Stage
from specsynth.spec.models import Arrangements, Physics

TABLE_TOP = 0.75


def _write(tm: trimesh.Trimesh, path: Path) -> tuple[str, str]:
    meshio.write_mesh(
        path,
        meshio.MeshData(vertices=np.asarray(tm.vertices, np.float32), faces=np.asarray(tm.faces, np.int32)),
    )
    return str(path), hashlib.sha256(path.read_bytes()).hexdigest()[:16]


def _asset(tm: trimesh.Trimesh, tmp: Path, name: str, obj_id: int) -> ObjectAsset:
    path, key = _write(tm, tmp / f"{name}.ply")
    lo, hi = tm.bounds
    return ObjectAsset(
        obj_id=obj_id,
        name=name,
        mesh_path=path,
        mesh_key=key,
        material=MaterialIR(),
        diameter=float(np.linalg.norm(hi - lo)),
        bbox_min=tuple(map(float, lo)),
        extents=tuple(map(float, hi - lo)),
        source=f"bench:{name}",
    )


def _load_lm(obj: int) -> trimesh.Trimesh | None:
    """A real LM model (BOP PLY in millimetres, installed by `make install`) in metres; None when the
    set is not installed."""
    from specsynth.assets.library.cache import cache_dir
    from specsynth.assets.library.realsets import RealSetError, resolve_ref

    try:
        path = resolve_ref("dataset:lmo/models", cache_dir()) / f"obj_{obj:06d}.ply"
    except RealSetError:
        return None
    if not path.exists():
        return None
    import logging

    logging.getLogger("trimesh").setLevel(logging.CRITICAL)
    tm = trimesh.load(path, process=False, force="mesh")
    return trimesh.Trimesh(vertices=np.asarray(tm.vertices) * 0.001, faces=tm.faces, process=False)


def lm_like_objects(tmp: Path, count: int) -> list[ObjectAsset]:
    shapes: list[tuple[str, trimesh.Trimesh]] = []
    for obj in (1, 5):
        tm = _load_lm(obj)
        if tm is not None:
            shapes.append((f"lm_{obj}", tm))
    sizes = [
        (0.10, 0.07, 0.05), (0.06, 0.06, 0.12), (0.15, 0.08, 0.04), (0.08, 0.08, 0.08),
        (0.12, 0.05, 0.09), (0.07, 0.04, 0.03), (0.09, 0.09, 0.06),
    ]
    for k, ext in enumerate(sizes):
        shapes.append((f"box_{k}", trimesh.creation.box(extents=ext)))
    for k, (r, h) in enumerate([(0.035, 0.11), (0.05, 0.06), (0.03, 0.15), (0.045, 0.09), (0.025, 0.07), (0.06, 0.04)]):
        shapes.append((f"cyl_{k}", trimesh.creation.cylinder(radius=r, height=h, sections=32)))
    assets = [_asset(tm, tmp, name, i + 1) for i, (name, tm) in enumerate(shapes)]
    return [assets[i % len(assets)] for i in range(count)]


def table_scene(tmp: Path) -> tuple[SceneDesc, Stage]:
    meshes = []
    for name, ext, z in (("table", (1.2, 0.8, 0.03), TABLE_TOP - 0.015), ("floor", (6.0, 6.0, 0.1), -0.05)):
        path, key = _write(trimesh.creation.box(extents=ext), tmp / f"{name}.ply")
        pose = np.eye(4)
        pose[2, 3] = z
        meshes.append(MeshInstance(name=name, mesh_path=path, mesh_key=key, pose=as_tuple(pose)))
    stage = Stage(name="table_top", polygon=((-0.5, -0.3), (0.5, -0.3), (0.5, 0.3), (-0.5, 0.3)), height=TABLE_TOP)
    return SceneDesc(name="bench_table", meshes=tuple(meshes), lights=(), world=WorldIR(), stages={stage.name: stage}), stage


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=50, help="arrangements (seeds 0..n-1)")
    ap.add_argument("--objects", type=int, default=15)
    ap.add_argument("--orientation", choices=("canonical", "random"), default="canonical")
    ap.add_argument("--collision", choices=("convex_hull", "decomposition"), default="convex_hull")
    args = ap.parse_args()

    with tempfile.TemporaryDirectory(prefix="bench-physics-") as tmp_s:
        tmp = Path(tmp_s)
        objects = lm_like_objects(tmp, args.objects)
        scene, stage = table_scene(tmp)
        arr = Arrangements(drop_height=(0.05, 0.5), physics=Physics(collision=args.collision))

        shapes = ShapeCache()
        t0 = time.process_time()
        for a in {o.mesh_key: o for o in objects}.values():
            shapes.models[(a.mesh_key, args.collision)] = build_collision_model(a, args.collision, tmp / "collision")
        build_cpu = time.process_time() - t0

        cpu, wall, sim, kept = [], [], [], []
        removed = redropped = unsettled = errors = 0
        reasons: Counter[str] = Counter()
        for seed in range(args.n):
            c0, w0 = time.process_time(), time.perf_counter()
            try:
                res = arrange(scene, stage, objects, arr, args.orientation, np.random.default_rng(seed), shapes=shapes)
            except ArrangeError:
                errors += 1
                continue
            finally:
                cpu.append(time.process_time() - c0)
                wall.append(time.perf_counter() - w0)
            sim.append(res.sim_seconds)
            kept.append(len(res.placed))
            removed += res.removed
            redropped += res.redropped
            unsettled += not res.settled
            reasons.update(res.invalid_reasons)

    n_obj = args.n * args.objects
    q = statistics.quantiles(cpu, n=10) if len(cpu) >= 2 else cpu * 9
    print(f"physics benchmark: {args.n} arrangements x {args.objects} objects, {args.orientation}, {args.collision}")
    print(f"collision models built once: {build_cpu:.3f} s CPU")
    print(
        f"CPU s / arrangement: mean {statistics.mean(cpu):.3f}  median {statistics.median(cpu):.3f}  "
        f"p90 {q[8]:.3f}  max {max(cpu):.3f}   (wall mean {statistics.mean(wall):.3f})"
    )
    if sim:
        print(f"simulated s / arrangement: mean {statistics.mean(sim):.2f}  max {max(sim):.2f}")
    print(f"kept objects / arrangement: mean {statistics.mean(kept) if kept else 0:.2f} of {args.objects}")
    print(f"removed: {removed} ({100 * removed / n_obj:.2f} % of objects)")
    print(f"re-dropped: {redropped} ({100 * redropped / n_obj:.2f} % of objects)")
    print(f"invalid drops by reason: {dict(sorted(reasons.items()))}")
    print(f"unsettled at max_time: {unsettled} of {args.n}; arrangements with nothing kept: {errors}")


if __name__ == "__main__":
    main()
