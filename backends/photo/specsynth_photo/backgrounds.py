"""Random real-photo backgrounds for the photo baseline (the paper's BL images).

Two kinds of source:
- ``"builtin"``: the photographs shipped inside scikit-image (offline, no download) plus random
  perspective views of the HDR panoramas bundled with the bpy wheel, tone-mapped to 8-bit sRGB;
- a folder of photographs (jpg/png, any size), searched recursively.

Every draw comes from the caller's generator. Decoded images are cached per pool (per backend
instance); folder photos through a byte-bounded LRU so that a large folder does not fill memory.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
from PIL import Image

from specsynth.assets.resolve import builtin_hdris, hdri_path
from specsynth.model.colour import linear_to_srgb8

# scikit-image sample images that are real photographs, with the file each needs. Only those whose
# file ships inside the installed package are used, so nothing is ever fetched from the network.
# (Drawings, scans of text and binary masks in skimage.data are left out.)
_SKIMAGE_PHOTOS: dict[str, str] = {
    "astronaut": "astronaut.png",
    "chelsea": "chelsea.png",
    "coffee": "coffee.png",
    "rocket": "rocket.jpg",
    "stereo_motorcycle": "motorcycle_left.png",
    "hubble_deep_field": "hubble_deep_field.jpg",
    "retina": "retina.jpg",
    "immunohistochemistry": "ihc.png",
    "camera": "camera.png",
    "moon": "moon.png",
    "coins": "coins.png",
    "brick": "brick.png",
    "grass": "grass.png",
    "gravel": "gravel.png",
}

_PHOTO_SUFFIXES = {".jpg", ".jpeg", ".png"}
_FOLDER_CACHE_BYTES = 512 * 2**20

# Perspective views of the panoramas: horizontal field of view and pitch ranges (degrees), and
# the Reinhard key (the mid-grey the log-average luminance is mapped to) range.
_PANO_HFOV = (55.0, 95.0)
_PANO_PITCH = (-25.0, 35.0)
_PANO_KEY = (0.12, 0.3)
# Crops (fraction of the largest crop with the image's aspect ratio) taken from a photograph.
_CROP_SCALE = (0.5, 1.0)


class BackgroundError(ValueError):
    pass


def skimage_photo_names() -> list[str]:
    """The scikit-image photographs available offline in the installed package."""
    try:
        import skimage.data
    except ImportError as e:
        raise BackgroundError(
            "photo backgrounds 'builtin' need scikit-image: pip install 'specsynth[photo]'"
        ) from e
    data_dir = Path(skimage.data.data_dir)
    return [name for name, fname in _SKIMAGE_PHOTOS.items() if (data_dir / fname).is_file()]


def hdri_paths() -> list[Path]:
    """The HDR panoramas in the bpy wheel (``specsynth.assets.resolve`` finds them without importing bpy)."""
    return [hdri_path(name) for name in builtin_hdris()]


def folder_photos(folder: str | Path) -> list[Path]:
    root = Path(folder).expanduser()
    if not root.is_dir():
        raise BackgroundError(
            f"photo backgrounds: {str(folder)!r} is neither 'builtin' nor an existing folder of photographs"
        )
    files = sorted(p for p in root.rglob("*") if p.suffix.lower() in _PHOTO_SUFFIXES and p.is_file())
    if not files:
        raise BackgroundError(f"photo backgrounds: no .jpg/.jpeg/.png photographs found in {str(root)!r}")
    return files


def _load_skimage(name: str) -> Image.Image:
    import skimage.data

    img = getattr(skimage.data, name)()
    if isinstance(img, tuple):  # stereo_motorcycle returns (left, right, disparity)
        img = img[0]
    return Image.fromarray(np.ascontiguousarray(img)).convert("RGB")


def _load_photo(path: Path) -> Image.Image:
    try:
        with Image.open(path) as im:
            return im.convert("RGB")
    except Image.DecompressionBombError:  # its header claims more pixels than memory should hold
        raise BackgroundError(f"photo backgrounds: {str(path)!r} claims over {Image.MAX_IMAGE_PIXELS:,} pixels; "
                              "scale it down or remove it from the folder") from None
    except OSError as e:
        raise BackgroundError(f"photo backgrounds: cannot decode {str(path)!r} ({type(e).__name__})") from None


def _load_exr(path: Path) -> np.ndarray:
    import OpenEXR

    with OpenEXR.File(str(path)) as f:
        channels = f.channels()
        if "RGB" in channels:
            rgb = channels["RGB"].pixels
        else:
            rgb = np.stack([channels[c].pixels for c in ("R", "G", "B")], axis=-1)
    # Negative values are compression ringing; they are not light.
    return np.clip(np.asarray(rgb, dtype=np.float32), 0.0, None)


@dataclass(frozen=True)
class _Source:
    kind: str  # "photo" or "pano"
    key: str
    load: Callable[[], object]


def _crop_photo(im: Image.Image, width: int, height: int, rng: np.random.Generator) -> np.ndarray:
    """Random crop with the output's aspect ratio, random zoom and mirror, resized to the output."""
    w0, h0 = im.size
    aspect = width / height
    cw_max = min(float(w0), h0 * aspect)
    scale, fx, fy, flip = rng.uniform(size=4)
    cw = cw_max * (_CROP_SCALE[0] + (_CROP_SCALE[1] - _CROP_SCALE[0]) * scale)
    ch = cw / aspect
    x0 = fx * (w0 - cw)
    y0 = fy * (h0 - ch)
    out = im.resize((width, height), Image.BILINEAR, box=(x0, y0, x0 + cw, y0 + ch))
    if flip < 0.5:
        out = out.transpose(Image.FLIP_LEFT_RIGHT)
    return np.asarray(out, dtype=np.uint8)


def _pano_view(pano: np.ndarray, width: int, height: int, rng: np.random.Generator) -> np.ndarray:
    """Pinhole view of an equirectangular panorama in a random direction, tone-mapped to sRGB."""
    yaw_u, pitch_u, fov_u, roll_u, key_u = rng.uniform(size=5)
    yaw = 2 * math.pi * yaw_u
    pitch = math.radians(_PANO_PITCH[0] + (_PANO_PITCH[1] - _PANO_PITCH[0]) * pitch_u)
    hfov = math.radians(_PANO_HFOV[0] + (_PANO_HFOV[1] - _PANO_HFOV[0]) * fov_u)
    roll = math.radians(10.0 * (2 * roll_u - 1))
    key = _PANO_KEY[0] + (_PANO_KEY[1] - _PANO_KEY[0]) * key_u

    ph, pw = pano.shape[:2]
    # The panorama has about pw * hfov / 2pi pixels across the view: sample at that resolution and
    # let PIL upscale, which is cheaper than sampling every output pixel and looks the same.
    scale = min(1.0, pw * hfov / (2 * math.pi) / width)
    sw, sh = max(2, round(width * scale)), max(2, round(height * scale))
    f = (sw / 2) / math.tan(hfov / 2)
    xs = (np.arange(sw, dtype=np.float32) + 0.5 - sw / 2) / f
    ys = (np.arange(sh, dtype=np.float32) + 0.5 - sh / 2) / f
    # Camera rays in a y-up, z-forward frame, then roll, pitch (about x) and yaw (about y).
    d = np.stack(np.broadcast_arrays(xs[None, :], -ys[:, None], np.float32(1.0)), axis=-1)
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    R_roll = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    R_pitch = np.array([[1, 0, 0], [0, cp, sp], [0, -sp, cp]])
    R_yaw = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    # 3x3 products by einsum (numpy's own loops): BLAS may round a last bit differently by the
    # operands' alignment, and that bit can flip a background pixel between two builds.
    R = np.einsum("ij,jk->ik", np.einsum("ij,jk->ik", R_yaw, R_pitch), R_roll).astype(np.float32)
    # Element-wise, not ``d @ R.T``: BLAS may pick kernels by memory alignment and thread count,
    # and a last-bit difference here can flip an 8-bit pixel; these bytes must depend on the seed only.
    d = np.stack([d[..., 0] * R[i, 0] + d[..., 1] * R[i, 1] + d[..., 2] * R[i, 2] for i in range(3)], axis=-1)
    d /= np.sqrt(d[..., 0] ** 2 + d[..., 1] ** 2 + d[..., 2] ** 2)[..., None]
    # float64, then float32: numpy's float32 arctan2 on these strided views gave results that
    # depended on the heap (its SIMD and scalar paths differ in the last bit, and which one a
    # value takes follows buffer alignment: measured 5 of 180 identical calls, 82 pixels off). In
    # float64 such a difference is far below what the cast to float32 keeps.
    lon = np.arctan2(d[..., 0].astype(np.float64), d[..., 2].astype(np.float64)).astype(np.float32)
    lat = np.arcsin(np.clip(d[..., 1].astype(np.float64), -1.0, 1.0)).astype(np.float32)
    u = (lon / (2 * np.pi) + 0.5) * pw - 0.5
    v = (0.5 - lat / np.pi) * ph - 0.5

    # Bilinear lookup; longitude wraps around, latitude clamps at the poles.
    u0 = np.floor(u).astype(np.int64)
    v0 = np.floor(v).astype(np.int64)
    au = (u - u0)[..., None]
    av = (v - v0)[..., None]
    u1 = (u0 + 1) % pw
    u0 %= pw
    v1 = np.clip(v0 + 1, 0, ph - 1)
    v0 = np.clip(v0, 0, ph - 1)
    lin = (pano[v0, u0] * (1 - au) + pano[v0, u1] * au) * (1 - av) + (pano[v1, u0] * (1 - au) + pano[v1, u1] * au) * av

    # Global Reinhard operator on luminance: scale the log-average to the key, compress L/(1+L).
    lum = np.float32(0.2126) * lin[..., 0] + np.float32(0.7152) * lin[..., 1] + np.float32(0.0722) * lin[..., 2]
    log_avg = float(np.exp(np.mean(np.log(lum.astype(np.float64) + 1e-4))))
    scaled_lum = lum * (key / log_avg)
    ratio = (key / log_avg) / (1.0 + scaled_lum)
    srgb = linear_to_srgb8(lin * ratio[..., None])
    out = Image.fromarray(srgb)
    if (sw, sh) != (width, height):
        out = out.resize((width, height), Image.BICUBIC)
    return np.asarray(out, dtype=np.uint8)


class BackgroundPool:
    """Draws random background images of a requested size."""

    def __init__(self, backgrounds: str = "builtin"):
        self.spec = backgrounds
        sources: list[_Source] = []
        if backgrounds == "builtin":
            for name in skimage_photo_names():
                sources.append(_Source("photo", f"skimage:{name}", lambda n=name: _load_skimage(n)))
            for path in hdri_paths():
                sources.append(_Source("pano", f"hdri:{path.name}", lambda p=path: _load_exr(p)))
            if not sources:
                raise BackgroundError("photo backgrounds 'builtin': no scikit-image photographs or HDRIs found")
            self._max_cache_bytes = None  # a few dozen MiB in all
        else:
            for path in folder_photos(backgrounds):
                sources.append(_Source("photo", str(path), lambda p=path: _load_photo(p)))
            self._max_cache_bytes = _FOLDER_CACHE_BYTES
        self.sources = tuple(sources)
        self._cache: OrderedDict[str, object] = OrderedDict()
        self._cache_bytes = 0

    def __len__(self) -> int:
        return len(self.sources)

    @property
    def keys(self) -> list[str]:
        return [s.key for s in self.sources]

    def _get(self, src: _Source):
        img = self._cache.get(src.key)
        if img is not None:
            self._cache.move_to_end(src.key)
            return img
        img = src.load()
        nbytes = img.nbytes if isinstance(img, np.ndarray) else img.width * img.height * 3
        self._cache[src.key] = img
        self._cache_bytes += nbytes
        if self._max_cache_bytes is not None:
            while self._cache_bytes > self._max_cache_bytes and len(self._cache) > 1:
                _, old = self._cache.popitem(last=False)
                self._cache_bytes -= old.nbytes if isinstance(old, np.ndarray) else old.width * old.height * 3
        return img

    def sample(self, width: int, height: int, rng: np.random.Generator) -> tuple[np.ndarray, str]:
        """An HxWx3 uint8 background and the key of the source it came from."""
        # The source index is drawn first and the crop draws after, with a fixed count per kind.
        src = self.sources[int(rng.integers(len(self.sources)))]
        img = self._get(src)
        if src.kind == "pano":
            return _pano_view(img, width, height, rng), src.key
        return _crop_photo(img, width, height, rng), src.key
