"""Cycles (Blender 5.0, the bpy wheel) as a specsynth backend plugin.

Importing this package does not import bpy: the plugin object below is what the compiler reads;
the renderer (``specsynth_cycles.backend``) is imported once per worker process.
"""

from specsynth.plugins import BackendPlugin, Capabilities

from .options import CyclesOptions

PLUGIN = BackendPlugin(
    name="cycles",
    options=CyclesOptions,
    backend="specsynth_cycles.backend:CyclesBackend",
    capabilities=Capabilities(
        draws_scene=True, denoise=True, gpu=False,
        material_channels=frozenset({"base_color", "roughness", "metallic", "normal", "emission", "opacity"}),
        quality="samples = max(AA, diffuse rays, specular rays); bounce limits from the preset's depths",
    ),
    distributions=("bpy",),
    # 2: sky sun azimuth turned the IR's way.
    revision=2,
    cost=(1.4, 0.458),  # ../shared/measurements.md: a bare VGA frame, 1.40 s + 0.458 s/spp
    install_hint="pip install -e backends/cycles  (needs the bpy==5.0.1 wheel)",
    bench_variants=(("denoise", {"denoise": True}), ("adaptive", {"adaptive_threshold": 0.01})),
    bench_toggles=(("light-path budget", "light_path_budget"),),
)

__all__ = ["PLUGIN", "CyclesOptions"]
