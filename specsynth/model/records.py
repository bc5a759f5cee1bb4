"""Result records of the jobs: plain, JSON-serialisable, what the cache stores and writers read.

Units: poses in metres here; BOP writers convert to millimetres at the edge.
Image ids: ``index = arr * cameras.per_arrangement + cam``; BOP ``chunk = index // chunk_size``,
``im_id = index % chunk_size``. Dropped views leave gaps, so ids stay stable across rebuilds.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any


@dataclass
class PlacedObject:
    obj_id: int
    inst: int  # index among the arrangement's kept objects: the gt order of every view
    name: str  # asset name (built-in name or obj_XXXXXX)
    pose: list[list[float]]  # 4x4 world-from-model, metres
    color: list[float] | None = None  # painted: the linear RGB base colour replacing the model's own


@dataclass
class ArrangementRecord:
    arr: int
    scene: str
    stage: str
    objects: list[PlacedObject]
    dropped: int = 0  # objects instantiated
    removed: int = 0  # removed by validation (left the stage, penetrating, NaN)
    redropped: int = 0
    settled: bool = True
    sim_seconds: float = 0.0  # simulated time
    seed: int = 0
    credits: list[dict] = field(default_factory=list)  # third-party assets of its scene (attribution)
    distractors: list[PlacedObject] = field(default_factory=list)  # part of the scene: not annotated

    @property
    def scene_ref(self) -> tuple[str, int | None]:
        """(the spec's scene ref, the procedural variant or None): ``scene`` is "random_room#123"
        for a procedural scene, whose room is drawn from that seed."""
        name, _, variant = self.scene.partition("#")
        return name, int(variant) if variant else None

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "ArrangementRecord":
        d = dict(d)
        d["objects"] = [PlacedObject(**o) for o in d["objects"]]
        d["distractors"] = [PlacedObject(**o) for o in d.get("distractors", [])]
        return cls(**d)


@dataclass
class ViewRecord:
    """One accepted (or dropped) camera of an arrangement."""

    arr: int
    cam: int
    index: int  # global image index (see module doc)
    accepted: bool
    tries: int  # cameras sampled, the accepted one included
    focus_inst: int = -1
    focus_visib_fract: float = 0.0
    R_w2c: list[list[float]] = field(default_factory=list)
    t_w2c: list[float] = field(default_factory=list)  # metres
    azimuth: float = 0.0  # degrees, of the accepted camera
    elevation: float = 0.0
    distance: float = 0.0  # metres
    rejected_seconds: float = 0.0  # annotation-engine time spent on rejected cameras
    seed: int = 0

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "ViewRecord":
        return cls(**d)


@dataclass
class InstanceGT:
    """BOP scene_gt + scene_gt_info entries of one object instance in one image."""

    obj_id: int
    inst: int
    R_m2c: list[list[float]]
    t_m2c: list[float]  # metres
    bbox_obj: list[int]  # [x, y, w, h], unclipped
    bbox_visib: list[int]  # [-1,-1,-1,-1] when nothing is visible
    px_count_all: int
    px_count_valid: int
    px_count_visib: int
    visib_fract: float


@dataclass
class ImageRecord:
    """A rendered image with its annotations and its files, which are relative to the job's store folder."""

    arr: int
    cam: int
    index: int
    scene: str
    stage: str
    backend: str
    backend_version: str
    quality: str
    seed: int
    width: int
    height: int
    K: list[list[float]]
    R_w2c: list[list[float]]
    t_w2c: list[float]  # metres
    depth_scale: float  # the depth files' (value * depth_scale = mm)
    instances: list[InstanceGT]
    # By kind: "rgb" (always) and what each product wrote, e.g. "depth": "depth.png", "mask":
    # ["mask_000000.png", ...] (one per instance, in gt order). See specsynth.output_api.
    files: dict[str, Any]
    distortion: list[float] | None = None  # OpenCV [k1, k2, p1, p2, k3] the image was warped with
    eye: str | None = None  # "left" / "right" in a stereo build (the left camera is the view's)
    baseline: float | None = None  # metres between the eyes, along the left camera's +x
    # Other images of the view by name (a stereo rig's "right"): their records, files under <name>/.
    companions: dict[str, dict[str, Any]] = field(default_factory=dict)
    render_seconds: float = 0.0
    stats: dict[str, Any] = field(default_factory=dict)

    def file(self, kind: str) -> str | None:
        """The image's one file of ``kind``, None when it has none."""
        name = self.files.get(kind)
        return name if isinstance(name, str) else None

    def instance_files(self, kind: str) -> list[str]:
        """The image's per-instance files of ``kind`` in gt order ([] when it has none)."""
        names = self.files.get(kind)
        return list(names) if isinstance(names, list) else []

    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "ImageRecord":
        d = dict(d)
        d["instances"] = [InstanceGT(**i) for i in d["instances"]]
        return cls(**d)
