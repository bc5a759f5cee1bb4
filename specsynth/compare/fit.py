"""From the real statistics to spec edits: what ``specsynth fit`` proposes.

Geometry comes from the real split alone: the camera's distance and elevation ranges are the 5th
to 95th percentiles over the real images of the object nearest each image's centre (the one a
specsynth camera would have aimed at), the in-plane range the images' own, and the visibility
threshold the 10th percentile of every real instance's visible fraction. The sensor (exposure, blur, noise, image format) is fitted to a
*probe*: a few images of the spec rendered as it is, which the sensor's own operations (linear
exposure, Gaussian blur, shot noise, then the 8-bit encoding) are applied to offline until the
probe's brightness, sharpness and noise medians are the real ones; the numbers found are what the
sensor block then applies to every rendered image. Every edit carries the real statistic behind
it, which the fitted YAML shows as a comment.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from .collect import Collected
from .distance import summary
from .imagestats import luma, noise_level, sharpness, srgb8_to_linear

VISIB_QUANTILE = 10
SEARCH_STEPS = 18  # bisection steps: 2^-18 of each range
# A probe within 1 % of the real sharpness is not blurred: the 8-bit round trip of the exposure
# search alone moves the statistic by a few tenths of a percent.
SHARPNESS_TOLERANCE = 0.01


@dataclass(frozen=True)
class Edit:
    field: str  # dotted path in the spec
    value: Any
    comment: str  # the real statistic behind it


def _range(values, lo_pct: float, hi_pct: float, step: float, lo: float, hi: float) -> list[float]:
    a = np.asarray(values, np.float64)
    a = a[np.isfinite(a)]
    p_lo, p_hi = np.percentile(a, (lo_pct, hi_pct))
    r = [min(max(round(p_lo / step) * step, lo), hi), min(max(round(p_hi / step) * step, lo), hi)]
    return [round(x, 6) for x in r]


def aimed_at(real: Collected) -> dict[str, np.ndarray]:
    """Per image, the instance nearest the image centre: the object a specsynth camera would have
    aimed at (it puts that object's origin on the principal point). Its distance and elevation are
    what ``cameras.distance`` and ``cameras.elevation`` draw; every visible instance's would be
    wider, because the other objects lie around it."""
    inst = real.instances
    if not len(inst["image"]):
        return {"distance": np.zeros(0), "elevation": np.zeros(0)}
    order = np.lexsort((inst["centre_offset"], inst["image"]))  # by image, then nearest the centre first
    first = order[np.r_[True, np.diff(inst["image"][order]) != 0]]
    return {"distance": inst["distance"][first], "elevation": inst["elevation"][first]}


def geometry_edits(real: Collected, source: str) -> list[Edit]:
    """Camera ranges from the objects the real cameras aim at; the visibility threshold from every
    real instance."""
    aim, inst, ims = aimed_at(real), real.instances, real.images
    d, e, r, v = (summary(x) for x in (aim["distance"], aim["elevation"], ims["inplane"], inst["visib_fract"]))
    out = [
        Edit("cameras.distance", _range(aim["distance"], 5, 95, 0.01, 0.02, 1e4),
             f"fit: real distance to the central object 5-95 % {d['p5']:.2f}-{d['p95']:.2f} m (median "
             f"{d['median']:.2f}) in {source}"),
        Edit("cameras.elevation", _range(aim["elevation"], 5, 95, 1.0, -90, 90),
             f"fit: real elevation over the central object 5-95 % {e['p5']:.0f}-{e['p95']:.0f} deg (median "
             f"{e['median']:.0f}) in {source}"),
    ]
    if r["n"]:
        out.append(Edit("cameras.inplane", _range(ims["inplane"], 5, 95, 1.0, -360, 360),
                        f"fit: real in-plane rotation 5-95 % {r['p5']:.0f}-{r['p95']:.0f} deg in {source}"))
    vis = np.asarray(inst["visib_fract"], np.float64)
    if len(vis):
        t = float(np.clip(round(np.percentile(vis, VISIB_QUANTILE) / 0.05) * 0.05, 0.05, 0.9))
        out.append(Edit("visibility.threshold", round(t, 2),
                        f"fit: {VISIB_QUANTILE} % of real visible instances are less visible than "
                        f"{np.percentile(vis, VISIB_QUANTILE):.2f} (median {v['median']:.2f}) in {source}"))
    return out


# ---------------------------------------------------------------------- the sensor, on a probe


def _encode(x: np.ndarray) -> np.ndarray:
    from ..model.colour import linear_to_srgb8

    return linear_to_srgb8(np.clip(x, 0.0, None).astype(np.float32))


def _median(values) -> float:
    a = np.asarray(values, np.float64)
    a = a[np.isfinite(a)]
    return float(np.median(a)) if len(a) else float("nan")


def _bisect(f, lo: float, hi: float, target: float, increasing: bool) -> float:
    """x in [lo, hi] with f(x) = target for a monotonic f (the nearer end when out of reach)."""
    f_lo, f_hi = f(lo), f(hi)
    if increasing and target <= f_lo or not increasing and target >= f_lo:
        return lo
    if increasing and target >= f_hi or not increasing and target <= f_hi:
        return hi
    for _ in range(SEARCH_STEPS):
        mid = 0.5 * (lo + hi)
        if (f(mid) < target) == increasing:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def _luma_mean(x: np.ndarray) -> float:
    return float(luma(_encode(x)).mean())


def sensor_edits(real: Collected, probe_rgb8: list[np.ndarray], source: str, real_format: str | None,
                 seed: int = 0) -> list[Edit]:
    """Exposure, blur and shot noise that bring the probe's medians to the real ones, in that order
    (each search holds the ones before it), and the real images' format."""
    from ..views.sensor import blur

    lin = [srgb8_to_linear(p) for p in probe_rgb8]
    out: list[Edit] = []
    target_b = _median(real.images["brightness"])
    stops = _bisect(lambda e: _median([_luma_mean(x * 2.0 ** e) for x in lin]), -5.0, 5.0, target_b, True)
    exposed = [x * 2.0 ** stops for x in lin]
    real_b = summary(real.images["brightness"])
    width = _stops_spread(real_b) - _stops_spread(summary([_luma_mean(x) for x in exposed]))
    half = round(max(0.0, width) / 2.0, 2)
    ex = [round(max(-5.0, stops - half), 2), round(min(5.0, stops + half), 2)]
    out.append(Edit("sensor.exposure", ex, f"fit: real brightness median {target_b:.3f} (5-95 % {real_b['p5']:.2f}-"
                                           f"{real_b['p95']:.2f}); the probe needs {stops:+.2f} stops"))
    target_s = _median(real.images["sharpness"])
    probe_s = _median([sharpness(luma(_encode(x))) for x in exposed])
    sigma = 0.0
    if probe_s > target_s * (1.0 + SHARPNESS_TOLERANCE):
        sigma = _bisect(lambda s: _median([sharpness(luma(_encode(blur(x, s)))) for x in exposed]), 0.0, 4.0,
                        target_s, False)
    sigma = round(sigma, 2)
    blurred = [blur(x, sigma) for x in exposed]
    out.append(Edit("sensor.blur", [round(0.75 * sigma, 2), round(1.25 * sigma, 2)] if sigma > 0 else None,
                    f"fit: real edge sharpness median {target_s:.3f}, the probe's {probe_s:.3f}: "
                    f"{'a blur of ' + format(sigma, '.2f') + ' px' if sigma else 'no blur'}"))
    target_n = _median(real.images["noise"])
    rng = np.random.default_rng(seed)
    normals = [rng.standard_normal(x.shape) for x in blurred]

    def noise_with(k: float) -> float:
        return _median([noise_level(luma(_encode(x + k * np.sqrt(np.maximum(x, 0.0)) * n)))
                        for x, n in zip(blurred, normals)])

    probe_n = noise_with(0.0)
    shot = _bisect(noise_with, 0.0, 0.2, target_n, True) if probe_n < target_n else 0.0
    out.append(Edit("sensor.shot_noise", round(shot, 4),
                    f"fit: real noise median {target_n:.2f} levels, the probe's {probe_n:.2f}"))
    if real_format == "png":
        out.append(Edit("outputs.image_format", "png", "fit: the real images are PNG (lossless)"))
    return out


def _stops_spread(s: dict) -> float:
    """The 5-95 % range of a brightness sample in stops of linear light."""
    lo, hi = (float(srgb8_to_linear(np.array([v * 255.0]))[0]) for v in (s["p5"], s["p95"]))
    return math.log2(hi / lo) if lo > 0 and hi > 0 else 0.0
