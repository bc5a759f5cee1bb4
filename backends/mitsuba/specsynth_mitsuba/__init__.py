"""Mitsuba 3 as a specsynth backend plugin.

Importing this package does not import Mitsuba: the variant is chosen, and Mitsuba imported, when
a ``MitsubaBackend`` is constructed (once per worker process).
"""

from specsynth.plugins import BackendPlugin, Capabilities

from .options import MitsubaOptions


def samples_taken(options: MitsubaOptions, n: int) -> int:
    """The samples per pixel Mitsuba renders when asked for ``n`` (``mapping.round_spp``): its
    stratified sampler takes the next square, ldsampler the next power of four (at least 4),
    multijitter a grid of isqrt(n) rows, orthogonal the square of a prime, independent ``n``."""
    from .mapping import round_spp  # numbers only: Mitsuba is not imported

    return round_spp(n, options.sampler)


PLUGIN = BackendPlugin(
    name="mitsuba",
    default_rank=10,  # specsynth init's choice when several backends are installed
    options=MitsubaOptions,
    backend="specsynth_mitsuba.backend:MitsubaBackend",
    capabilities=Capabilities(
        draws_scene=True, denoise=True, sampling_noise=True, gpu=True,  # cuda_ad_rgb where a GPU and its driver exist
        depth_of_field=True, motion_blur=True,  # the exact-K sensor's thin lens and motion (JIT variants)
        material_channels=frozenset({"base_color", "roughness", "metallic", "normal", "emission", "opacity"}),
        quality="path tracer, samples = max(AA, diffuse rays, specular rays); max_depth from the preset",
    ),
    distributions=("mitsuba", "drjit", "pyoidn"),
    # 2: exact K sensor for fy != fx, stratified sampler, albedo calibrated to Cycles, sky units,
    # see-through area lights. 3: calibrated quality levels. 4: denoiser guides from their own pass.
    # 5: the guides at the beauty's samples and seed. 6: the guides at up to 16x the beauty's
    # samples (at most 64), its seed.
    revision=6,
    cost=(0.11, 0.122),
    checks="specsynth_mitsuba.checks:checks",  # `specsynth doctor`
    install_hint="pip install -e backends/mitsuba  (and, for the LLVM variant, apt-get install libllvm19)",
    # At full VGA on the demo's first two views, emitters picked by power (docs/quality.md, "The
    # calibration run"): paper medium 25.59 dB in 22.5 s, 1 spp + OIDN 30.76 dB in 3.0 s; paper
    # high 33.44 dB in 176 s, 9 spp + OIDN 34.27 dB in 8.2 s (4 spp: 32.34; 4 at twice the
    # resolution 34.19 in 16.3 s). The stratified sampler renders squares only. Picked uniformly,
    # 9 spp had reached 32.93 dB and `high` needed 16.
    calibrated={"medium": {"samples": 1, "denoise": True, "emitter_sampling": "power"},
                "high": {"samples": 9, "denoise": True, "emitter_sampling": "power"}},
    sampling_options=("emitter_sampling",),  # an error target's renders pick emitters as the preset does
    sample_counts=samples_taken,  # quality.control: error plans with the counts the sampler takes
)

__all__ = ["PLUGIN", "MitsubaOptions"]
