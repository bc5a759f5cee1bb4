"""Content keys: what a job's output depends on, hashed.

A key is the sha256 of canonical JSON of exactly the resolved inputs a job reads: named input
digests shared by all jobs of a stage (its inputs model, ``specsynth.plan.inputs``; asset hashes,
backend version, the stage's code version), the upstream job's key, and the job id.
"""

from __future__ import annotations

import hashlib
import json
from typing import Any

# Bump a stage's version when its code changes what it produces: its jobs and every
# downstream job then re-run.
# view 2 / render 2: the annotation engine draws back faces (a camera behind a wall no longer sees
# through it) and cuts coverage-mapped holes. arrange 2: scene colliders cut to the stage's
# neighbourhood (physics.collider_region). arrange 3: settling judged on mean speed over the hold
# window (physics._stays_calm), so jittering piles stop before max_time. render 3: a calibrated
# level with denoising turned off renders the paper preset's samples (plugins.options_for). arrange 4:
# collision hulls of at most 1024 support points (physics.HULL_DIRECTIONS). render 4: files recorded by
# kind (ImageRecord.files) and written by registered products: a render job of an earlier version is
# run again, never read. arrange 5: standing distractors with no free spot are left out, not stacked
# (physics.arrange's unstacked); distractors may be painted. arrange 6: paint in a toy's hues
# (run.arrange.PLASTIC_HUES), not any hue. render 5: auto exposure meters 4 x 4 zones
# (views.sensor.metered_luminance), not single pixels.
STAGE_VERSIONS = {"arrange": 6, "view": 2, "render": 6}

# A backend's own revision is in its plugin object (plugins.BackendPlugin.revision).


def canonical_json(obj: Any) -> bytes:
    return json.dumps(obj, sort_keys=True, separators=(",", ":"), ensure_ascii=False, allow_nan=False).encode("utf-8")


def digest(obj: Any) -> str:
    return hashlib.sha256(canonical_json(obj)).hexdigest()


def stage_digest(stage: str, inputs: dict[str, str]) -> str:
    """Digest of the inputs shared by every job of a stage."""
    return digest({"stage": stage, "version": STAGE_VERSIONS[stage], "inputs": inputs})


def job_key(stage_digest_: str, job_id: str, upstream: str | None = None) -> str:
    # Plain string concatenation: this runs once per job, millions of times for big specs.
    return hashlib.sha256(f"{stage_digest_}|{upstream or ''}|{job_id}".encode("utf-8")).hexdigest()
