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
    # At full VGA on the demo's first two views (docs/quality.md, "The calibration run"): paper
    # medium 25.59 dB in 24 s, 1 spp + OIDN 28.87 dB in 3.0 s; paper high 33.44 dB in 167 s, 16 spp
    # + OIDN 33.95 dB in 15 s (9 spp: 32.93). The stratified sampler renders squares only. At twice
    # the resolution (docs/quality.md, "Supersampling") 4 spp were short (32.55 dB) and 9 slower (40 s).
    calibrated={"medium": {"samples": 1, "denoise": True}, "high": {"samples": 16, "denoise": True}},
    sample_counts=samples_taken,  # quality.control: error plans with the counts the sampler takes
)

__all__ = ["PLUGIN", "MitsubaOptions"]
