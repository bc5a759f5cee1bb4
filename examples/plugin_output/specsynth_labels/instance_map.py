"""``instance_map``: one uint16 PNG per image whose pixels hold the visible object's gt index + 1
(0 where no annotated object is visible): every instance mask of an image in one file.

BOP's writer puts it in ``bop/<split>/<chunk>/instance_map/<im_id>.png`` and Parquet's images table
gets an ``instance_map`` column, neither knowing this module.
"""

from __future__ import annotations

import numpy as np

from specsynth.output_api import Files, View, ViewProduct


class InstanceMap(ViewProduct):
    name = "instance_map"
    description = "Instance label maps: each pixel's visible object's gt index + 1, 0 elsewhere, uint16 PNG, into instance_map/."

    def write(self, view: View) -> Files:
        from specsynth.outputs.images import write_png

        ann = view.annotation
        labels = np.zeros(ann.depth.shape, np.uint16)
        for gt, visible in enumerate(ann.masks_visib):
            labels[visible] = gt + 1
        write_png(view.folder / "instance_map.png", labels)
        return {"instance_map": "instance_map.png"}


PRODUCT = InstanceMap()
