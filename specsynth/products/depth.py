"""``depth/``: the annotation engine's exact z-depth as BOP's uint16 PNG (``value * depth_scale = mm``)."""

from __future__ import annotations

from ..output_api import Files, View, ViewProduct


class Depth(ViewProduct):
    name = "depth"
    description = ("Depth maps: the exact z-depth as uint16 PNG, value x depth_scale = millimetres, 0 where "
                   "nothing is, into depth/.")
    default = True

    def write(self, view: View) -> Files:
        from ..outputs.images import write_png

        write_png(view.folder / "depth.png", view.depth16()[0])
        return {"depth": "depth.png"}


PRODUCT = Depth()
