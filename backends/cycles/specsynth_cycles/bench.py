"""What `specsynth bench` tries on Cycles beyond the quality levels (read by specsynth.run.bench only)."""

from specsynth.run.bench import BenchSettings

BENCH = BenchSettings(
    variants=(("denoise", {"denoise": True}),
              ("denoise-accurate", {"denoise": True, "denoise_prefilter": "accurate"}),
              ("denoise-fast", {"denoise": True, "denoise_prefilter": "fast", "denoise_quality": "balanced"}),
              ("adaptive", {"adaptive_threshold": 0.01}),
              # the ladder's denoise@128 with adaptive sampling: where it stops a pixel, OIDN takes over
              ("adaptive+denoise@128", {"denoise": True, "samples": 128, "adaptive_threshold": 0.03}),
              # against the ladder's denoise@16 (bench --ladder): the same samples, guided
              ("guided@16", {"denoise": True, "samples": 16, "guiding": True})),
    toggles=(("light-path budget", "light_path_budget"),),
)
