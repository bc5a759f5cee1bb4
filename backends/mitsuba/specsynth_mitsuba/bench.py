"""What `specsynth bench` tries on Mitsuba beyond the quality levels (read by specsynth.run.bench only)."""

from specsynth.run.bench import BenchSettings

BENCH = BenchSettings(
    variants=(("denoise", {"denoise": True}), ("independent", {"sampler": "independent"}),
              ("ldsampler", {"sampler": "ldsampler"}), ("multijitter", {"sampler": "multijitter"}),
              ("orthogonal", {"sampler": "orthogonal"}),
              # the level's preset with the calibrated levels' emitter choice: what the paper's
              # error would be if the preset picked emitters by power (docs/performance.md)
              ("power", {"emitter_sampling": "power"})),
)
