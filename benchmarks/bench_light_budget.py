"""What the scene-derived light-path budget saves in Cycles: the same views rendered with the
budget (no glossy / transmission bounces the scene cannot use) and without it.

    .venv/bin/python benchmarks/bench_light_budget.py [--width 160] [--level high]

For each built-in scene (no objects, its overview camera): whether the budget applies as modelled
(every built-in scene has some glossy material, none transmits), and a Lambertian variant of the
scene (every material made diffuse) where glossy bounces are skipped too.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

from specsynth.backend_api import load_backend
from specsynth.run.bench import psnr8
from specsynth.scenes import builtin_scenes, load_scene
from specsynth.spec.models import PAPER_PRESETS, Intrinsics
from specsynth.views.preview import overview_camera
from specsynth_cycles.options import CyclesOptions


def lambertian(scene):
    meshes = tuple(dataclasses.replace(m, material=dataclasses.replace(m.material, specular=0.0, metallic=0.0, roughness=1.0))
                   for m in scene.meshes)
    return dataclasses.replace(scene, meshes=meshes)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--width", type=int, default=160)
    ap.add_argument("--level", default="high")
    args = ap.parse_args()
    w = args.width
    intr = Intrinsics(width=w, height=w * 3 // 4, fx=0.45 * w, fy=0.45 * w, cx=w / 2 - 0.5, cy=w * 3 / 8 - 0.5)
    q = PAPER_PRESETS[args.level]
    backend = load_backend("cycles")(CyclesOptions(name="cycles"), threads=0)
    print(f"| scene | glossy / transmission bounces skipped | s with budget | s without | saved | PSNR with vs without |")
    print("|---|---|---|---|---|---|")
    for name in builtin_scenes():
        base = load_scene(name, Path.cwd())
        cam = overview_camera(base, intr)
        for label, rs in ((name, base.with_objects(())), (f"{name}, Lambertian", lambertian(base.with_objects(())))):
            # The first render after a load is slower (measured): alternate the order, keep the best.
            res: dict[bool, tuple[float, object]] = {}
            for budget in (True, False, False, True):
                backend.options = CyclesOptions(name="cycles", light_path_budget=budget)
                backend.load(rs)
                t0 = time.perf_counter()
                r = backend.render(cam, q, seed=1)
                dt = time.perf_counter() - t0
                if budget not in res or dt < res[budget][0]:
                    res[budget] = (dt, r)
            (t_on, r_on), (t_off, r_off) = res[True], res[False]
            skipped = f"{r_on.stats['glossy_skipped']} / {r_on.stats['transmission_skipped']}"
            print(f"| {label} | {skipped} | {t_on:.2f} | {t_off:.2f} | {100 * (1 - t_on / t_off):.0f} % "
                  f"| {psnr8(r_on.rgb, r_off.rgb):.1f} dB |", flush=True)
    backend.close()


if __name__ == "__main__":
    main()
