"""Pure numbers: how specsynth's IR and quality presets become Mitsuba 3 parameters.

Nothing here imports Mitsuba, so the mapping is testable (and documented) without a renderer.
See docs/backends/mitsuba.md for the tables these functions implement.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from specsynth.spec import QualityPreset

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
    perfect square."""
    spp = max(1, int(spp))
    if sampler == "ldsampler":
        n = 4
        while n < spp:
            n *= 4
        return n
    if sampler == "stratified":
        r = math.isqrt(spp)
        return spp if r * r == spp else (r + 1) ** 2
    return spp


def integrator_settings(preset: QualityPreset, sampler: str = "independent", samples: int | None = None) -> IntegratorSettings:
    # A unidirectional path tracer takes one diffuse and one specular continuation per camera
    # sample, so matching the preset's per-pixel ray budget needs max(camera, diffuse, specular)
    # samples: 1 / 36 / 225 for low / medium / high.
    requested = samples if samples is not None else max(preset.aa, preset.diffuse_rays, preset.specular_rays)
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
