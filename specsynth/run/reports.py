"""What a step reports back to the build for each job it finished: small typed records that travel
from the worker process to the scheduler. Each carries the job's record as the store holds it
(``Store.stored``), so the build and the merge need not read back what a worker just wrote."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ..assets.resolve import ObjectAsset


@dataclass(frozen=True)
class Arranged:
    """An arrangement settled (or found in the store: ``cached``)."""

    id: str
    key: str
    cached: bool = False
    objects: int = 0
    removed: int = 0
    redropped: int = 0
    record: dict[str, Any] | None = None
    # The worker's resolved models: the spec's objects, and this arrangement's annotated
    # distractors under their obj_ids (what the merge's BOP models and COCO categories need).
    models: tuple[ObjectAsset, ...] = ()
    distractors: tuple[ObjectAsset, ...] = ()


@dataclass(frozen=True)
class Viewed:
    """One view job: its camera accepted or dropped after ``tries``."""

    id: str
    key: str
    accepted: bool
    tries: int
    rejected_seconds: float
    record: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Rendered:
    """One render job: its render seconds and where the job's time went."""

    id: str
    key: str
    seconds: float
    phases: dict[str, float]
    record: dict[str, Any] = field(default_factory=dict)
