"""``depth_noisy/``: what an RGB-D sensor would have measured (``sensor.depth``), beside the exact depth."""

from __future__ import annotations

import numpy as np

from ..output_api import Files, View, ViewProduct


class NoisyDepth(ViewProduct):
    name = "depth_noisy"
    description = ("An RGB-D sensor's depth (axial noise, holes at depth edges, dropout: sensor.depth), uint16 PNG "
                   "at the depth maps' scale, into depth_noisy/; written with depth when sensor.depth is set.")
    switch = False  # sensor.depth turns it on

    def active(self, inputs) -> bool:
        return "depth" in inputs.outputs.products and inputs.sensor.depth is not None

    def write(self, view: View) -> Files:
        from ..outputs.images import encode_depth, write_png
        from ..views.sensor import sensor_depth

        # The third of the image's three sensor streams (colour, JPEG quality, depth).
        rng = np.random.default_rng(np.random.SeedSequence(view.seed("sensor")).spawn(3)[2])
        noisy = sensor_depth(view.annotation.depth, view.inputs.sensor.depth, rng)
        write_png(view.folder / "depth_noisy.png", encode_depth(noisy, view.depth16()[1])[0])
        return {"depth_noisy": "depth_noisy.png"}


PRODUCT = NoisyDepth()
