"""``mask/`` and ``mask_visib/``: every object's silhouette and its visible part (BOP's 0/255 PNGs),
and the visible masks' RLEs beside them for the merge (``outputs.masks``)."""

from __future__ import annotations

from ..output_api import Files, View, ViewProduct


class Masks(ViewProduct):
    name = "masks"
    description = ("Each object's mask (its whole silhouette) and visible mask, 8-bit 0/255 PNG, into mask/ and "
                   "mask_visib/; COCO's segmentations and Parquet's RLEs are the visible ones (without masks: "
                   "boxes only).")
    default = True
    kinds = ("mask", "mask_visib")

    def write(self, view: View) -> Files:
        from ..outputs.images import write_mask
        from ..outputs.masks import write_visible_rles

        ann = view.annotation
        masks, visible = [], []
        for gt, (m, mv) in enumerate(zip(ann.masks, ann.masks_visib)):
            masks.append(f"mask_{gt:06d}.png")
            visible.append(f"mask_visib_{gt:06d}.png")
            write_mask(view.folder / masks[-1], m)
            write_mask(view.folder / visible[-1], mv)
        write_visible_rles(view.folder, ann.masks_visib)
        return {"mask": masks, "mask_visib": visible}


PRODUCT = Masks()
