"""Pure numbers: how specsynth's IR and quality presets become Mitsuba 3 parameters.

Nothing here imports Mitsuba, so the mapping is testable (and documented) without a renderer.
See docs/backends/mitsuba.md for the tables these functions implement.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from specsynth.model.colour import REC709_LUMA
from specsynth.spec.models import QualityPreset

# Mitsuba's envmap is Y-up with its own longitude origin; these rows make a Z-up world map the
# equirectangular image the way Blender's world does (measured: a wrong choice costs ~7 dB).
ENVMAP_BASIS = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])

# LightIR emits along local -Z; Mitsuba's rectangle/spot emit along local +Z. A half turn about X
# (not a mirror) keeps the frame right-handed so shape normals are not flipped by a det < 0.
_HALF_TURN_X = np.diag([1.0, -1.0, -1.0, 1.0])


@dataclass(frozen=True)
class IntegratorSettings:
    spp: int  # samples per pixel actually taken (after the sampler's rounding)
    requested_spp: int  # before rounding
    max_depth: int  # Mitsuba's count: 1 = emitters seen directly, 2 = direct lighting
    rr_depth: int
    sampler: str


def mitsuba_max_depth(preset: QualityPreset) -> int:
    """Arnold/Cycles count indirect bounces; Mitsuba counts path vertices including the camera
    hit and the light: max_depth 2 is direct lighting only, so n bounces = n + 2."""
    return preset.max_depth + 2


def round_spp(spp: int, sampler: str) -> int:
    """The count Mitsuba's sampler will really take (it rounds with a warning; we round first so
    stats and content are honest). ldsampler needs a square power of two (4**k), stratified a
    perfect square, multijitter a grid of isqrt(n) rows, orthogonal the square of a prime (at least
    4); each rule checked against Mitsuba's own count for 1-399 (the backend's tests)."""
    spp = max(1, int(spp))
    if sampler == "ldsampler":
        n = 4
        while n < spp:
            n *= 4
        return n
    if sampler == "stratified":
        r = math.isqrt(spp)
        return spp if r * r == spp else (r + 1) ** 2
    if sampler == "multijitter":
        rows = math.isqrt(spp)
        return rows * -(-spp // rows)
    if sampler == "orthogonal":
        p = 2
        while p * p < spp or any(p % k == 0 for k in range(2, math.isqrt(p) + 1)):
            p += 1
        return p * p
    return spp


GUIDE_SAMPLES = 64  # samples per pixel the denoiser's guides take at most
GUIDE_FACTOR = 16  # ... and at most this many times the image's


def guide_samples(spp: int) -> int:
    """Samples per pixel of the denoiser's guide pass for an image of ``spp``: at least the image's
    (guides from fewer put other antialiased edges into it), up to 16x them and 64. The pass traces
    one ray per sample, so cleaner guides are cheap, and OIDN, taking them as clean, then keeps the
    true edges and texture where a few samples leave them noisy. Measured on two demo views at
    320x240 (OIDN ``high``, guides taken as clean): 1 spp 20.96 -> 27.51 dB, 4 spp 27.14 -> 29.44,
    16 spp 32.05/31.08 -> 32.54/31.68, 36 spp 33.33/32.60 -> 33.47/32.77, for 0.01-0.09 s more per
    image (144 or 256 guide samples added at most 0.05 dB). The backend then rounds the count up
    to one its sampler takes (``round_spp``): the same for stratified and ldsampler, 49 or 121 with
    orthogonal."""
    spp = max(1, int(spp))
    return max(spp, min(GUIDE_SAMPLES, GUIDE_FACTOR * spp))


def integrator_settings(preset: QualityPreset, sampler: str = "independent", samples: int | None = None) -> IntegratorSettings:
    # A unidirectional path tracer takes one diffuse and one specular continuation per camera
    # sample, so matching the preset's per-pixel ray budget needs max(camera, diffuse, specular)
    # samples: 1 / 36 / 225 for low / medium / high.
    requested = samples if samples is not None else preset.samples
    depth = mitsuba_max_depth(preset)
    # Russian roulette never starts inside the preset's depth: the presets are short, and RR there
    # only adds noise (it is unbiased, so the mean is unchanged either way).
    return IntegratorSettings(
        spp=round_spp(requested, sampler), requested_spp=int(requested), max_depth=depth, rr_depth=depth, sampler=sampler
    )


@dataclass(frozen=True)
class SensorSettings:
    x_fov: float  # degrees, along the image width
    ppo_x: float  # principal point offset, fraction of the width
    ppo_y: float  # fraction of the height
    fy_error_px: float  # worst vertical reprojection error the square-pixel sensor makes (px)


def sensor_settings(K: np.ndarray, width: int, height: int) -> SensorSettings:
    """Mitsuba's perspective sensor from an OpenCV K.

    Mitsuba traces film position x (pixels, pixel i spans [i, i+1]) as a centred pinhole would
    trace x + ppo * W, i.e. along (x + ppo W - W/2) / f. OpenCV pixel centres are integers, so
    x = u + 0.5, and equating with (u - cx) / f gives ppo = 0.5 - (cx + 0.5) / W (same in y,
    both with y down because specsynth's Mitsuba frame flips X and Y).
    The sensor has square pixels: fx sets the fov and fy != fx cannot be expressed (reported).
    """
    K = np.asarray(K, dtype=np.float64)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    x_fov = math.degrees(2.0 * math.atan(width / (2.0 * fx)))
    ppo_x = 0.5 - (cx + 0.5) / width
    ppo_y = 0.5 - (cy + 0.5) / height
    # farthest row from the principal point, times the relative focal mismatch
    worst_dy = max(cy + 0.5, height - (cy + 0.5))
    fy_err = abs(fy - fx) / fy * worst_dy
    skew_err = abs(K[0, 1]) / fy * worst_dy
    return SensorSettings(x_fov=x_fov, ppo_x=ppo_x, ppo_y=ppo_y, fy_error_px=float(fy_err + skew_err))


def rectangle_to_world(pose: np.ndarray, size: tuple[float, float]) -> np.ndarray:
    """Mitsuba's rectangle spans [-1,1]^2 with normal +Z; an IR area light spans size and emits -Z."""
    S = np.diag([size[0] / 2.0, size[1] / 2.0, 1.0, 1.0])
    return np.asarray(pose, dtype=np.float64) @ _HALF_TURN_X @ S


def emitter_to_world(pose: np.ndarray) -> np.ndarray:
    """Spot lights: IR local -Z becomes Mitsuba local +Z."""
    return np.asarray(pose, dtype=np.float64) @ _HALF_TURN_X


def area_radiance(power: float, size: tuple[float, float], color) -> list[float]:
    """A one-sided Lambertian emitter of power P and area A has radiance P / (A pi) (Blender's
    area-light watts, measured to match Cycles)."""
    area = float(size[0]) * float(size[1])
    return [float(c) * power / (area * math.pi) for c in color]


def point_intensity(power: float, color) -> list[float]:
    """Isotropic point of power P: intensity P / (4 pi) W/sr. Spots use the same (Blender
    defines spot power as that of the point light it would be without its cone)."""
    return [float(c) * power / (4.0 * math.pi) for c in color]


def envmap_to_world(rotation_z_deg: float) -> np.ndarray:
    """Rotating the environment by +theta about world Z moves what was seen along d to Rz d."""
    t = math.radians(rotation_z_deg)
    c, s = math.cos(t), math.sin(t)
    T = np.eye(4)
    T[:3, :3] = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ ENVMAP_BASIS
    return T


def sun_direction(elevation_deg: float, azimuth_deg: float) -> list[float]:
    """Direction *towards* the sun, world Z up, in Blender's sky convention (the Cycles backend
    passes azimuth as the sky's sun rotation): azimuth 0 puts the sun towards +Y, and positive
    azimuth turns it counter-clockwise seen from above (towards -X)."""
    el, az = math.radians(elevation_deg), math.radians(azimuth_deg) + math.pi / 2.0
    return [math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)]


def spot_angles(spot_angle_deg: float, blend: float) -> tuple[float, float]:
    """(cutoff_angle, beam_width) in degrees. Blender fades a spot over the outer ``blend``
    fraction of the cone measured in cosine (from cos(half) to cos(half) + blend (1 - cos(half)));
    Mitsuba is flat inside beam_width and falls off linearly in angle to zero at cutoff. Matching
    the fade's start makes the two agree at both ends of the edge (not its shape)."""
    half = math.radians(spot_angle_deg / 2.0)
    b = min(max(blend, 0.0), 1.0)
    c = math.cos(half)
    beam = math.acos(min(1.0, c + b * (1.0 - c)))
    return math.degrees(half), math.degrees(beam)


def fold_seed(seed: int) -> int:
    """Job seeds are 64-bit; Mitsuba's sampler seed is 32-bit. Fold both halves in so seeds that
    differ only in their high bits still give different images."""
    seed = int(seed) & 0xFFFFFFFFFFFFFFFF
    return (seed ^ (seed >> 32)) & 0xFFFFFFFF


# ----------------------------------------------------------------------------- Cycles agreement
# Measured against the Cycles backend (benchmarks/breakdown_backends.py; before/after numbers in the
# README, "Cycles vs Mitsuba on the built-in scenes").

# White-furnace albedo of a dielectric Principled BSDF (metallic 0, no transmission), measured by
# ``benchmarks/breakdown_backends.py --furnace --spp 256`` (Blender 5.0.1, Mitsuba 3.9.1): a smooth
# unit sphere in a radiance-1 world, mean over its disc = albedo averaged over cosine-weighted
# directions. Both are linear in the base colour: albedo = slope * base + intercept.
# - Blender: intercept = specular-layer albedo E_B(roughness, specular), slope = 1 - E_B (its
#   diffuse is Lambertian under an energy-conserving specular layer; measured slope + intercept =
#   1 within 0.15 %).
# - Mitsuba ``principled``: intercept E_M(roughness, specular) (single-scattering GGX; within 1 % of
#   E_B up to roughness 0.4, 14 % under at roughness 1: no multiple scattering), slope D_M(roughness)
#   = the albedo of Burley's diffuse (0.97 at roughness 0 to 1.04 at 1, retro-reflection), not
#   reduced by the specular layer on top. At roughness 0.9, specular 0.5 (most walls) Mitsuba
#   reflected 5.3 % more than Blender at base 0.5, compounding over a room's interreflections.
CALIB_ROUGHNESS = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)
CALIB_SPECULAR = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)
BLENDER_SPECULAR_ALBEDO = (  # rows: roughness, columns: specular
    (0.0000, 0.0184, 0.0307, 0.0413, 0.0511, 0.0603, 0.0691, 0.0776, 0.0859, 0.0940, 0.1019),
    (0.0000, 0.0184, 0.0307, 0.0414, 0.0511, 0.0603, 0.0691, 0.0776, 0.0859, 0.0940, 0.1019),
    (0.0000, 0.0185, 0.0308, 0.0414, 0.0511, 0.0603, 0.0691, 0.0775, 0.0858, 0.0939, 0.1018),
    (0.0000, 0.0182, 0.0302, 0.0406, 0.0502, 0.0592, 0.0679, 0.0762, 0.0844, 0.0924, 0.1002),
    (0.0000, 0.0168, 0.0282, 0.0381, 0.0473, 0.0559, 0.0643, 0.0724, 0.0803, 0.0881, 0.0957),
    (0.0000, 0.0145, 0.0248, 0.0338, 0.0423, 0.0504, 0.0582, 0.0658, 0.0732, 0.0806, 0.0878),
    (0.0000, 0.0120, 0.0209, 0.0289, 0.0364, 0.0437, 0.0508, 0.0577, 0.0645, 0.0713, 0.0780),
    (0.0000, 0.0096, 0.0170, 0.0239, 0.0304, 0.0368, 0.0430, 0.0491, 0.0552, 0.0612, 0.0672),
    (0.0000, 0.0075, 0.0136, 0.0193, 0.0248, 0.0302, 0.0355, 0.0407, 0.0459, 0.0511, 0.0562),
    (0.0000, 0.0058, 0.0107, 0.0153, 0.0198, 0.0242, 0.0285, 0.0329, 0.0372, 0.0415, 0.0459),
    (0.0000, 0.0044, 0.0083, 0.0119, 0.0155, 0.0190, 0.0225, 0.0260, 0.0295, 0.0331, 0.0366),
)
MITSUBA_SPECULAR_ALBEDO = (
    (0.0000, 0.0184, 0.0307, 0.0413, 0.0510, 0.0602, 0.0690, 0.0774, 0.0857, 0.0938, 0.1017),
    (0.0000, 0.0184, 0.0307, 0.0413, 0.0510, 0.0602, 0.0690, 0.0774, 0.0857, 0.0938, 0.1017),
    (0.0000, 0.0185, 0.0307, 0.0413, 0.0510, 0.0601, 0.0689, 0.0773, 0.0855, 0.0936, 0.1015),
    (0.0000, 0.0182, 0.0302, 0.0406, 0.0501, 0.0591, 0.0677, 0.0760, 0.0841, 0.0921, 0.0998),
    (0.0000, 0.0168, 0.0280, 0.0379, 0.0469, 0.0555, 0.0638, 0.0718, 0.0796, 0.0872, 0.0948),
    (0.0000, 0.0144, 0.0245, 0.0334, 0.0417, 0.0497, 0.0573, 0.0647, 0.0720, 0.0792, 0.0862),
    (0.0000, 0.0118, 0.0204, 0.0283, 0.0356, 0.0426, 0.0495, 0.0561, 0.0627, 0.0691, 0.0755),
    (0.0000, 0.0093, 0.0165, 0.0231, 0.0293, 0.0353, 0.0412, 0.0470, 0.0526, 0.0582, 0.0638),
    (0.0000, 0.0072, 0.0129, 0.0183, 0.0234, 0.0284, 0.0332, 0.0380, 0.0427, 0.0474, 0.0520),
    (0.0000, 0.0054, 0.0099, 0.0141, 0.0182, 0.0221, 0.0260, 0.0298, 0.0336, 0.0373, 0.0411),
    (0.0000, 0.0040, 0.0074, 0.0106, 0.0137, 0.0168, 0.0198, 0.0227, 0.0257, 0.0286, 0.0315),
)
MITSUBA_DIFFUSE_ALBEDO = (0.9725, 0.9798, 0.9875, 0.9935, 0.9992, 1.0057, 1.0130, 1.0204, 1.0280, 1.0356, 1.0436)


def _interp_row(table, r: float) -> np.ndarray:
    """The table's row at roughness r (linear between the measured rows, clamped to [0, 1])."""
    return np.array([np.interp(r, CALIB_ROUGHNESS, col) for col in np.asarray(table, dtype=np.float64).T])


def principled_calibration(roughness: float, specular: float) -> tuple[float, float]:
    """(base-colour factor, Mitsuba ``specular``) that give Mitsuba's ``principled`` Blender 5's
    albedo for a dielectric of this roughness and Specular IOR Level, for any base colour:
    ``specular'`` makes Mitsuba's specular albedo E_M equal Blender's E_B (the inverse of E_M in
    specular, extrapolated linearly above the table where a rough Blender surface reflects more
    than Mitsuba's specular 1 can), and the factor ``(1 - E_B) / D_M`` turns Burley's diffuse
    albedo into Blender's diffuse-under-specular. Residual (measured after calibration): see
    tests/test_mitsuba_agreement.py. Only the albedo is matched, not the angular shape (Burley's
    retro-reflection, single- vs multiple-scattering lobes)."""
    r = float(min(max(roughness, 0.0), 1.0))
    s = float(min(max(specular, 0.0), 1.0))
    e_b = float(np.interp(s, CALIB_SPECULAR, _interp_row(BLENDER_SPECULAR_ALBEDO, r)))
    e_m = _interp_row(MITSUBA_SPECULAR_ALBEDO, r)
    if e_b <= e_m[-1]:
        s_m = float(np.interp(e_b, e_m, CALIB_SPECULAR))
    else:  # beyond the table: continue its last segment
        slope = (e_m[-1] - e_m[-2]) / (CALIB_SPECULAR[-1] - CALIB_SPECULAR[-2])
        s_m = CALIB_SPECULAR[-1] + (e_b - e_m[-1]) / slope
    d_m = float(np.interp(r, CALIB_ROUGHNESS, MITSUBA_DIFFUSE_ALBEDO))
    return (1.0 - e_b) / d_m, s_m


# Blender's sky texture (MULTIPLE_SCATTERING, aerosol density (turbidity - 1) / 2, sun disc off)
# is ~50x brighter than Mitsuba's ``sunsky`` (sun_scale 0) at the same strength: Mitsuba's sky is in
# its own units. Cycles / Mitsuba ratio of the horizontal sky irradiance (luminance; a white floor
# under the sky alone), rows turbidity, columns sun elevation, measured by
# ``benchmarks/breakdown_backends.py --sky --spp 64`` (Blender 5.0.1, Mitsuba 3.9.1). Per channel
# the ratio differs by up to ~10 % (Blender's sky is bluer: R 48, G 54, B 58 at turbidity 3,
# elevation 38): shape and colour are the models' own, only the brightness is matched.
SKY_TURBIDITY = (1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 10.0)
SKY_ELEVATION = (5.0, 15.0, 30.0, 45.0, 60.0, 80.0)
SKY_UNITS = (
    (52.5, 57.0, 56.1, 56.8, 57.7, 57.2),
    (52.2, 57.1, 56.0, 56.7, 57.7, 56.5),
    (50.4, 54.9, 53.1, 53.5, 54.6, 54.1),
    (47.8, 50.6, 48.1, 47.7, 48.6, 49.3),
    (45.2, 47.0, 43.7, 41.8, 42.2, 43.8),
    (43.7, 44.3, 38.1, 34.3, 33.8, 36.6),
    (47.7, 43.5, 32.9, 25.3, 22.6, 25.8),
)


def sky_scale(strength: float, turbidity: float, elevation: float = 45.0) -> float:
    """``sky_scale`` for a sky of this strength: Mitsuba's sky brightened to Blender's units
    (bilinear in turbidity and sun elevation, clamped to the table)."""
    by_el = [float(np.interp(elevation, SKY_ELEVATION, row)) for row in SKY_UNITS]
    return float(strength) * float(np.interp(turbidity, SKY_TURBIDITY, by_el))


def luminance(rgb) -> float:
    return float(np.asarray(rgb, dtype=np.float64)[:3] @ REC709_LUMA)


def light_power(kind: str, power: float, color, spot_angle_deg: float = 180.0) -> float | None:
    """The power (W, luminance-weighted) a light emits into the scene, or None for the sun, whose
    power in the scene is not defined by itself. A spot emits the cone's share of its point's
    power (Blender's spot watts are the point's, ``point_intensity``)."""
    if kind == "sun":
        return None
    watts = max(float(power), 0.0) * luminance(color)
    if kind == "spot":
        half = math.radians(min(max(spot_angle_deg, 0.0), 180.0)) / 2.0
        watts *= (1.0 - math.cos(half)) / 2.0
    return watts


def surface_power(emission, area: float) -> float:
    """A one-sided Lambertian emitter of radiance L and area A emits L A pi (``area_radiance``)."""
    return max(luminance(emission), 0.0) * max(float(area), 0.0) * math.pi


def triangle_area(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Total area of a triangle mesh (vertices in metres, as the scene places them)."""
    if len(faces) == 0:
        return 0.0
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    return 0.5 * float(np.linalg.norm(cross, axis=1).sum())


def emitter_weights(powers: list[float], mode: str) -> list[float]:
    """Mitsuba's ``sampling_weight`` of each emitter of finite extent (lights, emissive meshes;
    ``powers`` in W); the environment and the sun keep 1. Mitsuba picks an emitter per shadow ray
    with probability proportional to its weight, all 1 by default (``uniform``). ``power`` keeps
    the share the emitters of finite extent have together under uniform choice (their weights sum
    to their count, so an environment seen through a window is sampled as often as before) and
    divides it among them by power: the same mean, far less noise where a room has bright and dim
    lamps (docs/backends/mitsuba.md)."""
    if mode == "uniform":
        return [1.0] * len(powers)
    if mode != "power":
        raise ValueError(f"unknown emitter sampling {mode!r}")
    total = sum(max(p, 0.0) for p in powers)
    if total < MIN_POWER:
        return [1.0] * len(powers)
    # a floor keeps every emitter sampled now and then: a weight of 0 would leave light that BSDF
    # sampling alone finds (MIS with a zero pdf) and a numerically dark lamp invisible to NEE
    floored = [max(p, 1e-3 * total / len(powers)) for p in powers]
    return [len(powers) * p / sum(floored) for p in floored]


MIN_POWER = 1e-9  # W: below it the emitters together emit nothing that power could divide
