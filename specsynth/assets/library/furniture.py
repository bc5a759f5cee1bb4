"""Sweet Home 3D's furniture library (Debian ``sweethome3d-furniture``): catalogue and extraction.

The package installs five ``.sh3f`` archives (zip files) under ``/usr/share/sweethome3d/furniture``
(``SPECSYNTH_SH3D_DIR`` overrides it), each with a ``PluginFurnitureCatalog.properties`` listing
its models: name, category, OBJ path, real size in centimetres (width x, depth z, height y of the
Y-up model), the elevation of the surface things are dropped on, the creator. A model is
unpacked on first use into ``<cache>/library/sh3d/<archive>/<model folder>/`` with a
``manifest.json`` of the files' sha256; never into the repository.

Licences, from the package's copyright file (``/usr/share/doc/sweethome3d-furniture/copyright``):
BlendSwap-CC-0 is CC0; BlendSwap-CC-BY and Scopia are CC-BY 3.0; KatorLegaz and Reallusion are
CC-BY 3.0 US. CC-BY requires attribution: every build lists what it used (see
:mod:`specsynth.assets.library.credits`).
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import shutil
import uuid
import zipfile
from dataclasses import dataclass
from pathlib import Path

DEFAULT_DIR = Path("/usr/share/sweethome3d/furniture")
SOURCE = "Sweet Home 3D furniture library (Debian package sweethome3d-furniture), www.sweethome3d.com"
LICENCES = {
    "BlendSwap-CC-0": ("CC0-1.0", "Blend Swap contributors, converted by Emmanuel Puybaret (eTeks)"),
    "BlendSwap-CC-BY": ("CC-BY-3.0", "Blend Swap contributors, converted by Emmanuel Puybaret (eTeks)"),
    "KatorLegaz": ("CC-BY-3.0-US", "Andrew Kator & Jennifer Legaz"),
    "Reallusion": ("CC-BY-3.0-US", "Reallusion"),
    "Scopia": ("CC-BY-3.0", "Scopia Visual Interfaces Systems, s.l."),
}


class LibraryError(ValueError):
    """The furniture library is missing, or a model in it is unknown or unreadable."""


@dataclass(frozen=True)
class FurnitureItem:
    id: str  # e.g. "Blend Swap CC-0#armchair"
    name: str
    category: str
    archive: str  # archive stem, e.g. "BlendSwap-CC-0"
    model: str  # path of the OBJ inside the archive, without the leading "/"
    size: tuple[float, float, float]  # metres: width (model x), depth (model z), height (model y)
    drop_on_top: float | None  # metres above the bottom: the surface things stand on (tables, shelves)
    elevation: float  # metres above the floor (wall shelves, wall lamps)
    creator: str
    rotation: tuple[float, ...] | None  # 3x3 row-major, applied to the Y-up model first
    door_or_window: bool
    light: bool

    @property
    def licence(self) -> str:
        return LICENCES.get(self.archive, ("see the package's copyright file", ""))[0]

    @property
    def credit(self) -> dict[str, str]:
        lic, holder = LICENCES.get(self.archive, ("see the package's copyright file", ""))
        return {"asset": f"furniture:{self.id}", "name": self.name, "author": self.creator,
                "copyright": holder, "licence": lic, "source": f"{SOURCE}, archive {self.archive}.sh3f"}


def library_dir() -> Path:
    return Path(os.environ.get("SPECSYNTH_SH3D_DIR", str(DEFAULT_DIR)))


def parse_properties(text: str) -> dict[str, str]:
    """Java .properties: key=value lines, # comments, backslash escapes of the common kinds."""
    out: dict[str, str] = {}
    for line in text.splitlines():
        line = line.strip()
        if not line or line[0] in "#!" or "=" not in line:
            continue
        key, value = line.split("=", 1)
        out[key.strip()] = value.strip().encode("latin-1", "backslashreplace").decode("unicode_escape", "replace")
    return out


def _items(archive: Path) -> list[FurnitureItem]:
    try:
        with zipfile.ZipFile(archive) as z:
            props = parse_properties(z.read("PluginFurnitureCatalog.properties").decode("latin-1"))
    except (OSError, KeyError, zipfile.BadZipFile) as e:
        raise LibraryError(f"{archive}: not a readable Sweet Home 3D library ({type(e).__name__})") from None
    out = []
    n = 1
    while f"id#{n}" in props:
        g = lambda k, d=None: props.get(f"{k}#{n}", d)  # noqa: E731
        try:
            rot = g("modelRotation")
            out.append(FurnitureItem(
                id=g("id"), name=g("name", g("id")), category=g("category", ""), archive=archive.stem,
                model=g("model").lstrip("/"),
                size=(float(g("width")) / 100, float(g("depth")) / 100, float(g("height")) / 100),
                drop_on_top=None if g("dropOnTopElevation") is None else float(g("dropOnTopElevation")) / 100,
                elevation=float(g("elevation", "0")) / 100, creator=g("creator", ""),
                rotation=None if rot is None else tuple(float(x) for x in rot.split()),
                door_or_window=g("doorOrWindow", "false") == "true", light=g("lightSourceX") is not None,
            ))
        except (TypeError, ValueError):
            pass  # an entry without a model or a size cannot be placed
        n += 1
    return out


@functools.lru_cache(maxsize=4)
def _catalogue(folder: str) -> tuple[FurnitureItem, ...]:
    root = Path(folder)
    archives = sorted(root.glob("*.sh3f")) if root.is_dir() else []
    if not archives:
        raise LibraryError(
            f"{root}: no Sweet Home 3D furniture (*.sh3f); install the Debian package sweethome3d-furniture "
            "(make install does) or set SPECSYNTH_SH3D_DIR"
        )
    return tuple(item for a in archives for item in _items(a))


def catalogue() -> tuple[FurnitureItem, ...]:
    """Every model of the installed library, in archive then catalogue order."""
    return _catalogue(str(library_dir()))


@functools.lru_cache(maxsize=4)
def _by_id(folder: str) -> dict[str, FurnitureItem]:
    return {item.id: item for item in _catalogue(folder)}


SMALL_MAX = 0.45  # metres: catalogue items up to this size are small (books, cups, plants, toys)
SMALL_CATEGORIES = ("Kitchen", "Office", "Living room", "Bedroom", "Miscellaneous")


def small_items() -> list[FurnitureItem]:
    """Small free-standing catalogue items: what stands on real tables, shelves and counters
    (``random_room``'s clutter) or is dropped among the objects (``catalogue/*`` distractors)."""
    return [i for i in catalogue() if i.category in SMALL_CATEGORIES and max(i.size) <= SMALL_MAX
            and i.elevation == 0 and not i.light and not i.door_or_window and min(i.size[0], i.size[1]) > 0.03]


def find(item_id: str) -> FurnitureItem:
    item = _by_id(str(library_dir())).get(item_id)
    if item is not None:
        return item
    import difflib

    close = difflib.get_close_matches(item_id, [i.id for i in catalogue()], n=3)
    hint = f" (did you mean {', '.join(close)}?)" if close else ""
    raise LibraryError(f"furniture {item_id!r}: not in the Sweet Home 3D library{hint}")


def _referenced_maps(folder: Path) -> set[str]:
    """File names the folder's MTL files name in map_* / bump / norm statements."""
    names = set()
    for mtl in folder.glob("*.mtl"):
        for line in mtl.read_text(errors="replace").splitlines():
            parts = line.split()
            if len(parts) > 1 and parts[0].lower().startswith(("map_", "bump", "norm")):
                names.add(parts[-1].replace("\\", "/").rsplit("/", 1)[-1])
    return names


def extract(item: FurnitureItem, cache: Path) -> Path:
    """The model's OBJ, unpacked once (with its MTL and textures) into the cache."""
    archive = library_dir() / f"{item.archive}.sh3f"
    folder = item.model.rsplit("/", 1)[0]
    dest = Path(cache) / "library" / "sh3d" / item.archive / folder
    obj = dest / item.model.rsplit("/", 1)[1]
    if (dest / "manifest.json").is_file() and obj.is_file():
        return obj
    tmp = dest.parent / f".{dest.name}.{uuid.uuid4().hex[:8]}.tmp"
    manifest = {}
    try:
        with zipfile.ZipFile(archive) as z:
            for info in z.infolist():
                name = info.filename
                if info.is_dir() or not name.startswith(folder + "/") or "/" in name[len(folder) + 1:]:
                    continue
                if ".." in Path(name).parts:
                    raise LibraryError(f"{archive}: unsafe path in the archive")
                data = z.read(info)
                target = tmp / name[len(folder) + 1:]
                target.parent.mkdir(parents=True, exist_ok=True)
                target.write_bytes(data)
                manifest[target.name] = hashlib.sha256(data).hexdigest()
            # Some models share a texture kept in another model's folder: bring those along.
            by_base = {i.filename.rsplit("/", 1)[-1]: i for i in z.infolist() if not i.is_dir()}
            for name in _referenced_maps(tmp):
                if name not in manifest and name in by_base:
                    data = z.read(by_base[name])
                    (tmp / name).write_bytes(data)
                    manifest[name] = hashlib.sha256(data).hexdigest()
        if obj.name not in manifest:
            raise LibraryError(f"{archive}: {item.model} is missing from the archive")
        (tmp / "manifest.json").write_text(json.dumps({"archive": archive.name, "files": manifest}, sort_keys=True))
        dest.parent.mkdir(parents=True, exist_ok=True)
        try:
            tmp.rename(dest)
        except OSError:  # another worker unpacked it first: theirs is the same bytes
            pass
    except (OSError, zipfile.BadZipFile) as e:
        raise LibraryError(f"{archive}: cannot unpack {item.model} ({type(e).__name__})") from None
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return obj
