"""Mitsuba 3 as a specsynth backend plugin.

Importing this package does not import Mitsuba: the variant is chosen, and Mitsuba imported, when
a ``MitsubaBackend`` is constructed (once per worker process).
"""

from specsynth.plugins import BackendPlugin, Capabilities

from .options import MitsubaOptions

PLUGIN = BackendPlugin(
    name="mitsuba",
    options=MitsubaOptions,
    backend="specsynth_mitsuba.backend:MitsubaBackend",
    capabilities=Capabilities(
        draws_scene=True, denoise=True, gpu=True,  # cuda_ad_rgb where a GPU and its driver exist
        material_channels=frozenset({"base_color", "roughness", "metallic", "normal", "emission", "opacity"}),
        quality="path tracer, samples = max(AA, diffuse rays, specular rays); max_depth from the preset",
    ),
    distributions=("mitsuba", "drjit"),
    # 2: exact K sensor for fy != fx, stratified sampler, albedo calibrated to Cycles, sky units,
    # see-through area lights.
    revision=2,
    cost=(0.11, 0.122),
    install_hint="pip install -e backends/mitsuba  (and, for the LLVM variant, apt-get install libllvm19)",
    bench_variants=(("denoise", {"denoise": True}), ("independent", {"sampler": "independent"}),
                    ("ldsampler", {"sampler": "ldsampler"})),
)

__all__ = ["PLUGIN", "MitsubaOptions"]
