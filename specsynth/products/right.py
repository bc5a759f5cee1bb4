"""The right eye of a stereo rig (``cameras.stereo``): another image of every view, the left camera
moved by the baseline along its own +x, with every product's files; the merge writes it as the split
``<split>_right`` with the same image ids."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..model.records import ImageRecord
from ..output_api import View, ViewProduct


class RightEye(ViewProduct):
    name = "right"
    description = ("The right eye of a stereo rig (cameras.stereo): every view rendered again from the left camera "
                   "moved by the baseline along its +x, written as the split <split>_right.")
    switch = False  # cameras.stereo turns it on
    kinds = ()  # no file of its own: the right eye's image has every product's

    def active(self, inputs) -> bool:
        return inputs.stereo is not None

    def other_images(self, inputs, t_w2c) -> dict[str, list[float]]:
        return {self.name: (np.asarray(t_w2c, np.float64) - [inputs.stereo.baseline, 0.0, 0.0]).tolist()}

    def finish(self, record: ImageRecord, view: View) -> ImageRecord:
        baseline = view.inputs.stereo.baseline
        right = replace(view.render_eye(self.other_images(view.inputs, record.t_w2c)[self.name], self.name),
                        eye="right", baseline=baseline)
        return replace(record, eye="left", baseline=baseline, companions={**record.companions, self.name: right.to_json()})


PRODUCT = RightEye()
