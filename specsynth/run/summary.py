"""What a build reports: per-stage counts and seconds, and the summary written to
``.specsynth/summary.json`` (and printed by ``specsynth build``)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..model.error import error_ratio
from ..plan.compiler import STAGES


@dataclass
class StageStats:
    total: int = 0
    cached: int = 0
    ran: int = 0
    failed: int = 0
    seconds: float = 0.0


@dataclass
class BuildSummary:
    out: str
    backend: str
    stages: dict[str, StageStats] = field(default_factory=lambda: {s: StageStats() for s in (*STAGES, "merge")})
    views_accepted: int = 0
    views_dropped: int = 0
    cameras_rejected: int = 0
    rejected_seconds: float = 0.0
    objects_removed: int = 0
    objects_redropped: int = 0
    images: int = 0
    instances: int = 0
    failures: list[dict[str, str | int]] = field(default_factory=list)
    # What skipping saved, in seconds (estimates from this build's own measured render times).
    saved: dict[str, float] = field(default_factory=dict)
    glossy_bounces_skipped: int = 0  # renders whose scene had no glossy material
    # Worker-seconds of this build's renders by phase (render.<backend phase>, load, annotate,
    # encode, write): where the render stage's time went.
    render_phases: dict[str, float] = field(default_factory=dict)
    # Seconds of the merge by phase (collect the records, the models, write the formats, record the
    # files), in the main process: what a build spends after its last job.
    merge_phases: dict[str, float] = field(default_factory=dict)
    wall_seconds: float = 0.0
    workers: int = 0
    # From the first job's start to the last job's end, and the share of it the workers were busy
    # (worker-seconds / (workers x that span)); the rest is start-up, scheduling and the tail.
    run_seconds: float = 0.0
    utilisation: float = 0.0
    # True when this build failed or rendered nothing and the folder's last complete dataset was
    # left as it was; the failures are then in KEPT_FAILURES, not the dataset's failures.json.
    kept_previous: bool = False
    # quality.control: error: samples per image and estimated error / target over the images
    # (medians, 95th percentiles) and the share whose estimate is within 10 % of the target or below.
    error_control: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        d = self.__dict__.copy()
        d["stages"] = {k: v.__dict__ for k, v in self.stages.items()}
        return d


def error_control_summary(stats: list[dict]) -> dict[str, Any]:
    """Samples and estimated error against target over the images rendered to an error target."""
    got = [s for s in stats if "error_target" in s]  # a target of 0 too: an image without noise
    if not got:
        return {}
    samples = np.array([s["samples"] for s in got], float)
    ratio = error_ratio([s["error_estimate"] for s in got], [s["error_target"] for s in got])
    return {"images": len(got),
            "samples": {"median": float(np.median(samples)), "p95": float(np.percentile(samples, 95)),
                        "max": int(samples.max())},
            "error_ratio": {"median": round(float(np.median(ratio)), 4), "p95": round(float(np.percentile(ratio, 95)), 4)},
            "within_10_percent": round(float(np.mean(ratio <= 1.1)), 4)}
