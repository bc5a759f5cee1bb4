"""Normal maps and HDRIs from the npm package ``@pmndrs/assets`` (CC0).

The package (npm registry, CC0-1.0) carries 29 tileable normal maps at 512 x 512 (from
emmelleppi/normal-maps) and 20 Poly Haven HDRIs at 512 x 256, each as a base64 data URL inside a
JavaScript module. ``make install`` (``specsynth assets install``) fetches the tarball with
``npm pack`` and unpacks only those images into ``<cache>/library/pmndrs/``: normal maps as PNG,
HDRIs re-written as OpenEXR without the web's DWAB compression, with a manifest of sha256 hashes.
Nothing is executed from the package and nothing is fetched at build time.

Normal maps give floors, walls, worktops and fabrics their relief; each is named here by the
surfaces it suits (``KINDS``), chosen by looking at them.
"""

from __future__ import annotations

import base64
import hashlib
import io
import json
import re
import shutil
import tarfile
import uuid
from dataclasses import dataclass
from pathlib import Path

PACKAGE = "@pmndrs/assets@1.7.0"
FOLDER = "pmndrs"
LICENCE = "CC0-1.0"
SOURCE = "npm package @pmndrs/assets 1.7.0 (normal maps from emmelleppi/normal-maps; HDRIs from Poly Haven)"

# Normal map number -> the surfaces it suits (looked at on a contact sheet of all 29).
KINDS: dict[str, tuple[str, ...]] = {
    "0000": ("wall",), "0001": ("stone",), "0006": ("stone",), "0015": ("wall", "worktop"),
    "0021": ("wall", "worktop", "plastic"), "0027": ("plastic", "leather"), "0004": ("wood",), "0011": ("wood",),
    "0012": ("wood",), "0016": ("wood",), "0019": ("wood",), "0023": ("wood",), "0025": ("tiles",),
    "0014": ("paper", "fabric"), "0017": ("fabric",), "0018": ("fabric",), "0003": ("leather",),
    "0009": ("metal",), "0008": ("metal",), "0020": ("stone", "worktop"), "0024": ("stone",), "0026": ("stone",),
    "0010": ("stone",), "0022": ("wood",),
}
INDOOR_HDRIS = ("apartment", "hall", "lab", "lobby", "studio", "warehouse", "workshop")
OUTDOOR_HDRIS = ("bridge", "city", "dawn", "esplanade", "forest", "night", "park", "sky", "sunrise", "sunset", "venice")


class PmndrsError(ValueError):
    """The set is not installed, or a name is unknown."""


@dataclass(frozen=True)
class NormalMap:
    name: str  # "0012"
    path: Path
    kinds: tuple[str, ...]

    @property
    def credit(self) -> dict[str, str]:
        return {"asset": f"normal:{self.name}", "name": f"normal map {self.name}", "author": "emmelleppi (normal-maps)",
                "licence": LICENCE, "source": SOURCE}


def folder(cache: Path) -> Path:
    return Path(cache) / "library" / FOLDER


def installed(cache: Path) -> bool:
    return (folder(cache) / "manifest.json").is_file()


_DATA_URL = re.compile(rb"data:[a-z/+-]+;base64,([A-Za-z0-9+/=]+)")


def _payload(js: bytes, member: str) -> bytes:
    m = _DATA_URL.search(js)
    if m is None:
        raise PmndrsError(f"{member}: no base64 data URL in the module")
    return base64.b64decode(m.group(1), validate=True)


def _normal_png(data: bytes) -> bytes:
    from PIL import Image

    with Image.open(io.BytesIO(data)) as im:
        if im.format != "WEBP" or im.size[0] > 4096 or im.size[1] > 4096:
            raise PmndrsError("a normal map is not a WebP image of at most 4096 x 4096 pixels")
        buf = io.BytesIO()
        im.convert("RGB").save(buf, format="PNG")
    return buf.getvalue()


def _plain_exr(data: bytes, scratch: Path) -> bytes:
    """The EXR re-written with ZIP compression (DWAB is lossy and not every reader has it)."""
    import numpy as np
    import OpenEXR

    src = scratch / f"in-{uuid.uuid4().hex[:8]}.exr"
    dst = scratch / f"out-{uuid.uuid4().hex[:8]}.exr"
    src.write_bytes(data)
    with OpenEXR.File(str(src)) as f:
        channels = f.channels()
        rgb = channels["RGB"].pixels if "RGB" in channels else np.stack([channels[c].pixels for c in "RGB"], -1)
        rgb = np.ascontiguousarray(rgb, np.float32)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or max(rgb.shape[:2]) > 8192 or not np.isfinite(rgb).all():
        raise PmndrsError("an HDRI is not a finite RGB image of at most 8192 pixels a side")
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, {"RGB": rgb}) as out:
        out.write(str(dst))
    return dst.read_bytes()


def install_from_tarball(tarball: Path, cache: Path) -> Path:
    """Unpack the normal maps and HDRIs of the npm tarball into the cache (atomically)."""
    dest = folder(cache)
    tmp = dest.parent / f".{dest.name}.{uuid.uuid4().hex[:8]}.tmp"
    files: dict[str, str] = {}
    try:
        (tmp / "normals").mkdir(parents=True)
        (tmp / "hdri").mkdir()
        with tarfile.open(tarball, "r:gz") as tar:
            for member in tar.getmembers():
                m = re.fullmatch(r"package/(normals|hdri)/([a-z0-9_]+)\.(webp|exr)\.js", member.name)
                if not member.isfile() or m is None or member.size > 64 << 20:
                    continue
                data = _payload(tar.extractfile(member).read(), member.name)
                kind, name = m.group(1), m.group(2)
                rel = f"normals/{name}.png" if kind == "normals" else f"hdri/{name}.exr"
                out = _normal_png(data) if kind == "normals" else _plain_exr(data, tmp)
                (tmp / rel).write_bytes(out)
                files[rel] = hashlib.sha256(out).hexdigest()
            for f in tmp.glob("*.exr"):
                f.unlink()
            licence = next((m for m in tar.getmembers() if m.name == "package/LICENSE" and m.isfile()), None)
            if licence is not None:
                (tmp / "LICENSE").write_bytes(tar.extractfile(licence).read())
        if not any(f.startswith("normals/") for f in files):
            raise PmndrsError(f"{tarball}: holds no normal maps")
        manifest = {"source": SOURCE, "licence": LICENCE, "package": PACKAGE, "files": dict(sorted(files.items()))}
        (tmp / "manifest.json").write_text(json.dumps(manifest, indent=1))
        if dest.exists():
            shutil.rmtree(dest)
        tmp.rename(dest)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return dest


def normal_maps(cache: Path, kind: str | None = None) -> list[NormalMap]:
    """The installed normal maps (those suiting ``kind``), in a fixed order; [] when not installed."""
    base = folder(cache) / "normals"
    out = []
    for name, kinds in sorted(KINDS.items()):
        p = base / f"{name}.png"
        if p.is_file() and (kind is None or kind in kinds):
            out.append(NormalMap(name, p, kinds))
    return out


def normal_map(cache: Path, name: str) -> NormalMap:
    """One normal map by its number ('0012'); an error naming the choices when unknown."""
    if not installed(cache):
        raise PmndrsError("the normal maps are not installed; run `specsynth assets install` (npm package "
                          f"{PACKAGE})")
    for n in normal_maps(cache):
        if n.name == name:
            return n
    raise PmndrsError(f"no normal map {name!r}; installed: {', '.join(n.name for n in normal_maps(cache))}")


def hdri(cache: Path, name: str) -> Path | None:
    p = folder(cache) / "hdri" / f"{name}.exr"
    return p if p.is_file() else None


def hdri_credit(name: str) -> dict[str, str]:
    return {"asset": f"hdri:{name}", "name": f"HDRI {name}", "author": "Poly Haven", "licence": LICENCE,
            "source": SOURCE}
