"""``normals/``: camera-space unit surface normals from the annotation's depth, so every backend gets
the same map."""

from __future__ import annotations

from ..output_api import Files, View, ViewProduct


class Normals(ViewProduct):
    name = "normals"
    description = ("Camera-space unit surface normals (OpenCV axes: x right, y down, z forward), "
                   "float32 OpenEXR RGB = (nx, ny, nz), 0 where empty, into normals/.")

    def write(self, view: View) -> Files:
        from ..annotate.maps import normals_from_depth
        from ..outputs.images import write_exr

        write_exr(view.folder / "normals.exr", normals_from_depth(view.annotation.depth, view.camera.K_array, view.rays))
        return {"normals": "normals.exr"}


PRODUCT = Normals()
