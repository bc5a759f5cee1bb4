"""Surface detail of scene materials: normal maps and roughness that varies across a surface.

A scene material may name a normal map (``normals:0012`` from the installed CC0 set, or an image
file) with a strength, and a roughness variation: rougher where the surface is darker or deeper
(wear, grime, the grooves between boards), smoother on the rest. Both become plain image maps of
the backend-neutral material (``MaterialIR.normal_texture`` / ``roughness_texture``), baked once
into the texture cache by content, so every backend reads the same pixels.
"""

from __future__ import annotations

import functools
import hashlib
import io
import os
from pathlib import Path

import numpy as np

from ..assets import resolve as assets
from ..atomic import atomic_write_bytes
from ..assets.library import pmndrs
from ..assets.meshfiles import bake

LIBRARY_PREFIX = "normals:"
MAP_SIZE = 512  # roughness maps are made at this size (the library's normal maps' own)


def resolve_normal_map(ref: str, base: Path, what: str) -> Path:
    """'normals:0012' (the installed set) or an image path relative to ``base``."""
    if ref.startswith(LIBRARY_PREFIX):
        try:
            return pmndrs.normal_map(assets.cache_dir(), ref[len(LIBRARY_PREFIX):]).path
        except pmndrs.PmndrsError as e:
            raise assets.AssetError(f"{what}: {e}") from None
    p = assets.resolve_data_ref(ref, base, what)
    assets.check_texture(p, what)
    return p


def library_credits(meshes) -> list[dict]:
    """Credits of the installed normal maps that scene meshes name ('normals:0012')."""
    names = sorted({mat.normal_map[len(LIBRARY_PREFIX):] for m in meshes for mat in (m.material, *m.materials.values())
                    if mat.normal_map and mat.normal_map.startswith(LIBRARY_PREFIX)})
    cache = assets.cache_dir()
    return [pmndrs.normal_map(cache, n).credit for n in names]


def _key(path: Path) -> tuple[str, int, int]:
    st = os.stat(path)
    return str(path), st.st_size, st.st_mtime_ns


DERIVED_VERSION = 1  # bump when a derived map's pixels change for the same inputs


def _derived(cache: str, what: str, source: str, *params) -> tuple[Path, bool]:
    """Where a map derived from ``source`` with ``params`` lives, named by those inputs (the source's
    bytes, not its path), and whether it is there: a room reloaded by another worker, stage or
    build finds its maps instead of computing and encoding them again."""
    key = f"{what} v{DERIVED_VERSION} {assets.file_digest(Path(source))} {params!r}"
    dest = Path(cache) / "derived" / f"{hashlib.sha256(key.encode()).hexdigest()}.png"
    return dest, dest.is_file()


def _store(image, dest: Path) -> str:
    buf = io.BytesIO()
    image.save(buf, format="PNG", compress_level=1)
    dest.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(dest, buf.getvalue())
    return str(dest)


@functools.lru_cache(maxsize=256)
def _scaled(key: tuple, strength: float, cache: str) -> str:
    from PIL import Image

    dest, done = _derived(cache, "normal", key[0], strength)
    if done:
        return str(dest)
    with Image.open(key[0]) as im:
        return _store(bake.scaled_normal_map(im, strength, key[0]).convert("RGB"), dest)


def normal_texture(path: Path, strength: float, cache: Path) -> str:
    """The normal map with its relief scaled by ``strength`` (glTF's normal scale), as a file."""
    if abs(strength - 1.0) < 1e-9:
        return str(path)
    return _scaled(_key(path), round(float(strength), 4), str(cache))


def _relief(image) -> np.ndarray:
    """How deep or dark each pixel is, in [0, 1]: a normal map's tilt, or a colour image's darkness."""
    a = bake.as_array(image, "texture")[..., :3]
    if np.abs(a.mean(axis=(0, 1)) - (0.5, 0.5, 1.0)).max() < 0.15:  # a normal map: tilt away from +Z
        n = a * 2.0 - 1.0
        v = 1.0 - n[..., 2] / np.maximum(np.linalg.norm(n, axis=-1), 1e-6)
    else:
        v = 1.0 - a @ np.array([0.2126, 0.7152, 0.0722], np.float32)
    lo, hi = np.percentile(v, (2, 98))
    return np.clip((v - lo) / max(hi - lo, 1e-6), 0.0, 1.0)


@functools.lru_cache(maxsize=256)
def _roughness(key: tuple, base: float, variation: float, cache: str) -> str:
    from PIL import Image

    dest, done = _derived(cache, "roughness", key[0], base, variation, MAP_SIZE)
    if done:
        return str(dest)
    with Image.open(key[0]) as im:
        im.draft("RGB", (MAP_SIZE, MAP_SIZE))
        small = im.convert("RGB").resize((min(MAP_SIZE, im.width), min(MAP_SIZE, im.height)), Image.BILINEAR)
    r = np.clip(base + variation * (2.0 * _relief(small) - 1.0), 0.0, 1.0)
    return _store(bake.grey(r), dest)


def roughness_texture(source: Path, base: float, variation: float, cache: Path) -> str:
    """A grey map of roughness ``base`` +/- ``variation``: rougher where ``source`` (a normal map or
    a colour texture, tiled as the material's texture is) is deeper or darker."""
    return _roughness(_key(source), round(float(base), 4), round(float(variation), 4), str(cache))
