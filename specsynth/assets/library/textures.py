"""Tileable surface textures for floors, walls and worktops: robosuite's MIT texture set.

``make install`` downloads the robosuite wheel (PyPI, no dependencies) and unpacks only its 30
textures and licence into ``<cache>/library/robosuite-textures/`` with a ``manifest.json`` of
sha256 hashes (:func:`install_from_wheel`); nothing is fetched at run time. Chosen over the other
reachable sets because it is the one with floors (wood planks, tiles), walls (five plasters,
bricks) and worktops (ceramic, steel, clay) at 512-1024 px in 21 MB; Poly Haven's npm set carries
HDRIs and normal maps but no such colour textures.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import uuid
import zipfile
from dataclasses import dataclass
from pathlib import Path

WHEEL = "robosuite==1.5.2"
FOLDER = "robosuite-textures"
LICENCE = "MIT"
COPYRIGHT = "Stanford Vision and Learning Lab and UT Robot Perception and Learning Lab"
SOURCE = "robosuite 1.5.2 (PyPI wheel), robosuite/models/assets/textures"

# What each texture is good for, and its physical repeat size (metres per tile) on a surface.
KINDS: dict[str, tuple[str, float]] = {
    "wood-tiles": ("floor", 1.0), "light-gray-floor-tile": ("floor", 0.8), "light-wood": ("floor", 1.2),
    "dark-wood": ("floor", 1.2), "wood-varnished-panels": ("floor", 1.5), "gray-woodgrain": ("floor", 1.2),
    "blue-wood": ("floor", 1.2), "red-wood": ("floor", 1.2), "green-wood": ("floor", 1.2),
    "cream-plaster": ("wall", 1.5), "gray-plaster": ("wall", 1.5), "light-gray-plaster": ("wall", 1.5),
    "pink-plaster": ("wall", 1.5), "white-plaster": ("wall", 1.5), "yellow-plaster": ("wall", 1.5),
    "white-bricks": ("wall", 1.2), "clay": ("wall", 1.0),
    "ceramic": ("worktop", 0.6), "steel-brushed": ("worktop", 0.8), "steel-scratched": ("worktop", 0.8),
    "metal": ("worktop", 0.8), "gray-felt": ("fabric", 0.5), "brass-ambra": ("worktop", 0.6),
}


class TextureLibraryError(ValueError):
    """The texture set is not installed, or a texture is unknown."""


@dataclass(frozen=True)
class SurfaceTexture:
    name: str
    path: Path
    kind: str
    tile: float  # metres per repeat

    @property
    def credit(self) -> dict[str, str]:
        return {"asset": f"texture:{self.name}", "name": self.name, "author": COPYRIGHT, "copyright": COPYRIGHT,
                "licence": LICENCE, "source": SOURCE}


def folder(cache: Path) -> Path:
    return Path(cache) / "library" / FOLDER


def install_from_wheel(wheel: Path, cache: Path) -> Path:
    """Unpack the textures and the licence of a robosuite wheel into the cache (atomically)."""
    dest = folder(cache)
    tmp = dest.parent / f".{dest.name}.{uuid.uuid4().hex[:8]}.tmp"
    files = {}
    try:
        with zipfile.ZipFile(wheel) as z:
            for name in z.namelist():
                base = name.rsplit("/", 1)[-1]
                if name.startswith("robosuite/models/assets/textures/") and base.endswith(".png"):
                    target = tmp / base
                elif name.endswith(".dist-info/licenses/LICENSE"):
                    target = tmp / "LICENSE"
                else:
                    continue
                data = z.read(name)
                target.parent.mkdir(parents=True, exist_ok=True)
                target.write_bytes(data)
                files[target.name] = hashlib.sha256(data).hexdigest()
        (tmp / "manifest.json").write_text(json.dumps({"source": SOURCE, "licence": LICENCE, "files": files},
                                                      indent=1, sort_keys=True))
        if dest.exists():
            shutil.rmtree(dest)
        tmp.rename(dest)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return dest


def available(cache: Path) -> list[SurfaceTexture]:
    root = folder(cache)
    try:
        manifest = json.loads((root / "manifest.json").read_text())
    except (OSError, ValueError):
        raise TextureLibraryError(
            f"{root}: surface textures are not installed; run `make install` "
            "(it unpacks robosuite's MIT textures there)"
        ) from None
    out = []
    for name in sorted(manifest["files"]):
        stem = name.removesuffix(".png")
        if stem in KINDS and (root / name).is_file():
            kind, tile = KINDS[stem]
            out.append(SurfaceTexture(stem, root / name, kind, tile))
    return out


def of_kind(cache: Path, kind: str) -> list[SurfaceTexture]:
    return [t for t in available(cache) if t.kind == kind]


def main(argv: list[str] | None = None) -> int:
    """``python -m specsynth.assets.library.textures WHEEL`` (the install step)."""
    import sys

    from .cache import cache_dir

    args = sys.argv[1:] if argv is None else argv
    dest = install_from_wheel(Path(args[0]), cache_dir())
    print(f"installed {len(json.loads((dest / 'manifest.json').read_text())['files'])} files into {dest}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
