"""Seconds per 640x480 image at the paper's low / medium / high presets, Mitsuba backend.

Scene (representative of a specsynth arrangement, untextured): floor, back wall, two boxes, a
diffuse and a glossy sphere, a 0.3 m area light and the ``courtyard`` HDRI from the bpy wheel
(found without importing bpy). Camera: LM-O intrinsics.

    .venv/bin/python benchmarks/bench_mitsuba.py [--levels low medium high] [--repeats 3]
        [--sampler independent|ldsampler|stratified] [--variant auto] [--threads 0] [--json out.json]

Times are medians over ``--repeats`` renders in one process after one warm-up render (which
compiles the kernels and is reported separately as time to first frame).
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import resource
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
from specsynth_mitsuba.options import MitsubaOptions  # noqa: E402


def find_hdri(name: str = "courtyard") -> Path | None:
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        return None
    for root in spec.submodule_search_locations:
        hits = sorted(Path(root).glob(f"*/datafiles/studiolights/world/{name}.exr"))
        if hits:
            return hits[0]
    return None


def _mesh(tmp: Path, name: str, tm) -> tuple[str, str]:
    p = tmp / f"{name}.ply"
    write_mesh(p, MeshData(
        vertices=tm.vertices.astype(np.float32),
        faces=tm.faces.astype(np.int32),
        normals=tm.vertex_normals.astype(np.float32),
    ))
    return str(p), name


def _T(t=(0, 0, 0), rz=0.0, s=(1, 1, 1)) -> tuple:
    c, sn = np.cos(np.radians(rz)), np.sin(np.radians(rz))
    T = np.eye(4)
    T[:3, :3] = np.array([[c, -sn, 0], [sn, c, 0], [0, 0, 1]]) @ np.diag(s)
    T[:3, 3] = t
    return as_tuple(T)


def build_scene(tmp: Path) -> RenderScene:
    import trimesh

    box = _mesh(tmp, "box", trimesh.creation.box(extents=(1, 1, 1)))
    ball = _mesh(tmp, "ball", trimesh.creation.icosphere(subdivisions=4, radius=1.0))
    diffuse = dict(specular=0.0, metallic=0.0, roughness=1.0)
    meshes = (
        MeshInstance("floor", *box, _T((0, 0, -0.01), s=(2, 2, 0.02)), MaterialIR(base_color=(0.6, 0.6, 0.55), **diffuse)),
        MeshInstance("wall", *box, _T((0, 0.6, 0.5), s=(2, 0.02, 1)), MaterialIR(base_color=(0.5, 0.55, 0.6), **diffuse)),
        MeshInstance("box1", *box, _T((-0.12, 0.05, 0.04), 20, (0.08, 0.08, 0.08)), MaterialIR(base_color=(0.7, 0.2, 0.1), roughness=0.5), obj_id=1, inst=0),
        MeshInstance("box2", *box, _T((0.1, -0.08, 0.03), -35, (0.1, 0.05, 0.06)), MaterialIR(base_color=(0.1, 0.3, 0.7), roughness=0.3), obj_id=2, inst=1),
        MeshInstance("ball1", *ball, _T((0.02, 0.1, 0.05), s=(0.05,) * 3), MaterialIR(base_color=(0.9, 0.7, 0.2), metallic=1.0, roughness=0.2), obj_id=3, inst=2),
        MeshInstance("ball2", *ball, _T((0.15, 0.12, 0.035), s=(0.035,) * 3), MaterialIR(base_color=(0.8, 0.8, 0.8), **diffuse), obj_id=4, inst=3),
    )
    light_pose = np.eye(4)
    light_pose[:3, 3] = (0.3, -0.3, 1.0)
    lights = (LightIR(kind="area", pose=as_tuple(light_pose), power=4.0, size=(0.3, 0.3)),)
    hdri = find_hdri()
    world = WorldIR(kind="envmap", envmap=str(hdri), strength=1.0) if hdri else WorldIR(kind="color", color=(0.3, 0.3, 0.3))
    return RenderScene(meshes=meshes, lights=lights, world=world)


def camera() -> CameraIR:
    K = np.array([[572.4114, 0, 325.2611], [0, 573.57043, 242.04899], [0, 0, 1]])
    eye, target = np.array([0.0, -0.55, 0.35]), np.array([0.0, 0.05, 0.05])
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0, 0, 1.0])
    x /= np.linalg.norm(x)
    R = np.stack([x, np.cross(z, x), z])
    return CameraIR(K=as_tuple(K), width=640, height=480, R_w2c=as_tuple(R), t_w2c=as_tuple(-R @ eye))


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--levels", nargs="+", default=["low", "medium", "high"], choices=list(PAPER_PRESETS))
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--sampler", default="independent", choices=["independent", "ldsampler", "stratified", "multijitter", "orthogonal"])
    ap.add_argument("--variant", default="auto")
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--json", type=Path)
    a = ap.parse_args(argv)

    t0 = time.perf_counter()
    from specsynth_mitsuba.backend import MitsubaBackend

    backend = MitsubaBackend(MitsubaOptions(name="mitsuba", variant=a.variant, sampler=a.sampler), threads=a.threads)
    t_init = time.perf_counter() - t0
    with tempfile.TemporaryDirectory() as tmp:
        scene = build_scene(Path(tmp))
        t1 = time.perf_counter()
        backend.load(scene)
        t_load = time.perf_counter() - t1
        cam = camera()
        t2 = time.perf_counter()
        first = backend.render(cam, PAPER_PRESETS["low"], seed=0)
        t_first = time.perf_counter() - t2
        out = {
            "backend": backend.version(),
            "variant": backend.variant,
            "sampler": a.sampler,
            "world": scene.world.kind,
            "envmap": scene.world.envmap,
            "init_s": round(t_init, 3),
            "load_s": round(t_load, 3),
            "first_frame_s": round(t_first, 3),
            "load_average_1min": round(__import__("os").getloadavg()[0], 2),
            "levels": {},
        }
        print(f"{out['backend']}  init {t_init:.2f} s (variant probe), load {t_load:.2f} s, first low frame {t_first:.2f} s")
        for level in a.levels:
            q = PAPER_PRESETS[level]
            backend.render(cam, q, seed=1)  # per-level warm-up: a new spp/depth is a new kernel
            times, cpus, stats = [], [], None
            reps = a.repeats if level != "high" else max(1, min(a.repeats, 2))
            for i in range(reps):
                t, c = time.perf_counter(), _cpu()
                r = backend.render(cam, q, seed=100 + i)
                times.append(time.perf_counter() - t)
                cpus.append(_cpu() - c)
                stats = r.stats
            med = statistics.median(times)
            # CPU seconds of all render threads: on a shared machine wall time measures the
            # neighbours as much as the renderer
            out["levels"][level] = {
                "seconds_per_image": round(med, 3),
                "cpu_seconds_per_image": round(statistics.median(cpus), 3),
                "runs": [round(x, 3) for x in times],
                "spp": stats["spp"],
                "max_depth": stats["max_depth"],
                "mean_linear": float(r.linear.mean()),
            }
            print(f"{level:>6}: {med:7.2f} s/image, {statistics.median(cpus):7.2f} CPU s  (spp {stats['spp']}, max_depth {stats['max_depth']}, runs {out['levels'][level]['runs']})")
        del first
    backend.close()
    if a.json:
        a.json.write_text(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
