"""Converged renders of each built-in scene from Cycles and Mitsuba, compared.

    .venv/bin/python benchmarks/compare_backends.py --spp 1024 --width 160 --out bench-out/compare

For each scene: the overview camera of `specsynth scenes preview`, both backends at the same
high sample count and path depth, then PSNR of the 8-bit sRGB images and the ratio of mean linear
radiance per channel (a light-unit or sky-model mismatch shows as a ratio far from 1).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from specsynth.backend_api import load_backend
from specsynth.outputs.images import write_png
from specsynth.run.bench import psnr8
from specsynth.scenes import builtin_scenes, load_scene
from specsynth.spec.models import Intrinsics, QualityPreset
from specsynth.views.preview import draw_stages, overview_camera


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--width", type=int, default=160)
    ap.add_argument("--out", default="bench-out/compare")
    ap.add_argument("--scenes", nargs="*", default=None)
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    w = args.width
    h = w * 3 // 4
    intr = Intrinsics(width=w, height=h, fx=0.45 * w, fy=0.45 * w, cx=w / 2 - 0.5, cy=h / 2 - 0.5)
    # diffuse and specular depth = max depth: Mitsuba's path integrator has only the total limit.
    q = QualityPreset(aa=args.spp, diffuse_rays=args.spp, specular_rays=args.spp, diffuse_depth=4, specular_depth=4, max_depth=4)
    results = {}
    backends = {name: load_backend(name)({"name": name}, threads=0) for name in ("cycles", "mitsuba")}
    for name in args.scenes or builtin_scenes():
        scene = load_scene(name, Path.cwd())
        cam = overview_camera(scene, intr)
        rs = scene.with_objects(())
        imgs = {}
        for b, backend in backends.items():
            backend.load(rs)
            t0 = time.perf_counter()
            imgs[b] = backend.render(cam, q, seed=1)
            dt = time.perf_counter() - t0
            write_png(out / f"{name}_{b}.png", np.asarray(draw_stages(imgs[b].rgb, scene, cam)))
            results.setdefault(name, {})[f"{b}_seconds"] = round(dt, 1)
        # Each backend against itself with another seed: the PSNR that noise alone allows.
        noise = {}
        for b, backend in backends.items():
            backend.load(rs)
            noise[b] = round(psnr8(imgs[b].rgb, backend.render(cam, q, seed=2).rgb), 2)
        results[name]["self_psnr_db"] = noise
        c, m = imgs["cycles"], imgs["mitsuba"]
        ratio = (m.linear.reshape(-1, 3).mean(0) / np.maximum(c.linear.reshape(-1, 3).mean(0), 1e-9)).round(3).tolist()
        results[name].update({"psnr_db": round(psnr8(c.rgb, m.rgb), 2), "mitsuba_over_cycles_mean_radiance": ratio})
        print(name, results[name], flush=True)
    for backend in backends.values():
        backend.close()
    (out / "compare.json").write_text(json.dumps({"spp": args.spp, "size": [w, h], "scenes": results}, indent=2) + "\n")


if __name__ == "__main__":
    main()
