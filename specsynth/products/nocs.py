"""``nocs/``: each visible object pixel's point in its model's normalised frame (Wang et al. 2019)."""

from __future__ import annotations

import numpy as np

from ..output_api import Files, View, ViewProduct


class Nocs(ViewProduct):
    name = "nocs"
    description = ("NOCS maps (model-frame point / bounding-box diagonal + 0.5, in [0, 1]; Wang et al. "
                   "2019) of every visible object pixel, float32 OpenEXR RGB, 0 elsewhere (mask_visib says whose), "
                   "into nocs/.")

    def write(self, view: View) -> Files:
        from ..annotate.maps import nocs_map
        from ..outputs.images import write_exr

        ann = view.annotation
        diagonals = [float(np.linalg.norm(view.assets[g.obj_id].extents)) for g in ann.instances]
        poses = [(g.R_m2c, g.t_m2c) for g in ann.instances]
        write_exr(view.folder / "nocs.exr",
                  nocs_map(ann.depth, view.camera.K_array, ann.masks_visib, poses, diagonals, view.rays))
        return {"nocs": "nocs.exr"}


PRODUCT = Nocs()
