"""Seconds per view of the Mitsuba backend's exact-K sensor against the built-in ``perspective``.

    .venv/bin/python benchmarks/bench_mitsuba_sensor.py [--views 12]
"""

from __future__ import annotations

import argparse

import numpy as np

from specsynth_mitsuba.backend import MitsubaBackend
from specsynth_mitsuba.sensor import PINHOLE


def bench(width: int = 320, height: int = 240, spp: int = 16, views: int = 6, threads: int = 1) -> None:
    """Seconds per view, built-in ``perspective`` vs this sensor, through MitsubaBackend:
    Floor + two balls + area light, a new pose per view
    (warm kernels: the first view of each sensor is not timed), the sensors interleaved so that
    a neighbour's load hits both alike. Prints wall and CPU (process) seconds, medians."""
    import tempfile
    import time
    from pathlib import Path

    import trimesh

    from specsynth.assets.meshio import MeshData, write_mesh
    from specsynth.model.ir import CameraIR, LightIR, MaterialIR, MeshInstance, RenderScene, as_tuple
    from specsynth.spec.models import QualityPreset
    from specsynth.views.cameras import look_at


    tmp = Path(tempfile.mkdtemp())

    def mesh(name, tm):
        p = tmp / f"{name}.ply"
        write_mesh(p, MeshData(vertices=tm.vertices.astype(np.float32), faces=tm.faces.astype(np.int32),
                               normals=tm.vertex_normals.astype(np.float32)))
        return str(p)

    def pose(t, s=1.0):
        T = np.diag([s, s, s, 1.0])
        T[:3, 3] = t
        return as_tuple(T)

    floor = mesh("floor", trimesh.creation.box(extents=[4.0, 4.0, 0.02]))
    ball = mesh("ball", trimesh.creation.icosphere(subdivisions=4, radius=0.3))
    scene = RenderScene(
        meshes=(
            MeshInstance("floor", floor, "floor", pose((0, 0, -0.01)), MaterialIR(specular=0.0, metallic=0.0, roughness=1.0)),
            MeshInstance("b1", ball, "ball", pose((0.2, 0, 0.3)), MaterialIR(base_color=(0.8, 0.2, 0.2), roughness=0.3)),
            MeshInstance("b2", ball, "ball", pose((-0.5, 0.4, 0.3)), MaterialIR(base_color=(0.2, 0.6, 0.8))),
        ),
        lights=(LightIR(kind="area", pose=pose((0, 0, 2.0)), power=80.0, size=(0.5, 0.5)),),
    )
    quality = QualityPreset(aa=spp, diffuse_rays=1, specular_rays=1, diffuse_depth=1, specular_depth=1, max_depth=2)
    f = 0.9 * width
    configs = {  # name: (fy, use the K sensor); one backend each, so each keeps its sensor
        "perspective, fy = fx": (f, False),
        f"{PINHOLE}, fy = fx": (f, True),
        f"{PINHOLE}, fy = 1.1 fx": (1.1 * f, True),
    }
    backends = {}
    for name, (_, k_sensor) in configs.items():
        b = backends[name] = MitsubaBackend({"variant": "auto"}, threads=threads)
        b._use_k_sensor = lambda sset, k=k_sensor: k  # the benchmark forces the choice
        b.load(scene)
    times: dict[str, list[tuple[float, float]]] = {k: [] for k in configs}
    for i in range(views + 1):
        a = 2 * np.pi * i / (views + 1)
        R, t = look_at(np.array([2.0 * np.cos(a), 2.0 * np.sin(a), 1.2]), np.array([0.0, 0.0, 0.2]))
        for name, (fy, k_sensor) in configs.items():
            K = np.array([[f, 0, (width - 1) / 2 + 3.3], [0, fy, (height - 1) / 2 - 2.1], [0, 0, 1]])
            cam = CameraIR(K=as_tuple(K), width=width, height=height, R_w2c=as_tuple(R), t_w2c=as_tuple(t))
            w0, c0 = time.perf_counter(), time.process_time()
            r = backends[name].render(cam, quality, seed=i)
            w1, c1 = time.perf_counter(), time.process_time()
            assert r.stats["sensor"] == (PINHOLE if k_sensor else "perspective")
            if i > 0:  # view 0 builds the sensor and compiles
                times[name].append((w1 - w0, c1 - c0))
    variant = next(iter(backends.values())).variant
    print(f"{variant}, {width}x{height}, {spp} spp, threads={threads}, {views} timed views each (medians):")
    base = float(np.median([c for _, c in times["perspective, fy = fx"]]))
    for name, tt in times.items():
        wall, cpu = np.median([w for w, _ in tt]), np.median([c for _, c in tt])
        print(f"  {name:30s} wall {wall:.3f} s  cpu {cpu:.3f} s  ({100 * (cpu / base - 1):+.1f} % cpu)")
    for b in backends.values():
        b.close()


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--views", type=int, default=12)
    bench(views=ap.parse_args().views)
