#!/usr/bin/env bash
# Third-party assets for the built-in furnished scenes, from package registries only:
# - Sweet Home 3D's furniture library: Debian package sweethome3d-furniture (install-system-deps.sh);
# - robosuite's MIT surface textures: the PyPI wheel, unpacked into the cache (not the repo).
# Nothing is downloaded at run time. Usage: scripts/install-assets.sh PYTHON
set -euo pipefail
PY=${1:-.venv/bin/python}
cache=$("$PY" -c 'from specsynth.assets.resolve import cache_dir; print(cache_dir())')
if [ ! -f "$cache/library/robosuite-textures/manifest.json" ]; then
  tmp=$(mktemp -d)
  trap 'rm -rf "$tmp"' EXIT
  "$PY" -m pip download -q --no-deps "robosuite==1.5.2" -d "$tmp"
  "$PY" -m specsynth.assets.library.textures "$tmp"/robosuite-*.whl
fi
