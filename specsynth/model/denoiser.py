"""OpenImageDenoise on the CPU (pyoidn), as Blender's Cycles runs it: the renderers' shared denoiser
for images the core puts together from several renders (RenderBackend.denoise).

Guides are HxWx6 float32: albedo in [0, 1], then the shading normal in [-1, 1]
(``RenderResult.guides``). ``prefilter`` is Cycles' choice: 'none' takes the guides as noise-free;
'fast' lets the filter denoise them with the image; 'accurate' denoises each guide with a filter of
its own first (OIDN's documented prefiltering), then takes them as clean.
"""

from __future__ import annotations

import numpy as np

PREFILTERS = ("none", "fast", "accurate")
QUALITIES = ("fast", "balanced", "high")


def _pyoidn(who: str):
    try:
        import pyoidn
    except ImportError as e:
        raise RuntimeError(f"{who}: denoising needs pyoidn (pip install pyoidn; make install does)") from e
    return pyoidn


def _prefiltered(pyoidn, image: np.ndarray, slot: str, quality: str) -> np.ndarray:
    """One guide denoised on its own: a filter given only that guide (no colour) and an output."""
    src = np.ascontiguousarray(image, np.float32)
    out = np.empty_like(src)
    with pyoidn.Device() as device:
        device.commit()
        with pyoidn.Filter(device) as f:
            f.set_image(slot, src, pyoidn.OIDN_FORMAT_FLOAT3)
            f.set_image(pyoidn.OIDN_IMAGE_OUTPUT, out, pyoidn.OIDN_FORMAT_FLOAT3)
            f.set_quality({"fast": pyoidn.OIDN_QUALITY_FAST, "balanced": pyoidn.OIDN_QUALITY_BALANCED,
                           "high": pyoidn.OIDN_QUALITY_HIGH}[quality])
            f.commit()
            f.execute()
        error = device.get_error()
    if error:
        raise RuntimeError(f"OpenImageDenoise could not prefilter the {slot} guide: {error}")
    return out


def oidn(linear: np.ndarray, guides: np.ndarray, quality: str = "high", prefilter: str = "fast",
         who: str = "denoise") -> np.ndarray:
    """``linear`` (HxWx3 radiance) denoised with its ``guides`` -> HxWx3 float32, never negative."""
    if quality not in QUALITIES or prefilter not in PREFILTERS:
        raise ValueError(f"{who}: denoise quality {quality!r} / prefilter {prefilter!r}: one of {QUALITIES} / {PREFILTERS}")
    pyoidn = _pyoidn(who)
    albedo = np.ascontiguousarray(np.clip(guides[..., 0:3], 0, 1), np.float32)
    normal = np.ascontiguousarray(np.clip(guides[..., 3:6], -1, 1), np.float32)
    if prefilter == "accurate":
        albedo = np.clip(_prefiltered(pyoidn, albedo, pyoidn.OIDN_IMAGE_ALBEDO, quality), 0, 1)
        normal = np.clip(_prefiltered(pyoidn, normal, pyoidn.OIDN_IMAGE_NORMAL, quality), -1, 1)
    out = pyoidn.denoise(np.ascontiguousarray(linear, np.float32), albedo, normal, hdr=True, quality=quality,
                         clean_aux=prefilter != "fast")
    return np.ascontiguousarray(np.maximum(np.asarray(out, np.float32), 0.0))
