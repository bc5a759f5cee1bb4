"""Cycles' light tree on and off at equal samples, each denoised by OIDN, against the whole-image
VGA reference of `specsynth bench` (docs/backends/cycles.md, "What a sample costs on the demo").

    .venv/bin/python benchmarks/cycles_light_tree.py [--samples 9 16] [--refs bench-out/vga_full]

Needs the Cycles references of a whole-image VGA bench of the demo's first view in
``--refs``/bench/references (the bench command in docs/performance.md, without --ref-crop).
Prints seconds per render and the error of each against the two-part reference; the first render
is a warm-up. Run it on an idle machine: times are the point.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from specsynth.model.colour import linear_to_srgb8
from specsynth.model.error import rel_mse
from specsynth.plan.compiler import compile_spec
from specsynth.plan.inputs import ArrangeInputs
from specsynth.plugins import backend_plugin
from specsynth.run.bench import (Shots, _setting_options, _views, base_options, psnr8, reference, scaled_intrinsics,
                                 settings_for)
from specsynth.run.worker import Optics, World
from specsynth.spec.yamlio import load_spec

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--samples", type=int, nargs="+", default=[9, 16])
    ap.add_argument("--refs", default="bench-out/vga_full")
    args = ap.parse_args()
    graph = compile_spec(load_spec(ROOT / "specs/demo.yaml", []))
    spec = graph.spec
    (arec, vrec, seed), *_ = _views(graph, Path(args.refs), 1)[0]
    shots = Shots(World(ArrangeInputs.cut(spec), graph.spec_path.parent), Optics(scaled_intrinsics(spec.intrinsics, 1.0)),
                  spec.objects.materials, None)
    plugin = backend_plugin("cycles")
    base = {**base_options(spec.backend, plugin), "denoise_quality": "high", "denoise_prefilter": "none"}
    ref_setting = next(st for st in settings_for(plugin, 2) if st.reference)  # the bench's --ref-factor 2
    ref_options, ref_preset, _ = _setting_options(plugin, ref_setting, base, spec)
    backend = plugin.load_class()(ref_options, threads=0)
    backend.load(shots.scene(arec))
    cam = shots.camera(vrec)
    ref = reference(backend, ref_options, cam, ref_preset, seed, spec.quality.clamp, arec, Path(args.refs),
                    revision=plugin.revision).linear  # cached by the bench; rendered (minutes) when not
    preset = spec.quality.model_copy(update={"level": "paper_high"}).resolved()
    backend.options = plugin.options.model_validate({**base, "denoise": True, "samples": 4})
    backend.render(cam, preset, seed)
    for n in args.samples:
        backend.options = backend.options.model_copy(update={"samples": n})
        for tree in (True, False):
            backend._bpy.context.scene.cycles.use_light_tree = tree
            backend._last_settings = None  # a full sync of the changed setting
            t0 = time.perf_counter()
            r = backend.render(cam, preset, seed)
            print(f"{n} spp + OIDN, light tree {'on ' if tree else 'off'}: {time.perf_counter() - t0:.2f} s, "
                  f"relMSE {rel_mse(r.linear, ref):.3e}, PSNR {psnr8(r.rgb, linear_to_srgb8(ref)):.2f} dB", flush=True)


if __name__ == "__main__":
    main()
