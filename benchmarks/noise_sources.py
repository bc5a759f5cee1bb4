"""Why Mitsuba is noisier than Cycles at equal samples: the bench's first view, each backend against
its own converged reference, changing one sampling choice at a time.

    .venv/bin/python benchmarks/noise_sources.py [--spp 225] [--ref 1800] [--scale 0.25]

Cycles' defaults are a quasi-Monte Carlo pattern (tabulated Sobol) and a light tree (lights picked by
estimated contribution); Mitsuba's `independent` sampler is pure random and its `path` integrator picks
one emitter per shading point in proportion to `sampling_weight` (1 each by default: uniform).
Rows: Cycles as built, Cycles without the light tree; Mitsuba with each of its samplers. Only error is
measured here (no timings), so the machine need not be idle.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from specsynth.backend_api import load_backend
from specsynth.plan.compiler import compile_spec
from specsynth.run.bench import _views, psnr8, rel_mse, scaled_intrinsics
from specsynth.plan.inputs import BuildInputs
from specsynth.run.worker import Optics, World
from specsynth.spec.models import PAPER_PRESETS, QualityPreset
from specsynth.spec.yamlio import load_spec

ROOT = Path(__file__).resolve().parents[1]


def preset(spp: int) -> QualityPreset:
    return QualityPreset(**{**PAPER_PRESETS["high"].model_dump(), "aa": spp, "diffuse_rays": spp, "specular_rays": spp})


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--spp", type=int, default=225)
    ap.add_argument("--ref", type=int, default=1800)
    ap.add_argument("--scale", type=float, default=0.25)
    ap.add_argument("--out", default="bench-out/noise")
    args = ap.parse_args()
    graph = compile_spec(load_spec(ROOT / "specs/demo.yaml", []))
    out = Path(args.out)
    (picked, _) = _views(graph, out, 1)
    arec, vrec, seed = picked[0]
    spec = graph.spec.model_copy(update={"intrinsics": scaled_intrinsics(graph.spec.intrinsics, args.scale)})
    world = World(BuildInputs.of(spec).arrange, graph.spec_path.parent)
    scene, cam = world.render_scene(arec, graph.inputs.render.materials), Optics(spec.intrinsics).camera(vrec.R_w2c, vrec.t_w2c)
    rows = []

    def measure(backend_name, label, options, tweak=None):
        ref_key = (backend_name, "ref")
        b = load_backend(backend_name)(options, threads=0)
        if tweak:
            tweak(b)
        b.load(scene)
        if ref_key not in refs:
            refs[ref_key] = b.render(cam, preset(args.ref), seed + 7919)
        r = b.render(cam, preset(args.spp), seed)
        ref = refs[ref_key]
        rows.append((backend_name, label, r.stats.get("spp", r.stats.get("samples")), psnr8(r.rgb, ref.rgb),
                     rel_mse(r.linear, ref.linear), float(np.mean(r.linear) / np.mean(ref.linear))))
        print(rows[-1], flush=True)
        b.close()

    refs: dict = {}

    def no_light_tree(b):
        b._bpy.context.scene.cycles.use_light_tree = False

    measure("cycles", "as built (Sobol QMC, light tree)", {"name": "cycles"})
    measure("cycles", "light tree off", {"name": "cycles"}, no_light_tree)
    for sampler in ("independent", "stratified", "ldsampler", "multijitter", "orthogonal"):
        measure("mitsuba", sampler, {"name": "mitsuba", "sampler": sampler})
    print(f"\nbench view 0 of specs/demo.yaml at {spec.intrinsics.width}x{spec.intrinsics.height}, {args.spp} spp vs "
          f"each backend's own {args.ref}-spp reference (another seed)")
    print("| backend | setting | spp | PSNR dB | relMSE | mean / reference |")
    print("|---|---|---|---|---|---|")
    for b, label, spp, p, e, m in rows:
        print(f"| {b} | {label} | {spp} | {p:.2f} | {e:.2e} | {m:.4f} |")


if __name__ == "__main__":
    main()
