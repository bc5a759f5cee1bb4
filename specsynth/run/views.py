"""The view step: per camera job, sample cameras aimed at a random object until one sees enough of
it (the visibility pre-check, through the lens when there is one) from free space, with nothing
filling the view in front of it."""

from __future__ import annotations

import time

import numpy as np

from ..model.records import ArrangementRecord, ViewRecord
from ..plan import seeds
from ..plan.compiler import Job
from ..plan.inputs import ViewInputs
from ..views import cameras
from .reports import Viewed
from .store import Store, stored
from .worker import Framed, Held, Optics, World


class ViewStep:
    """Finds the cameras of its own inputs, over a ``world`` of the same arrangement inputs and
    an ``annotator`` of the image's size (the renders' too: a view group and the renders of its
    arrangement on one worker load the scene into it once)."""

    def __init__(self, inputs: ViewInputs, world: World, annotator: Held, store: Store):
        if world.inputs != inputs.arrange:
            raise ValueError("the view step's world must be built from its own arrangement inputs")
        self.inputs, self.world, self.annotator, self.store = inputs, world, annotator, store
        self.optics = Optics(inputs.intrinsics)

    def run(self, arrange_key: str, jobs: list[Job]) -> list[Viewed]:
        """Find a camera for each view job of one arrangement and store its record (accepted or not)."""
        framed = self.world.frame(ArrangementRecord.from_json(self.store.load("arrange", arrange_key)))
        if framed.scene.objects():
            self.annotator.load(arrange_key, framed.scene)
        out = []
        for job in jobs:
            if self.store.has("view", job.key):  # finished before a retry
                continue
            rec = self.find(job, framed)
            self.store.put("view", job.key, rec.to_json())
            out.append(Viewed(job.id, job.key, rec.accepted, rec.tries, rec.rejected_seconds, stored(rec.to_json())))
        return out

    def find(self, job: Job, framed: Framed) -> ViewRecord:
        """Cameras aimed at a random object, drawn from the job's seed until one sees enough of it
        from free space (through the lens, the fraction is the distorted image's)."""
        inp, objects, origin = self.inputs, framed.scene.objects(), framed.origin
        annot, warp = self.annotator.get(), self.optics.warp
        rng = seeds.job_rng(inp.arrange.seed, job.id)
        rec = ViewRecord(arr=job.arr, cam=job.cam, index=job.arr * inp.cameras.per_arrangement + job.cam,
                         accepted=False, tries=0, seed=job.seed)
        rejected = 0.0
        for _ in range(inp.cameras.max_tries if objects else 0):
            focus = objects[int(rng.integers(len(objects)))]
            a = framed.assets[focus.obj_id]
            centre = np.asarray(a.bbox_min) + 0.5 * np.asarray(a.extents)
            target = (focus.matrix @ np.append(centre, 1.0))[:3] + origin  # world frame
            s = cameras.sample_camera(rng, target, inp.cameras, inp.intrinsics)
            t0 = time.perf_counter()
            cam = self.optics.camera(s.R_w2c, s.t_w2c, origin)
            vf = (annot.visib_fract_lens(cam, warp, inp.intrinsics.distortion, focus.inst, inp.visibility.delta)
                  if warp else annot.visib_fract(cam, focus.inst, inp.visibility.delta))
            rec.tries += 1
            if (vf >= inp.visibility.threshold and in_free_space(annot, s, origin, inp.cameras.clearance)
                    and in_open_view(annot, cam, s.distance, inp.visibility)):
                rec.accepted = True
                rec.focus_inst, rec.focus_visib_fract = focus.inst, float(vf)
                rec.R_w2c, rec.t_w2c = np.asarray(s.R_w2c).tolist(), np.asarray(s.t_w2c).tolist()
                rec.azimuth, rec.elevation, rec.distance = float(s.azimuth), float(s.elevation), float(s.distance)
                break
            rejected += time.perf_counter() - t0
        rec.rejected_seconds = rejected
        return rec


def in_free_space(annot, s, origin: np.ndarray, clearance: float) -> bool:
    """The camera stands in the open, ``cameras.clearance`` from every surface: not inside a
    wall, a piece of furniture or an object (where a renderer shows the inside of it)."""
    if clearance <= 0:
        return True
    eye = -np.asarray(s.R_w2c, np.float64).T @ np.asarray(s.t_w2c, np.float64)  # world frame
    return annot.free_distance(eye - origin) >= clearance


def in_open_view(annot, cam, distance: float, visibility) -> bool:
    """At most ``visibility.near_share`` of the image is nearer than ``visibility.near_distance`` of
    the way to the target: no wall, shelf or chair back fills the view, as none does in a
    photograph of a desk."""
    if visibility.near_share >= 1.0:
        return True
    return annot.near_share(cam, visibility.near_distance * distance) <= visibility.near_share
