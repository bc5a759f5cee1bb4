"""``albedo/``: every surface's unlit diffuse colour, drawn from the labels' scene and camera."""

from __future__ import annotations

from ..output_api import Files, View, ViewProduct


class Albedo(ViewProduct):
    name = "albedo"
    revision = 2  # 2: base colours and vertex colours encoded as the texture is (they were drawn too dark)
    description = ("Albedo maps (each surface's diffuse colour: base colour x texture x vertex colours, "
                   "unlit), 8-bit sRGB PNG, into albedo/.")

    def write(self, view: View) -> Files:
        from ..outputs.images import write_png

        write_png(view.folder / "albedo.png", view.albedo())
        return {"albedo": "albedo.png"}


PRODUCT = Albedo()
