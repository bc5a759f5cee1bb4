"""The view step: per camera job, sample cameras aimed at a random object until one sees enough of
it (the visibility pre-check, through the lens when there is one) from free space."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from ..model.records import ArrangementRecord, ViewRecord
from ..plan import seeds
from ..plan.compiler import Job
from ..plan.inputs import ViewInputs
from ..views import cameras
from .worker import Worker


def run_views(w: Worker, inp: ViewInputs, arrange_key: str, jobs: list[Job]) -> list[dict[str, Any]]:
    """Find a camera for each view job of one arrangement and store its record (accepted or not)."""
    arr = ArrangementRecord.from_json(w.store.load("arrange", arrange_key))
    scene, origin = w.frame(arr)
    objects = scene.objects()
    annot = w.annotator()
    if objects:
        w.load("annotator", arrange_key, scene)
    by_id = w.assets_by_id(arr)
    warp = w.lens_warp()  # through a lens, the fraction is the distorted image's
    out = []
    for job in jobs:
        if w.store.has("view", job.key):  # finished before a retry
            continue
        rng = seeds.job_rng(inp.arrange.seed, job.id)
        rec = ViewRecord(arr=job.arr, cam=job.cam, index=job.arr * inp.cameras.per_arrangement + job.cam,
                         accepted=False, tries=0, seed=job.seed)
        rejected = 0.0
        for _ in range(inp.cameras.max_tries if objects else 0):
            focus = objects[int(rng.integers(len(objects)))]
            a = by_id[focus.obj_id]
            centre = np.asarray(a.bbox_min) + 0.5 * np.asarray(a.extents)
            target = (focus.matrix @ np.append(centre, 1.0))[:3] + origin  # world frame
            s = cameras.sample_camera(rng, target, inp.cameras)
            t0 = time.perf_counter()
            cam = w.camera(s.R_w2c, s.t_w2c, origin)
            vf = (annot.visib_fract_lens(cam, warp, inp.intrinsics.distortion, focus.inst, inp.visibility.delta)
                  if warp else annot.visib_fract(cam, focus.inst, inp.visibility.delta))
            rec.tries += 1
            if vf >= inp.visibility.threshold and in_free_space(annot, s, origin, inp.cameras.clearance):
                rec.accepted = True
                rec.focus_inst, rec.focus_visib_fract = focus.inst, float(vf)
                rec.R_w2c, rec.t_w2c = np.asarray(s.R_w2c).tolist(), np.asarray(s.t_w2c).tolist()
                rec.azimuth, rec.elevation, rec.distance = float(s.azimuth), float(s.elevation), float(s.distance)
                break
            rejected += time.perf_counter() - t0
        rec.rejected_seconds = rejected
        w.store.put("view", job.key, rec.to_json())
        out.append({"id": job.id, "accepted": rec.accepted, "tries": rec.tries, "rejected_seconds": rejected})
    return out


def in_free_space(annot, s, origin: np.ndarray, clearance: float) -> bool:
    """The camera stands in the open, ``cameras.clearance`` from every surface: not inside a
    wall, a piece of furniture or an object (where a renderer shows the inside of it)."""
    if clearance <= 0:
        return True
    eye = -np.asarray(s.R_w2c, np.float64).T @ np.asarray(s.t_w2c, np.float64)  # world frame
    return annot.free_distance(eye - origin) >= clearance
