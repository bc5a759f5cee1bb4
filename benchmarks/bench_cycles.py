"""Seconds per 640x480 Cycles image for the paper's quality levels, with and without OpenImageDenoise.

    .venv/bin/python benchmarks/bench_cycles.py                    # low and medium
    .venv/bin/python benchmarks/bench_cycles.py --levels low medium high --repeats 3 --json out.json

The scene is built in code (floor, back wall, boxes, spheres incl. a glossy metal one, a 0.3 m area light
and the ``courtyard`` HDRI shipped in the bpy wheel) so the numbers need no downloads. Timings are
``RenderResult.stats['seconds']``: camera + settings + render + EXR read-back, scene already loaded.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from specsynth.assets.meshio import MeshData, write_mesh  # noqa: E402
from specsynth.model.ir import (  # noqa: E402
    CameraIR,
    LightIR,
    MaterialIR,
    MeshInstance,
    RenderScene,
    WorldIR,
    as_tuple,
)
from specsynth.spec.models import PAPER_PRESETS  # noqa: E402


def box_mesh() -> MeshData:
    """Unit cube centred at the origin, flat-shaded (4 vertices per face)."""
    verts, norms, faces = [], [], []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            n = np.zeros(3)
            n[axis] = sign
            u, v = np.roll(np.eye(3), 1, axis=0)[axis], np.roll(np.eye(3), 2, axis=0)[axis]
            if sign > 0:
                u, v = v, u  # counter-clockwise seen from outside: cross(u, v) must be n
            c = n * 0.5
            base = len(verts)
            verts += [c + 0.5 * (a * u + b * v) for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
            norms += [n] * 4
            faces += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
    return MeshData(np.float32(verts), np.int32(faces), np.float32(norms))


def sphere_mesh(nu: int = 64, nv: int = 32) -> MeshData:
    th, ph = np.linspace(0, np.pi, nv + 1), np.linspace(0, 2 * np.pi, nu + 1)
    T, P = np.meshgrid(th, ph, indexing="ij")
    n = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(nv), np.arange(nu), indexing="ij")
    a = (i * (nu + 1) + j).ravel()
    f = np.concatenate([np.stack([a, a + nu + 1, a + 1], 1), np.stack([a + 1, a + nu + 1, a + nu + 2], 1)])
    return MeshData(n.astype(np.float32), f.astype(np.int32), n.astype(np.float32))


def pose(t=(0, 0, 0), s=(1, 1, 1), rz: float = 0.0) -> tuple:
    c, si = np.cos(np.radians(rz)), np.sin(np.radians(rz))
    T = np.eye(4)
    T[:3, :3] = np.array([[c, -si, 0], [si, c, 0], [0, 0, 1]]) @ np.diag(s)
    T[:3, 3] = t
    return as_tuple(T)


def bench_scene(tmp: Path, envmap: str) -> RenderScene:
    write_mesh(tmp / "box.ply", box_mesh())
    write_mesh(tmp / "sphere.ply", sphere_mesh())
    box, sph = str(tmp / "box.ply"), str(tmp / "sphere.ply")
    grey = MaterialIR(base_color=(0.6, 0.6, 0.6), roughness=0.8, specular=0.3)
    meshes = [
        MeshInstance("floor", box, "box", pose((0, 0, -0.01), (3, 3, 0.02)), grey),
        MeshInstance("wall", box, "box", pose((0, 0.8, 0.6), (3, 0.02, 1.2)), MaterialIR(base_color=(0.7, 0.65, 0.55), roughness=0.9)),
    ]
    objs = [
        (box, "box", (-0.25, 0.1, 0.06), (0.12, 0.12, 0.12), 20, MaterialIR(base_color=(0.7, 0.2, 0.1), roughness=0.6)),
        (box, "box", (0.2, 0.25, 0.08), (0.1, 0.2, 0.16), -35, MaterialIR(base_color=(0.1, 0.3, 0.7), roughness=0.4)),
        (sph, "sphere", (0.05, -0.1, 0.07), (0.07,) * 3, 0, MaterialIR(base_color=(1.0, 0.78, 0.34), metallic=1.0, roughness=0.25)),
        (sph, "sphere", (-0.05, 0.3, 0.05), (0.05,) * 3, 0, MaterialIR(base_color=(0.2, 0.6, 0.2), roughness=0.5)),
    ]
    for k, (path, key, t, s, rz, mat) in enumerate(objs):
        meshes.append(MeshInstance(f"obj{k}", path, key, pose(t, s, rz), mat, obj_id=k + 1, inst=k))
    light = LightIR(kind="area", pose=pose((0.3, -0.3, 1.2)), power=60.0, size=(0.3, 0.3))
    return RenderScene(meshes=tuple(meshes), lights=(light,), world=WorldIR(kind="envmap", envmap=envmap, strength=0.35, rotation_z=40.0))


def bench_camera() -> CameraIR:
    C = np.array([0.0, -1.1, 0.75])
    target = np.array([0.0, 0.1, 0.1])
    z = target - C
    z /= np.linalg.norm(z)
    x = np.cross(z, [0, 0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])  # rows: camera axes in world (OpenCV: x right, y down, z forward)
    return CameraIR(K=((572.0, 0, 319.5), (0, 572.0, 239.5), (0, 0, 1.0)), width=640, height=480, R_w2c=as_tuple(R), t_w2c=tuple(-R @ C))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--levels", nargs="+", default=["low", "medium"], choices=["low", "medium", "high"])
    ap.add_argument("--denoise", nargs="+", default=["off", "on"], choices=["off", "on"])
    ap.add_argument("--repeats", type=int, default=1, help="renders per setting; the median is reported")
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--save", type=Path, help="folder for the rendered PNGs")
    ap.add_argument("--json", type=Path, help="write the results here")
    args = ap.parse_args(argv)

    t0 = time.perf_counter()
    import bpy

    from specsynth_cycles.backend import CyclesBackend
    from specsynth_cycles.settings import coerce_options

    envmap = str(Path(bpy.utils.system_resource("DATAFILES", path="studiolights")) / "world" / "courtyard.exr")
    results = []
    with tempfile.TemporaryDirectory() as d:
        scene = bench_scene(Path(d), envmap)
        # Options are fixed per backend instance (one per worker), but bpy holds one session per
        # process, so the benchmark swaps the instance's options instead of building a second one.
        option_sets = {dn: {"denoise": dn == "on", "threads": args.threads} for dn in args.denoise}
        backend = CyclesBackend(option_sets[args.denoise[0]], threads=args.threads)
        t_init = time.perf_counter() - t0
        t1 = time.perf_counter()
        backend.load(scene)
        t_load = time.perf_counter() - t1
        cam = bench_camera()
        first = None
        print(f"cycles {backend.version()}  threads={backend.threads}  import+init {t_init:.2f}s  load {t_load:.2f}s")
        for level in args.levels:
            q = PAPER_PRESETS[level]
            for dn in args.denoise:
                backend.options = coerce_options(option_sets[dn])
                times = []
                for r in range(args.repeats):
                    res = backend.render(cam, q, seed=r)
                    times.append(res.stats["seconds"])
                    if first is None:
                        first = time.perf_counter() - t0
                if args.save:
                    from PIL import Image

                    args.save.mkdir(parents=True, exist_ok=True)
                    Image.fromarray(res.rgb).save(args.save / f"cycles_{level}_denoise-{dn}.png")
                row = dict(level=level, denoise=dn == "on", samples=res.stats["samples"], seconds=statistics.median(times), runs=times,
                           mean_linear=float(res.linear.mean()))  # fmt: skip
                results.append(row)
                print(f"{level:7s} denoise={dn:3s} spp={row['samples']:4d}  {row['seconds']:7.2f} s/image  (runs: {', '.join(f'{t:.2f}' for t in times)})", flush=True)
        backend.close()
    out = dict(device="cpu", threads=backend.threads, time_to_first_image=first, init_seconds=t_init, load_seconds=t_load, results=results)
    if args.json:
        args.json.write_text(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
