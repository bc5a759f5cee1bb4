"""The camera's sensor and processing, applied after rendering: the same in every backend.

RGB: auto white balance divides out the colour of the light in view (the render over the view's
albedo: what a camera's AWB estimates, here known exactly) and auto exposure meters the image to
middle grey; then exposure and white-balance errors scale the linear radiance, the lens darkens
its corners (vignetting, after the metering: the exposure a fit finds is for the vignetted image) and blurs it,
then shot noise (std proportional to the square root of the signal) and read noise (constant std) are added, all
in linear units, as in a real camera's raw pipeline; the camera's processing then sets the colour
saturation, encodes sRGB, applies its tone curve and sharpens. Depth: a structured-
light sensor's errors on a copy of the exact depth (axial noise growing with z², holes at depth
jumps, random dropout, quantisation). Every draw comes from the generator passed in, which the
caller seeds from the render job: the same job gives the same noise on every machine.
"""

from __future__ import annotations

import numpy as np

from ..model.colour import REC709_LUMA, kelvin_rgb, linear_to_srgb, linear_to_srgb8, srgb_to_linear
from ..spec.models import DepthSensor, Sensor

AWB_GAINS = (0.2, 5.0)  # a camera's AWB range: about 2000 K to 12000 K under one light
MIDDLE_GREY = 0.18
AE_RANGE = (1.0 / 16.0, 16.0)


def illuminant(linear: np.ndarray, albedo: np.ndarray, clipped: float = np.inf) -> np.ndarray | None:
    """The colour of the light in view (linear RGB): the render's sum over the albedo's sum per
    channel, over pixels with a surface of known, not-black colour whose render is not clipped.
    Light bounced off orange wood counts, as it does for a camera. None when too little is seen."""
    ok = (albedo.min(axis=-1) > 0.02) & (linear.max(axis=-1) < clipped)
    if ok.sum() < 16:
        return None
    return linear[ok].sum(axis=0) / albedo[ok].sum(axis=0)


def balance_gains(light: np.ndarray | None) -> np.ndarray:
    """Per-channel gains that make ``light`` neutral at its own luminance (brightness kept)."""
    if light is None or not np.all(np.isfinite(light)) or light.max() <= 0:
        return np.ones(3)
    return np.clip(float(light @ REC709_LUMA) / np.maximum(light, 1e-12), *AWB_GAINS)


METER_ZONE = 4  # pixels a side of the zones metering averages before their log-average


def metered_luminance(linear: np.ndarray) -> np.ndarray:
    """The luminance auto exposure meters: the mean of each METER_ZONE x METER_ZONE zone (the
    image's edge rows and columns that fill no zone are left out). A camera meters the light, not
    a render's noise: the log-average of single pixels of a one-sample render, where many pixels
    found no light path, read its image 2.8 stops darker than its converged render (a demo view at
    640 x 480, Cycles); of 4 x 4 zones 0.3 stops; and the zones of the converged render read it 0.08
    stops brighter than its pixels do."""
    y = np.asarray(linear, np.float64) @ REC709_LUMA
    b = METER_ZONE
    h, w = y.shape[0] // b * b, y.shape[1] // b * b
    if h == 0 or w == 0:  # smaller than a zone: the image is one zone
        return np.array([[y.mean()]]) if y.size else y
    return y[:h, :w].reshape(h // b, b, w // b, b).mean(axis=(1, 3))


def exposure_gain(linear: np.ndarray) -> float:
    """The factor that brings the image's log-average luminance over metering zones
    (``metered_luminance``) to middle grey (Reinhard's key), as a camera's average metering does;
    within AE_RANGE; 1 for a black image."""
    y = metered_luminance(linear)
    if not np.any(y > 0):
        return 1.0
    log_mean = float(np.exp(np.mean(np.log(np.maximum(y, 1e-4)))))
    return float(np.clip(MIDDLE_GREY / log_mean, *AE_RANGE))


def sensor_rgb(linear: np.ndarray | None, rgb8: np.ndarray, sensor: Sensor, rng: np.random.Generator,
               albedo8: np.ndarray | None = None) -> np.ndarray:
    """The sensor's 8-bit sRGB image of a render (its linear radiance, or its 8-bit image decoded);
    ``albedo8`` (the view's sRGB albedo map) is needed for auto white balance."""
    # Draw every number whatever is switched on, so enabling one effect never shifts another's noise.
    stops = float(rng.uniform(*sensor.exposure)) if sensor.exposure != (0.0, 0.0) else 0.0
    kelvin = float(rng.uniform(*sensor.white_balance)) if sensor.white_balance else 6500.0
    if not sensor.affects_rgb:
        return rgb8
    x = (np.asarray(linear, np.float64) if linear is not None else srgb_to_linear(rgb8.astype(np.float64) / 255.0))
    x = np.maximum(x, 0.0)
    if sensor.auto_white_balance:
        if albedo8 is None:
            raise ValueError("auto white balance needs the view's albedo map")
        albedo = srgb_to_linear(np.asarray(albedo8, np.float64) / 255.0)
        x = x * balance_gains(illuminant(x, albedo, clipped=np.inf if linear is not None else 0.99))
    if sensor.auto_exposure:
        x = x * exposure_gain(x)
    gains = np.asarray(kelvin_rgb(6500.0)) / np.asarray(kelvin_rgb(kelvin))
    x = x * (2.0 ** stops) * (gains / gains.mean())
    if sensor.vignetting > 0:  # after metering, as `specsynth fit` develops its probe: the fitted exposure holds
        x = x * vignette(x.shape[0], x.shape[1], sensor.vignetting)[..., None]
    noise = rng.standard_normal(x.shape)
    if sensor.blur:  # drawn after the noise: a spec without blur keeps every earlier draw
        x = blur(x, float(rng.uniform(*sensor.blur)))
    noise_std = np.sqrt(sensor.shot_noise ** 2 * x + sensor.read_noise ** 2)
    x = x + noise_std * noise
    return process(np.clip(x, 0.0, None), sensor.saturation, sensor.contrast, sensor.sharpening)


def saturate(x: np.ndarray, factor: float) -> np.ndarray:
    """Each linear colour moved from its luminance by ``factor`` (1: unchanged), never below 0."""
    if factor == 1.0:
        return x
    y = (np.asarray(x) @ REC709_LUMA)[..., None]
    return np.clip(y + factor * (x - y), 0.0, None)


def tone_curve(v: np.ndarray, k: float) -> np.ndarray:
    """The S-curve v^k / (v^k + (1 - v)^k) on encoded values in [0, 1]: 0, 1/2 and 1 stay, the
    slope at 1/2 is k (1: the identity)."""
    if k == 1.0:
        return v
    a = np.power(np.clip(v, 0.0, 1.0), k)
    return a / (a + np.power(np.clip(1.0 - v, 0.0, 1.0), k))


SHARPEN_SIGMA = 1.0  # pixels: the unsharp mask's Gaussian (a camera's sharpening halo is 1-2 pixels wide)


def sharpen(v: np.ndarray, amount: float) -> np.ndarray:
    """An unsharp mask on encoded values' luma, as a camera's image processor sharpens: each channel
    moved by ``amount`` times the luma's difference from its Gaussian blur (``SHARPEN_SIGMA``), so
    edges get dark and bright halos and colours keep their hue; 0: unchanged."""
    if amount <= 0:
        return v
    from scipy.ndimage import gaussian_filter

    y = np.asarray(v, np.float64) @ REC709_LUMA
    return np.clip(v + amount * (y - gaussian_filter(y, SHARPEN_SIGMA, mode="mirror"))[..., None], 0.0, 1.0)


def process(linear: np.ndarray, saturation: float = 1.0, contrast: float = 1.0, sharpening: float = 0.0) -> np.ndarray:
    """The camera's processing of a linear image -> its 8-bit sRGB: saturation in linear light, the
    sRGB encoding, the tone curve on the encoded values, then sharpening."""
    x = saturate(np.asarray(linear, np.float64), saturation)
    if contrast == 1.0 and sharpening <= 0:
        return linear_to_srgb8(x.astype(np.float32))
    v = tone_curve(linear_to_srgb(x.astype(np.float32)).astype(np.float64), contrast)
    return np.round(sharpen(v, sharpening) * 255.0).astype(np.uint8)


def vignette(height: int, width: int, amount: float) -> np.ndarray:
    """A lens's fall-off of light towards the image corners, HxW gains: (1 + k rho^2)^-2, the cos^4
    law of a pinhole whose corner ray makes an angle of atan(sqrt(k)) with its axis, rho a pixel
    centre's distance from the image centre over the corners' (1 at the corner pixels), and k set
    so that the corners keep ``1 - amount`` of the light (0: none)."""
    if amount <= 0:
        return np.ones((height, width))
    k = (1.0 - amount) ** -0.5 - 1.0
    cy, cx = (height - 1) / 2.0, (width - 1) / 2.0
    yy, xx = np.mgrid[0:height, 0:width]
    rho2 = ((yy - cy) ** 2 + (xx - cx) ** 2) / max(cy * cy + cx * cx, 1e-12)
    return (1.0 + k * rho2) ** -2


def blur(x: np.ndarray, sigma: float) -> np.ndarray:
    """A Gaussian blur of ``sigma`` pixels over each channel (the image's edges mirrored)."""
    if sigma <= 0:
        return x
    from scipy.ndimage import gaussian_filter

    return gaussian_filter(x, sigma=(sigma, sigma, 0), mode="mirror")


def jpeg_quality(sensor: Sensor, default: int, rng: np.random.Generator) -> int:
    return int(rng.integers(sensor.jpeg_quality[0], sensor.jpeg_quality[1] + 1)) if sensor.jpeg_quality else default


def sensor_depth(depth: np.ndarray, model: DepthSensor, rng: np.random.Generator) -> np.ndarray:
    """A noisy copy of a z-depth map (metres, 0 = empty)."""
    z = np.asarray(depth, np.float64)
    valid = z > 0
    a, b = model.axial_noise
    noisy = z + (a + b * z * z) * rng.standard_normal(z.shape)
    holes = rng.random(z.shape) < model.dropout
    if model.edge_holes:
        jump = np.zeros_like(valid)
        for axis in (0, 1):
            d = np.abs(np.diff(z, axis=axis))
            big = d > 0.05 * np.maximum(np.delete(z, 0, axis=axis), np.delete(z, -1, axis=axis))
            pad = [(0, 0), (0, 0)]
            pad[axis] = (1, 0)
            jump |= np.pad(big, pad)
            pad[axis] = (0, 1)
            jump |= np.pad(big, pad)
        grown = jump.copy()
        for _ in range(model.edge_holes - 1):
            grown |= np.roll(grown, 1, 0) | np.roll(grown, -1, 0) | np.roll(grown, 1, 1) | np.roll(grown, -1, 1)
        holes |= grown
    if model.quantisation > 0:
        noisy = np.round(noisy / model.quantisation) * model.quantisation
    return np.where(valid & ~holes & (noisy > 0), noisy, 0.0).astype(np.float32)
