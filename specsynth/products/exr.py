"""``exr/``: the backend's linear radiance before the camera model, as OpenEXR."""

from __future__ import annotations

from ..output_api import Files, View, ViewProduct


class Exr(ViewProduct):
    name = "exr"
    description = "The linear beauty pass as OpenEXR (float32 RGB, into exr/; none from a backend without one)."

    def write(self, view: View) -> Files:
        if view.result.linear is None:
            return {}
        from ..outputs.images import write_exr

        write_exr(view.folder / "rgb.exr", view.result.linear)
        return {"exr": "rgb.exr"}


PRODUCT = Exr()
