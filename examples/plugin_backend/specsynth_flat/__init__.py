"""``flat``: an example specsynth backend plugin that draws every mesh in its unlit base colour.

What a plugin provides, all of it here:
- an options model subclassing ``specsynth.spec.models.BackendOptions`` with ``name: Literal["flat"]``:
  the spec's ``backend:`` block is validated by it (unknown keys are located errors);
- a ``BackendPlugin`` object, registered under the ``specsynth.backends`` entry point, that is
  cheap to import (no OpenGL here): the compiler reads it without rendering anything;
- the renderer class (``specsynth_flat.backend``), imported only in the processes that render.
"""

from typing import Literal

from pydantic import Field, field_validator

from specsynth.plugins import BackendPlugin, Capabilities
from specsynth.spec.models import BackendOptions


class FlatOptions(BackendOptions):
    name: Literal["flat"] = "flat"
    background: tuple[float, float, float] = Field(
        (0.5, 0.6, 0.7), description="Colour where no mesh is drawn: sRGB, each in [0, 1]."
    )

    @field_validator("background")
    @classmethod
    def _in_unit_range(cls, v):
        if not all(0.0 <= c <= 1.0 for c in v):
            raise ValueError("each channel must be in [0, 1]")
        return v


PLUGIN = BackendPlugin(
    name="flat",
    options=FlatOptions,
    backend="specsynth_flat.backend:FlatBackend",
    # No lights, no noise: it draws the whole scene, has nothing to denoise.
    capabilities=Capabilities(draws_scene=True, denoise=False, material_channels=frozenset({"base_color"}),
                              quality="rasterised: one sample per pixel; the preset is ignored"),
    distributions=("pyrender",),
    cost=(0.05, 0.0),
    install_hint="pip install examples/plugin_backend  (and apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri)",
)
