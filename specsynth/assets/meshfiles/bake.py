"""Texture maps as every backend can read them, written once into the texture cache by content.

Importers bake material factors into grey-level maps here (roughness = factor x G of glTF's packed
map, metallic = factor x B, coverage = alpha x factor, thresholded for "mask"), and a normal map's
scale into its vectors (glTF's definition: ``normalize((2 n - 1) * (scale, scale, 1))``). Each
backend then reads plain images, with no per-backend arithmetic to disagree on.
"""

from __future__ import annotations

import hashlib
import io
import math
import warnings
from pathlib import Path

import numpy as np

from ...atomic import atomic_write_bytes
from ...files import not_a_file
from .part import MeshFileError

MAX_TEXTURE_PIXELS = 8192 * 8192  # past this a texture is refused, not silently decoded


def check_image(source, what: str) -> None:
    """A texture (a path, or the bytes of an embedded image) that every backend can decode within
    the pixel limit, checked from its header and chunks: nothing is decoded (a renderer would
    allocate the whole image: Cycles took 2.2 GB for a 20000 x 20000 map). ``what`` says where it
    is named; errors name the file, never what it holds."""
    from PIL import Image

    is_path = isinstance(source, (str, Path))
    label = f"{what}: texture {source}" if is_path else what
    if is_path and (problem := not_a_file(source)) is not None:
        raise MeshFileError(f"{label} is {problem}")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)  # refused below, by our own limit
            with Image.open(source if is_path else io.BytesIO(source)) as im:
                w, h = im.size
                if w * h > MAX_TEXTURE_PIXELS:
                    raise MeshFileError(f"{label}: {w} x {h} pixels, over the {MAX_TEXTURE_PIXELS:,}-pixel limit "
                                        "for a texture (8192 x 8192); scale it down")
                im.verify()
    except MeshFileError:
        raise
    except Image.DecompressionBombError:
        raise MeshFileError(f"{label}: over the {MAX_TEXTURE_PIXELS:,}-pixel limit for a texture (8192 x 8192; "
                            "its header claims far more); scale it down") from None
    except (OSError, SyntaxError, ValueError, EOFError) as e:  # PIL's ways of saying "not an image"
        raise MeshFileError(f"{label} is unreadable (not an image PIL can decode: {type(e).__name__})") from None


def store_png(image, cache: Path) -> Path:
    """The image as PNG under its content hash; written once, never overwritten."""
    buf = io.BytesIO()
    mode = image.mode if image.mode in ("L", "RGB", "RGBA") else ("RGBA" if "A" in image.getbands() else "RGB")
    # zlib level 1: a third of the default's time for ~10 % more bytes; rooms derive a dozen maps each
    image.convert(mode).save(buf, format="PNG", compress_level=1)
    data = buf.getvalue()
    dest = Path(cache) / f"{hashlib.sha256(data).hexdigest()}.png"
    if not (dest.is_file() and dest.stat().st_size == len(data)):
        atomic_write_bytes(dest, data)
    return dest


def as_array(image, what: str) -> np.ndarray:
    """float32 HxWxC in [0, 1]."""
    w, h = image.size
    if w * h > MAX_TEXTURE_PIXELS:
        raise MeshFileError(f"{what}: texture of {w}x{h} pixels is over the {MAX_TEXTURE_PIXELS:,}-pixel limit")
    a = np.asarray(image.convert("RGBA"), dtype=np.float32) / 255.0
    return a


def grey(values: np.ndarray):
    from PIL import Image

    return Image.fromarray(np.clip(np.rint(values * 255.0), 0, 255).astype(np.uint8), mode="L")


def channel_map(image, channel: int, factor: float, what: str):
    """One channel of an image times a factor, as a grey map (glTF: G roughness, B metallic)."""
    return grey(as_array(image, what)[..., channel] * float(factor))


def scaled_normal_map(image, scale: float, what: str):
    from PIL import Image

    n = as_array(image, what)[..., :3] * 2.0 - 1.0
    if not math.isclose(scale, 1.0):
        n[..., :2] *= float(scale)
    n /= np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-6)
    return Image.fromarray(np.clip(np.rint((n * 0.5 + 0.5) * 255.0), 0, 255).astype(np.uint8), mode="RGB")


def coverage_map(image, factor_alpha: float, mode: str, cutoff: float, what: str):
    """Coverage = texture alpha x factor alpha; for "mask", 1 where >= cutoff (glTF's rule), else 0."""
    a = as_array(image, what)[..., 3] * float(factor_alpha)
    if mode == "mask":
        a = (a >= cutoff).astype(np.float32)
    return grey(a)


def has_alpha(image) -> bool:
    return "A" in image.getbands() and image.getextrema()[image.getbands().index("A")][0] < 255
