"""From the real statistics to spec edits: what ``specsynth fit`` proposes.

Geometry comes from the real split alone: the intrinsics those of the camera most real images
were taken with; the camera's distance and elevation ranges are the 5th
to 95th percentiles over the real images of the object nearest each image's centre (the one a
specsynth camera would have aimed at), the in-plane range the images' own, the aim offset where
that object sits in its image, and the visibility
threshold the 10th percentile of every real instance's visible fraction. The sensor (exposure, tone
curve, saturation, blur, noise, image format) is fitted to a *probe*: a few images of the spec
rendered with a neutral sensor, which the sensor's own operations (``Camera.develop``: those of
``views.sensor``) are applied to offline until the probe's brightness, contrast, saturation,
sharpness and noise medians are the real ones; the numbers found are what the sensor block then
applies to every rendered image. Every edit carries the real statistic behind
it, which the fitted YAML shows as a comment.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from ..views.cameras import elevation_on_area
from .collect import Collected
from .distance import spread, summary
from .imagestats import (MIN_OBJECT_PIXELS, colourfulness, half_rgb8, halo, lab_of_linear, linear_of_lab, luma, noise_level,
                         percentiles, saturation, sharpness, srgb8_to_linear, vignetting)

VISIB_QUANTILE = 10
SEARCH_STEPS = 12  # bisection steps: 2^-12 of each range (0.0024 stops of exposure)
# A probe within 1 % of the real sharpness is not blurred: the 8-bit round trip of the exposure
# search alone moves the statistic by a few tenths of a percent.
SHARPNESS_TOLERANCE = 0.01
# The real images' medians the sensor is fitted to.
SENSOR_TARGETS = ("brightness", "contrast", "saturation", "sharpness", "halo", "noise", "vignetting")


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


def elevation_law_distances(values, lo: float, hi: float) -> dict[str, float]:
    """The 1-Wasserstein distance (degrees) between real elevations and each way of drawing them
    in [lo, hi]: through the quantile functions, at the real sample's own quantile levels."""
    x = np.sort(np.asarray(values, np.float64)[np.isfinite(values)])
    p = (np.arange(len(x)) + 0.5) / max(len(x), 1)
    laws = {"angle": lo + p * (hi - lo),
            "area": np.array([elevation_on_area(float(q), lo, hi) for q in p])}
    return {name: float(np.mean(np.abs(x - q))) if len(x) else 0.0 for name, q in laws.items()}


def geometry_edits(real: Collected, source: str) -> list[Edit]:
    """Camera ranges from the objects the real cameras aim at; the visibility threshold from every
    real instance."""
    aim, inst, ims = aimed_at(real), real.instances, real.images
    d, e, r, v = (summary(x) for x in (aim["distance"], aim["elevation"], ims["inplane"], inst["visib_fract"]))
    out = [
        Edit("cameras.distance", _range(aim["distance"], 5, 95, 0.01, 0.02, 1e4),
             f"fit: real distance to the central object 5-95 % {d['p5']:.2f}-{d['p95']:.2f} m (median "
             f"{d['median']:.2f}) in {source}"),
        Edit("cameras.elevation", elevation := _range(aim["elevation"], 5, 95, 1.0, -90, 90),
             f"fit: real elevation over the central object 5-95 % {e['p5']:.0f}-{e['p95']:.0f} deg (median "
             f"{e['median']:.0f}) in {source}"),
    ]
    if e["n"]:
        w = elevation_law_distances(aim["elevation"], *elevation)
        law = min(w, key=w.get)
        out.append(Edit("cameras.elevation_sampling", law,
                        f"fit: real elevations are {w['area']:.1f} deg from a draw over the sphere's area, "
                        f"{w['angle']:.1f} deg from a draw uniform in angle, in {source}"))
    if r["n"]:
        out.append(Edit("cameras.inplane", _range(ims["inplane"], 5, 95, 1.0, -360, 360),
                        f"fit: real in-plane rotation 5-95 % {r['p5']:.0f}-{r['p95']:.0f} deg in {source}"))
    off = np.asarray(ims.get("aim_offset", ()), np.float64)
    if np.isfinite(off).any():
        o = summary(off)
        out.append(Edit("cameras.aim_offset", _range(np.minimum(off, 1.0), 5, 95, 0.01, 0.0, 1.0),
                        f"fit: the object nearest the centre sits 5-95 % {o['p5']:.2f}-{o['p95']:.2f} of the way to "
                        f"the image's ellipse (median {o['median']:.2f}) in {source}"))
    vis = np.asarray(inst["visib_fract"], np.float64)
    if len(vis):
        t = float(np.clip(round(np.percentile(vis, VISIB_QUANTILE) / 0.05) * 0.05, 0.05, 0.9))
        out.append(Edit("visibility.threshold", round(t, 2),
                        f"fit: {VISIB_QUANTILE} % of real visible instances are less visible than "
                        f"{np.percentile(vis, VISIB_QUANTILE):.2f} (median {v['median']:.2f}) in {source}"))
    return out


CAMERA_FIELDS = ("width", "height", "fx", "fy", "cx", "cy")


def intrinsics_edits(cameras, spec_intrinsics, source: str) -> list[Edit]:
    """The real images' camera as the spec's ``intrinsics``: ``cameras`` gives each real image's
    (K, width, height); the one most images share is proposed, nothing when the spec has it."""
    from collections import Counter

    seen = Counter((int(w), int(h), *(round(float(v), 6) for v in (K[0][0], K[1][1], K[0][2], K[1][2])))
                   for K, w, h in cameras)
    if not seen:
        return []
    best, n = seen.most_common(1)[0]
    real = dict(zip(CAMERA_FIELDS, best))
    if all(abs(float(getattr(spec_intrinsics, k)) - v) <= 1e-6 * max(1.0, abs(v)) for k, v in real.items()):
        return []
    note = f"fit: the camera of {n} of {sum(seen.values())} real images in {source}"
    return [Edit(f"intrinsics.{k}", v, note) for k, v in real.items()]


# ---------------------------------------------------------------------- the sensor, on a probe


@dataclass
class Camera:
    """The sensor settings a fit searches, applied to a probe as ``views.sensor`` applies them:
    exposure, vignetting, blur, shot noise in linear light, then saturation, the sRGB encoding,
    the tone curve and sharpening."""

    stops: float = 0.0
    contrast: float = 1.0
    saturation: float = 1.0
    sigma: float = 0.0
    shot: float = 0.0
    sharpening: float = 0.0
    vignetting: float = 0.0

    def develop(self, x: np.ndarray, normal: np.ndarray | None = None) -> np.ndarray:
        from ..views.sensor import blur, process, vignette

        y = x * 2.0 ** self.stops
        if self.vignetting > 0:
            y = y * vignette(y.shape[0], y.shape[1], self.vignetting)[..., None]
        if self.sigma > 0:
            y = blur(y, self.sigma)
        if self.shot > 0 and normal is not None:
            y = y + self.shot * np.sqrt(np.maximum(y, 0.0)) * normal
        return process(np.clip(y, 0.0, None), self.saturation, self.contrast, self.sharpening)


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


def _stat(name: str, rgb8: np.ndarray) -> float:
    y_half = luma(half_rgb8(rgb8))
    if name == "brightness":
        return float(y_half.mean())
    if name == "contrast":
        p5, p95 = percentiles(y_half, (5, 95))
        return p95 - p5
    if name == "saturation":
        return saturation(half_rgb8(rgb8).astype(np.float32) / np.float32(255.0))
    if name == "colourfulness":
        return colourfulness(half_rgb8(rgb8).astype(np.float32) / np.float32(255.0))
    if name == "sharpness":
        return sharpness(luma(rgb8))
    if name == "halo":
        return halo(luma(rgb8))
    if name == "vignetting":
        return vignetting(y_half)
    return noise_level(luma(rgb8))


class Probe:
    """The probe in linear light and the noise drawn for each of its images, developed under a
    camera and measured in ``jobs`` processes (each image on its own: the numbers are those of one
    process). A context manager: the processes end with it."""

    def __init__(self, lin: list[np.ndarray], normals: list[np.ndarray] | None = None, jobs: int = 1):
        self.lin, self.normals = lin, normals if normals is not None else [None] * len(lin)
        self.jobs, self._pool = max(1, min(int(jobs), len(lin))), None

    def __enter__(self) -> "Probe":
        if self.jobs > 1:
            import multiprocessing

            # fork: the workers inherit the probe's arrays instead of receiving a pickled copy
            self._pool = multiprocessing.get_context("fork").Pool(self.jobs, _init_worker, (self.lin, self.normals))
        return self

    def __exit__(self, *exc) -> None:
        if self._pool is not None:
            self._pool.terminate()
            self._pool.join()
            self._pool = None

    def stats(self, cam: Camera, names: tuple[str, ...], noise: bool = True) -> list[tuple[float, ...]]:
        """Per image, ``names``' statistics of the probe developed by ``cam`` (with its noise)."""
        tasks = [(k, cam, names, noise) for k in range(len(self.lin))]
        if self._pool is None:
            return [_image_stats(self.lin[k], self.normals[k] if noise else None, cam, names) for k, *_ in tasks]
        return self._pool.map(_worker_stats, tasks, chunksize=max(1, len(tasks) // (4 * self.jobs)))

    def median(self, cam: Camera, stat: str, noise: bool = True) -> float:
        """The median ``stat`` of the probe developed by ``cam``."""
        return _median([v[0] for v in self.stats(cam, (stat,), noise)])


def _image_stats(x: np.ndarray, normal, cam: Camera, names: tuple[str, ...]) -> tuple[float, ...]:
    image = cam.develop(x, normal)
    return tuple(_stat(name, image) for name in names)


_WORKER_PROBE: dict[str, list] = {}  # a fit worker's probe (its process only, set once at its start)


def _init_worker(lin, normals) -> None:
    _WORKER_PROBE.update(lin=lin, normals=normals)


def _worker_stats(task) -> tuple[float, ...]:
    k, cam, names, noise = task
    return _image_stats(_WORKER_PROBE["lin"][k], _WORKER_PROBE["normals"][k] if noise else None, cam, names)


def _search(probe: Probe, cam: Camera, field: str, stat: str, lo: float, hi: float, target: float,
            increasing: bool) -> float:
    """The value of ``field`` within [lo, hi] that brings the probe's median ``stat`` to ``target``."""
    return _bisect(lambda v: probe.median(replace(cam, **{field: v}), stat), lo, hi, target, increasing)


# Sharpening amounts a fit tries, and how close to the real halo counts as there. A halo grows with
# the amount only so far (it clips at black and white), and blur and sharpening trade against each
# other: the fit takes the least sharpening that reaches the real halo.
SHARPENING_STEPS = tuple(float(v) for v in np.round(np.arange(0.0, 3.01, 0.25), 2))
HALO_TOLERANCE = 0.01


def _sharpening(probe: Probe, cam: Camera, target: float) -> float:
    """0 when the unsharpened probe's median halo is within ``HALO_TOLERANCE`` of ``target`` or above
    it; else the first of ``SHARPENING_STEPS`` whose probe median halo reaches ``target``, or the
    step before it when that one is nearer; the step with the largest halo when none does (the
    steps stop once the halo falls: past its peak, more sharpening clips more of it)."""
    tried: list[tuple[float, float]] = []
    for v in SHARPENING_STEPS:
        h = probe.median(replace(cam, sharpening=v), "halo")
        if h >= target - (HALO_TOLERANCE if v == 0 else 0.0):
            return tried[-1][0] if tried and abs(tried[-1][1] - target) < abs(h - target) else v
        if tried and h < tried[-1][1]:
            break
        tried.append((v, h))
    return max(tried, key=lambda t: t[1])[0]


MAX_VIGNETTING = 0.9


def _vignetting(probe: Probe, cam: Camera, target: float) -> float:
    """0 when the unvignetted probe's median corners are as dark as the real ones' (``target``) or
    darker, or either side does not say; else the amount, up to ``MAX_VIGNETTING``, that brings
    them there. The real corners are darker for the lens and for what the camera aims at: the probe
    is rendered with the fitted cameras, so it shows the second itself and the amount is the
    rest."""
    plain = probe.median(replace(cam, vignetting=0.0), "vignetting")
    if not np.isfinite(target) or not plain > target:  # (NaN: the probe's centres clip)
        return 0.0
    return _search(probe, cam, "vignetting", "vignetting", 0.0, MAX_VIGNETTING, target, False)


COLOUR_STATS = ("saturation", "colourfulness")
# The probe is 8-bit: a pixel that clips there has lost the colour, texture and noise that the
# exposure found would have kept (LM-O: the demo's probe at 0 stops clipped a channel in 18 % of its
# pixels, and the fit darkens it by 1.1 stops). A probe with more clipped pixels than this, which
# the fit darkens, is rendered again at the exposure found.
CLIPPED_LIMIT = 0.01


def clipped_share(probe_rgb8: list[np.ndarray]) -> float:
    """The median share of a probe image's pixels with a channel at 255."""
    return _median([float(np.mean(np.max(p, axis=2) >= 255)) for p in probe_rgb8])


def reprobe_exposure(probe_rgb8: list[np.ndarray], cam: "Camera") -> float | None:
    """The exposure (stops) to render the probe again at, or None when this probe can stand:
    it clips little, or the fit brightens it (what clipped stays clipped then too)."""
    if cam.stops < -0.25 and clipped_share(probe_rgb8) > CLIPPED_LIMIT:
        return round(cam.stops, 2)
    return None


def _colour_offset(probe: Probe, cam: Camera, real: Collected):
    """Saturation factor -> how far the probe's colour is from the real images', in real spreads:
    the offsets of its median HSV saturation and median colourfulness, summed. Both grow with the
    factor; matching one alone can leave the other far (dark pixels count fully in HSV saturation,
    barely in colourfulness)."""
    t = {k: _median(real.images[k]) for k in COLOUR_STATS}
    s = {k: spread(real.images[k]) for k in COLOUR_STATS}

    def offset(v: float) -> float:
        per_image = np.asarray(probe.stats(replace(cam, saturation=v), COLOUR_STATS))
        return sum((_median(per_image[:, i]) - t[k]) / s[k] for i, k in enumerate(COLOUR_STATS))
    return offset


def sensor_edits(real: Collected, probe_rgb8: list[np.ndarray], source: str, real_format: str | None,
                 seed: int = 0, probe_stops: float = 0.0, jobs: int = 1) -> tuple[list[Edit], Camera]:
    """Exposure and tone curve (searched in turn, twice: each moves the other's statistic), colour
    saturation (HSV saturation and colourfulness together), blur and shot noise that bring the
    probe's medians to the real ones, and the real images' format -> (the edits, the camera found,
    whose exposure is relative to the probe's ``probe_stops``). ``jobs``: processes developing the
    probe; the result is the same for any number. Vignetting is fitted on a probe that clips at
    most ``CLIPPED_LIMIT``: the bright levels it compares are what a clipped probe has lost (the
    real photographs through themselves at 1.9x clipped 10.6 % of their pixels, and the fit found
    0.27 of vignetting they do not have)."""
    lin = [srgb8_to_linear(p) for p in probe_rgb8]
    normals = [np.random.default_rng([seed, k]).standard_normal(x.shape) for k, x in enumerate(lin)]
    t = {k: _median(real.images.get(k, [])) for k in SENSOR_TARGETS}
    clipped = clipped_share(probe_rgb8)
    searched = {**t, "vignetting": t["vignetting"] if clipped <= CLIPPED_LIMIT else float("nan")}
    with Probe(lin, normals, jobs) as probe:
        cam, probe_s, probe_n = _fit_camera(real, probe, searched)
        return _edits(real, probe, cam, probe_s, probe_n, t, real_format, probe_stops, clipped), cam


def _fit_camera(real: Collected, probe: Probe, t: dict[str, float]) -> tuple[Camera, float, float]:
    """The camera that brings the probe's medians to the real ones (``t``) -> (it, the probe's
    sharpness unblurred, the probe's noise without shot noise)."""
    cam = Camera()
    for _ in range(2):  # each setting moves the others' statistics a little: a second pass settles them
        for _ in range(2):
            cam.stops = _search(probe, cam, "stops", "brightness", -5.0, 5.0, t["brightness"], True)
            cam.contrast = _search(probe, cam, "contrast", "contrast", 1.0, 3.0, t["contrast"], True)
        # After the exposure: at another, clipped centres would make the corners look relatively bright
        cam.vignetting = _vignetting(probe, cam, t["vignetting"])
        cam.saturation = _bisect(_colour_offset(probe, cam, real), 0.5, 2.5, 0.0, True)
        # Sharpening, then the blur that brings the sharpened edges to the real width; in turn,
        # twice: blur takes halos away, sharpening steepens edges.
        for _ in range(2 if np.isfinite(t["halo"]) else 1):
            if np.isfinite(t["halo"]):
                cam.sharpening = _sharpening(probe, cam, t["halo"])
            probe_s = probe.median(replace(cam, sigma=0.0), "sharpness")
            cam.sigma = 0.0
            if probe_s > t["sharpness"] * (1.0 + SHARPNESS_TOLERANCE):
                cam.sigma = _search(probe, cam, "sigma", "sharpness", 0.0, 4.0, t["sharpness"], False)
        probe_n = probe.median(replace(cam, shot=0.0), "noise", noise=False)
        cam.shot = _search(probe, cam, "shot", "noise", 0.0, 0.2, t["noise"], True) if probe_n < t["noise"] else 0.0
    return cam, probe_s, probe_n


def _edits(real: Collected, probe: Probe, cam: Camera, probe_s: float, probe_n: float, t: dict[str, float],
           real_format, probe_stops: float, clipped: float = 0.0) -> list[Edit]:
    real_b = summary(real.images["brightness"])
    probe_b = summary([v[0] for v in probe.stats(cam, ("brightness",), noise=False)])
    width = _stops_spread(real_b) - _stops_spread(probe_b)
    half = round(max(0.0, width) / 2.0, 2)
    sigma = round(cam.sigma, 2)
    stops = probe_stops + cam.stops
    out = [
        Edit("sensor.exposure", [round(max(-5.0, stops - half), 2), round(min(5.0, stops + half), 2)],
             f"fit: real brightness median {t['brightness']:.3f} (5-95 % {real_b['p5']:.2f}-{real_b['p95']:.2f}); "
             f"the probe needs {stops:+.2f} stops"),
        Edit("sensor.contrast", round(cam.contrast, 2), f"fit: real luma range (5-95 %) median {t['contrast']:.3f}"),
        Edit("sensor.saturation", round(cam.saturation, 2), f"fit: real saturation median {t['saturation']:.3f}, "
             f"colourfulness {_median(real.images['colourfulness']):.3f}"),
        Edit("sensor.blur", [round(0.75 * sigma, 2), round(1.25 * sigma, 2)] if sigma > 0 else None,
             f"fit: real edge sharpness median {t['sharpness']:.3f}, the probe's {probe_s:.3f}: "
             f"{'a blur of ' + format(sigma, '.2f') + ' px' if sigma else 'no blur'}"),
        Edit("sensor.shot_noise", round(cam.shot, 4),
             f"fit: real noise median {t['noise']:.2f} levels, the probe's {probe_n:.2f}"),
    ]
    if np.isfinite(t["halo"]):
        probe_halo = probe.median(cam, "halo")
        out.append(Edit("sensor.sharpening", cam.sharpening,
                        f"fit: real sharpening halo median {t['halo']:.3f}, the probe's {probe_halo:.3f}"))
    if np.isfinite(t["vignetting"]):
        seen = (f"the probe's {probe.median(replace(cam, vignetting=0.0), 'vignetting'):.3f} unvignetted"
                if clipped <= CLIPPED_LIMIT else f"not fitted: the probe clips {100 * clipped:.1f} % of its pixels")
        out.append(Edit("sensor.vignetting", round(cam.vignetting, 2),
                        f"fit: real corners' bright level median {t['vignetting']:.3f} of the centre's, {seen}"))
    if real_format == "png":
        out.append(Edit("outputs.image_format", "png", "fit: the real images are PNG (lossless)"))
    return out


# ---------------------------------------------------------------------- the objects' colours

OBJECT_STEPS = 4  # multiplicative updates of each object's colour gain
MIN_INSTANCES = 3  # an object is fitted when the probe and the real split each show it this often


def _object_colours(probe, cam: Camera, gains: dict[int, np.ndarray]) -> dict[int, list[np.ndarray]]:
    """Each object's mean linear colour inside its visible masks, per probe instance, with its gain
    applied to its rendered pixels and the probe developed through ``cam``."""
    out: dict[int, list[np.ndarray]] = {}
    for rgb8, instances in probe:
        x = srgb8_to_linear(rgb8)
        for obj_id, mask in instances:
            x[mask] *= gains.get(obj_id, 1.0)
        dev = srgb8_to_linear(cam.develop(x))
        for obj_id, mask in instances:
            if mask.sum() >= MIN_OBJECT_PIXELS:
                out.setdefault(obj_id, []).append(dev[mask].mean(0))
    return out


def _median_lab(colours) -> np.ndarray:
    return np.median(np.array([lab_of_linear(c) for c in colours]), axis=0)


def object_gains(real: Collected, probe, cam: Camera) -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per object shown often enough on both sides: the colour gain (linear, per channel) that brings
    its median CIELAB colour in the developed probe to the real one -> {obj_id: (gain, real Lab,
    probe Lab before)}. The rendered pixels are scaled (a gain on the albedo scales the light the
    object returns), developed, measured, and the gain updated, ``OBJECT_STEPS`` times."""
    ids = np.asarray(real.objects["obj_id"])
    targets = {}
    for obj_id in sorted(set(ids.tolist())):
        k = ids == obj_id
        if k.sum() >= MIN_INSTANCES:
            targets[obj_id] = np.array([np.median(real.objects[c][k]) for c in ("obj_lightness", "obj_a", "obj_b")])
    gains = {i: np.ones(3) for i in targets}
    before = {i: _median_lab(c) for i, c in _object_colours(probe, cam, {}).items() if len(c) >= MIN_INSTANCES}
    for _ in range(OBJECT_STEPS):
        seen = _object_colours(probe, cam, gains)
        for obj_id in targets:
            if len(seen.get(obj_id, ())) >= MIN_INSTANCES:
                want, have = linear_of_lab(*targets[obj_id]), linear_of_lab(*_median_lab(seen[obj_id]))
                # A channel near 0 (a yellow duck's blue) says little and would swing the gain: floored.
                want, have = (np.maximum(c, 0.03 * max(c.max(), 1e-4)) for c in (want, have))
                gains[obj_id] = np.clip(gains[obj_id] * (want / have) ** 0.8, 0.25, 4.0)
    return {i: (gains[i], targets[i], before[i]) for i in targets if i in before}


def object_edits(real: Collected, probe, cam: Camera, materials: dict, source: str) -> list[Edit]:
    """``objects.materials.<obj_id>`` with a fitted ``color_gain``, keeping what the spec gave that
    object (its own entry, else the default's: the most specific entry is the only one used). The
    probe was rendered with the spec's own gain: the one found multiplies it."""
    out = []
    for obj_id, (gain, want, had) in sorted(object_gains(real, probe, cam).items()):
        base = materials.get(str(obj_id)) or materials.get("default") or {}
        entry = {k: v for k, v in base.items() if k != "color_gain"}
        total = np.clip(np.asarray(base.get("color_gain", (1.0, 1.0, 1.0))) * gain, 0.1, 4.0)
        entry["color_gain"] = [round(float(g), 3) for g in total]
        out.append(Edit(f"objects.materials.{obj_id}", entry,
                        f"fit: real L*a*b* {want[0]:.0f} {want[1]:+.0f} {want[2]:+.0f}, the probe's "
                        f"{had[0]:.0f} {had[1]:+.0f} {had[2]:+.0f} in {source}"))
    return out


def _stops_spread(s: dict) -> float:
    """The 5-95 % range of a brightness sample in stops of linear light."""
    lo, hi = (float(srgb8_to_linear(np.array([v * 255.0]))[0]) for v in (s["p5"], s["p95"]))
    return math.log2(hi / lo) if lo > 0 and hi > 0 else 0.0
