"""Whether a rendered image looks like a photograph to a user: the check of the tests that build
what the first hour builds (the starter spec, the tutorials)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

# A rendered image a user would take for a photograph: not speckle, not burnt out. Calibrated on
# the starter spec's room at 160 x 120 (its first two images): denoised and metered, a median
# |Laplacian| of luma of 17-27 levels and 0.1 % of pixels at 250 or more; one sample undenoised
# and unmetered, 262-319 levels and 4-6 %, up to 46 % in other rooms at 320 x 240.
SPECKLE_LEVELS = 100.0
BURNT_SHARE = 0.15


def photo_faults(path: Path) -> list[str]:
    """What keeps the 8-bit image at ``path`` from looking like a photograph (empty: nothing)."""
    luma = np.asarray(Image.open(path).convert("L"), np.float64)
    lap = np.abs(4 * luma[1:-1, 1:-1] - luma[:-2, 1:-1] - luma[2:, 1:-1] - luma[1:-1, :-2] - luma[1:-1, 2:])
    faults = []
    if np.median(lap) > SPECKLE_LEVELS:
        faults.append(f"{path.name}: speckle (median |Laplacian| {np.median(lap):.0f} levels)")
    if (luma >= 250).mean() > BURNT_SHARE:
        faults.append(f"{path.name}: burnt out ({(luma >= 250).mean():.0%} of pixels at 250 or more)")
    return faults
