"""A user scene of ~200k triangles and ~20 textures from one GLB: import, stages, first render, per view.

    .venv/bin/python benchmarks/bench_scene_import.py [--triangles 200000] [--textures 20] [--views 4]

The GLB is generated here (deterministic): a 6 x 5 m floor and walls, and ``--textures`` pieces
of furniture-sized geometry, each with its own 512 x 512 base-colour texture; every other piece
also has a normal map and a packed metallic-roughness map. Measured, in one process:

- import: ``meshfiles.read_parts`` (parse, flatten, bake maps) with an empty texture cache;
- scene load, cold: ``load_scene`` with an empty mesh cache (import + normalised PLYs + stages);
- scene load, warm: the same scene again from the cache (what every later worker pays);
- per backend (VGA, 1 spp + denoise for Cycles, 4 spp for Mitsuba): ``load`` (scene sync, BVH,
  textures), the first render and the mean of the next renders from other viewpoints.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np


def make_glb(path: Path, triangles: int, textures: int) -> None:
    import trimesh
    from PIL import Image
    from trimesh.visual.material import PBRMaterial

    rng = np.random.default_rng(0)
    scene = trimesh.Scene()
    floor = trimesh.creation.box((6.0, 0.05, 5.0))  # glTF: +Y up
    floor.visual = trimesh.visual.TextureVisuals(material=PBRMaterial(name="floor", baseColorFactor=[0.6, 0.5, 0.4, 1]))
    scene.add_geometry(floor, node_name="floor", transform=trimesh.transformations.translation_matrix((0, -0.025, 0)))
    per_piece = max(triangles // textures, 100)
    count = max(int(round(np.sqrt(per_piece / 4))), 4)  # a UV sphere of count x count has ~4 count^2 triangles
    for i in range(textures):
        mesh = trimesh.creation.uv_sphere(radius=0.3, count=[count, count])
        mesh.apply_scale((1.0 + rng.uniform(0, 1), 0.8, 1.0 + rng.uniform(0, 1)))
        yy, xx = np.mgrid[0:512, 0:512] / 512.0
        tex = np.stack([np.sin(xx * (4 + i)) * 0.5 + 0.5, np.cos(yy * (3 + i)) * 0.5 + 0.5,
                        rng.uniform(0.2, 0.8) * np.ones_like(xx)], -1)
        uv = np.stack([np.arctan2(mesh.vertices[:, 2], mesh.vertices[:, 0]) / (2 * np.pi) + 0.5,
                       mesh.vertices[:, 1] / 0.6 + 0.5], 1)
        kw = {}
        if i % 2 == 0:
            n = np.stack([0.3 * np.sin(xx * 40), 0.3 * np.cos(yy * 40), np.ones_like(xx)], -1)
            n /= np.linalg.norm(n, axis=-1, keepdims=True)
            kw["normalTexture"] = Image.fromarray((n * 127.5 + 127.5).astype(np.uint8))
            kw["metallicRoughnessTexture"] = Image.fromarray((np.stack([xx, yy, 1 - yy], -1) * 255).astype(np.uint8))
        mat = PBRMaterial(name=f"piece_{i:02d}", baseColorTexture=Image.fromarray((tex * 255).astype(np.uint8)),
                          roughnessFactor=0.6, metallicFactor=0.0, **kw)
        mesh.visual = trimesh.visual.TextureVisuals(uv=uv, material=mat)
        x, z = (i % 5) * 1.1 - 2.2, (i // 5) * 1.1 - 1.6
        scene.add_geometry(mesh, node_name=f"piece_{i:02d}",
                           transform=trimesh.transformations.translation_matrix((x, 0.3, z)))
    path.write_bytes(scene.export(file_type="glb"))


def timed(fn):
    t0 = time.perf_counter()
    out = fn()
    return out, time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--triangles", type=int, default=200_000)
    ap.add_argument("--textures", type=int, default=20)
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--backends", nargs="*", default=["cycles", "mitsuba"])
    args = ap.parse_args()

    from specsynth.assets import meshfiles
    from specsynth.model.ir import CameraIR, RenderScene, as_tuple
    from specsynth.scenes import load_scene
    from specsynth.spec.models import QualityPreset, SceneRef
    from specsynth.views.cameras import look_at

    with tempfile.TemporaryDirectory() as d:
        d = Path(d)
        glb = d / "big.glb"
        make_glb(glb, args.triangles, args.textures)
        parts, t_import = timed(lambda: meshfiles.read_parts(glb, d / "tex"))
        tris = sum(len(p.mesh.faces) for p in parts)
        maps = len({t for p in parts for t in p.material.textures})
        desc, t_cold = timed(lambda: load_scene(SceneRef(file=str(glb)), d, cache=d / "cache"))
        _, t_warm = timed(lambda: load_scene(SceneRef(file=str(glb)), d, cache=d / "cache"))
        print(f"scene: {glb.stat().st_size / 1e6:.1f} MB GLB, {tris:,} triangles, {len(parts)} materials, "
              f"{maps} texture maps after baking, {len(desc.stages)} stages found\n")
        print("| step | seconds |\n|---|---|")
        print(f"| import (parse, flatten, bake maps) | {t_import:.2f} |")
        print(f"| scene load, cold cache (import + normalised meshes + stages) | {t_cold:.2f} |")
        print(f"| scene load, warm cache | {t_warm:.2f} |")
        scene = RenderScene(meshes=desc.meshes, lights=desc.lights, world=desc.world)
        K = np.array([[572.4, 0, 319.5], [0, 572.4, 239.5], [0, 0, 1]])
        cams = []
        for k in range(args.views + 1):
            a = 2 * np.pi * k / (args.views + 1)
            R, t = look_at(np.array([2.5 * np.cos(a), 2.5 * np.sin(a), 1.6]), np.array([0.0, 0.0, 0.3]))
            cams.append(CameraIR(K=as_tuple(K), width=640, height=480, R_w2c=as_tuple(R), t_w2c=as_tuple(t)))
        for name in args.backends:
            if name == "cycles":
                from specsynth_cycles.backend import CyclesBackend

                b = CyclesBackend({"name": "cycles", "denoise": True}, threads=2)
                q = QualityPreset(aa=1, diffuse_rays=1, specular_rays=1, diffuse_depth=1, specular_depth=1, max_depth=2)
            else:
                from specsynth_mitsuba.backend import MitsubaBackend

                b = MitsubaBackend({"variant": "auto"}, threads=2)
                q = QualityPreset(aa=4, diffuse_rays=1, specular_rays=1, diffuse_depth=1, specular_depth=1, max_depth=2)
            try:
                _, t_load = timed(lambda: b.load(scene))
                _, t_first = timed(lambda: b.render(cams[0], q, seed=1))
                rest = [timed(lambda c=c: b.render(c, q, seed=1))[1] for c in cams[1:]]
            finally:
                b.close()
            print(f"| {name}: load (sync, BVH, textures) | {t_load:.2f} |")
            print(f"| {name}: first render, VGA | {t_first:.2f} |")
            print(f"| {name}: per further view, VGA (mean of {len(rest)}) | {statistics.mean(rest):.2f} |")


if __name__ == "__main__":
    main()
