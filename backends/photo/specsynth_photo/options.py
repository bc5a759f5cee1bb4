"""The ``backend:`` block for the photo baseline (pydantic only: never imports OpenGL)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field

from specsynth.spec.models import Augment, BackendOptions, FloatRange, IntRange


class PhotoOptions(BackendOptions):
    name: Literal["photo"] = "photo"
    backgrounds: str = Field(
        "builtin", description="'builtin' (scikit-image photos + HDRI crops) or a folder of photographs."
    )
    lights: IntRange(0) = Field((1, 3), description="Random point/directional lights per image.")
    ambient: FloatRange(0.0, 10.0) = Field((0.1, 0.4), description="Ambient light intensity range.")
    augment: Augment = Augment()

    def input_folders(self) -> dict[str, str]:
        return {} if self.backgrounds == "builtin" else {"backgrounds": self.backgrounds}

    def relative_to(self, spec_dir) -> PhotoOptions:
        if self.backgrounds == "builtin" or Path(self.backgrounds).expanduser().is_absolute():
            return self
        return self.model_copy(update={"backgrounds": str(Path(spec_dir) / self.backgrounds)})
