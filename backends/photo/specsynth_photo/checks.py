"""``specsynth doctor``'s check of the photo backend: its built-in backgrounds (scikit-image's
photographs and the HDR panoramas that come with other installed packages). OpenGL itself is the
core's EGL check: the annotation engine needs it too."""

from __future__ import annotations

from specsynth.plugins import Check, dist_version

from .backgrounds import hdri_paths, skimage_photo_names


def checks() -> list[Check]:
    photos, panos = skimage_photo_names(), hdri_paths()
    ok = bool(photos or panos)
    return [Check("photo backgrounds", ok,
                  f"{len(photos)} scikit-image photographs and {len(panos)} HDR panoramas built in "
                  f"(scikit-image {dist_version('scikit-image')})",
                  "" if ok else "pip install --force-reinstall scikit-image (its sample photographs)")]
