"""Seconds per photo-baseline image: 640x480, ~10 objects, built-in backgrounds.

    .venv/bin/python benchmarks/bench_photo.py [--images 40] [--objects 10] [--augment]

Prints the median and quartiles of the wall time of ``render()`` (background, lights, raster,
composite, augmentation) after a warm-up that has decoded every built-in background once, plus the
one-off costs (backend start, load, first frame). Goal: <= 0.1 s per image on a 2-core machine
(the paper's BL images took 3 s each).
"""

from __future__ import annotations

import argparse
import hashlib
import math
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np


def _objects(folder: Path, n: int):
    import trimesh
    from PIL import Image

    from specsynth.assets.meshio import MeshData, mesh_bytes, write_mesh
    from specsynth.model.ir import MaterialIR, MeshInstance, as_tuple

    tex = folder / "tex.png"
    ij = np.indices((256, 256)) // 32
    Image.fromarray(np.where(((ij[0] + ij[1]) % 2)[..., None] > 0, [200, 180, 40], [40, 90, 160]).astype(np.uint8)).save(tex)
    # BOP-like complexity: a few thousand to ~20k triangles per object.
    shapes = [
        trimesh.creation.icosphere(subdivisions=4, radius=0.04),
        trimesh.creation.capsule(height=0.06, radius=0.025, count=[48, 48]),
        trimesh.creation.cylinder(radius=0.03, height=0.08, sections=96),
        trimesh.creation.torus(major_radius=0.035, minor_radius=0.012, major_sections=96, minor_sections=48),
        trimesh.creation.box(extents=(0.06, 0.05, 0.04)).subdivide().subdivide().subdivide(),
    ]
    instances = []
    rng = np.random.default_rng(0)
    for i in range(n):
        m = shapes[i % len(shapes)]
        textured = i % 3 == 0
        v = m.vertices.astype(np.float32)
        lo, hi = v.min(0), v.max(0)
        cols = np.concatenate([np.round(40 + 200 * (v - lo) / (hi - lo + 1e-9)).astype(np.uint8), np.full((len(v), 1), 255, np.uint8)], 1)
        uv = ((v[:, :2] - lo[:2]) / (hi[:2] - lo[:2] + 1e-9)).astype(np.float32)
        md = MeshData(v, m.faces.astype(np.int32), m.vertex_normals.astype(np.float32), uv if textured else None, cols)
        path = folder / f"obj_{i:02d}.ply"
        write_mesh(path, md)
        key = hashlib.sha256(mesh_bytes(md)).hexdigest()
        T = np.eye(4)
        a = rng.uniform(0, 2 * math.pi)
        T[:3, :3] = [[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]]
        T[:3, 3] = [0.09 * (i % 4) - 0.135, 0.09 * (i // 4) - 0.09, 0.04]
        mat = MaterialIR(texture=str(tex) if textured else None, roughness=float(rng.uniform(0.2, 0.8)), metallic=float(i % 5 == 4))
        instances.append(MeshInstance(f"obj_{i}", str(path), key, as_tuple(T), mat, obj_id=i + 1, inst=i))
    return tuple(instances), sum(len(s.faces) for s in shapes) * n // len(shapes)


def _cameras(n: int):
    from specsynth.model.ir import CameraIR, as_tuple

    K = ((572.4114, 0.0, 325.2611), (0.0, 573.57043, 242.04899), (0.0, 0.0, 1.0))
    rng = np.random.default_rng(1)
    cams = []
    for _ in range(n):
        az, el, d = rng.uniform(0, 2 * math.pi), rng.uniform(0.3, 1.2), rng.uniform(0.6, 0.9)
        eye = d * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
        z = -eye / np.linalg.norm(eye)
        x = np.cross(z, (0, 0, 1.0))
        x /= np.linalg.norm(x)
        R = np.stack([x, np.cross(z, x), z])
        cams.append(CameraIR(K=K, width=640, height=480, R_w2c=as_tuple(R), t_w2c=as_tuple(-R @ eye)))
    return cams


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--images", type=int, default=40)
    ap.add_argument("--objects", type=int, default=10)
    ap.add_argument("--augment", action="store_true", help="enable all augmentations (blur sigma 0.5-1.5)")
    ap.add_argument("--threads", type=int, default=0, help="llvmpipe threads (LP_NUM_THREADS); 0 = Mesa's default")
    ap.add_argument("--quality", choices=["low", "medium", "high"], default="low", help="low: no MSAA; medium/high: 4x MSAA")
    ap.add_argument("--save", type=Path, help="write the rendered images here")
    args = ap.parse_args()

    t0 = time.perf_counter()
    from specsynth.model.ir import RenderScene
    from specsynth.spec.models import PAPER_PRESETS
    from specsynth_photo.backend import PhotoBackend

    t_import = time.perf_counter() - t0
    options = {"name": "photo"}
    if args.augment:
        options["augment"] = {"brightness": 0.2, "contrast": 0.2, "hue": 0.05, "saturation": 0.2,
                              "noise_std": 0.02, "blur_sigma": [0.5, 1.5]}
    with tempfile.TemporaryDirectory() as tmp:
        objects, n_faces = _objects(Path(tmp), args.objects)
        scene = RenderScene(meshes=objects)
        t0 = time.perf_counter()
        backend = PhotoBackend(options, threads=args.threads)
        backend.load(scene)
        t_load = time.perf_counter() - t0
        cams = _cameras(args.images)
        t0 = time.perf_counter()
        backend.render(cams[0], PAPER_PRESETS[args.quality], 0)
        t_first = time.perf_counter() - t0
        # Warm-up: decode every built-in background once (a one-off cost per worker process).
        for src in backend._backgrounds.sources:
            backend._backgrounds._get(src)
        times, cpu, raster, bg = [], [], [], []
        for i, cam in enumerate(cams):
            t0, c0 = time.perf_counter(), time.process_time()
            r = backend.render(cam, PAPER_PRESETS[args.quality], 1000 + i)
            times.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
            raster.append(r.stats["seconds_raster"])
            bg.append(r.stats["seconds_background"])
            if args.save:
                from PIL import Image

                args.save.mkdir(parents=True, exist_ok=True)
                Image.fromarray(r.rgb).save(args.save / f"{i:04d}.jpg", quality=90)
        backend.close()

    q = statistics.quantiles(times, n=4)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    print(f"backend: {backend.version()}  objects: {args.objects} (~{n_faces} triangles)  augment: {args.augment}  "
          f"quality: {args.quality}  cores: {os.cpu_count()}  load average: {load:.1f}")
    print(f"one-off: import {t_import:.2f} s, start+load {t_load:.2f} s, first frame {t_first:.2f} s")
    print(f"per 640x480 image over {len(times)}: median {statistics.median(times):.4f} s "
          f"(quartiles {q[0]:.4f}-{q[2]:.4f}); raster {statistics.median(raster):.4f} s, "
          f"background {statistics.median(bg):.4f} s")
    # CPU seconds of all threads: what one image costs a machine, independent of other load.
    print(f"CPU time per image (all threads): median {statistics.median(cpu):.4f} s")


if __name__ == "__main__":
    main()
