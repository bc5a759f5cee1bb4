"""Every statistic of a split, streamed: images are read, measured and dropped one at a time.

Per image: the appearance statistics (``imagestats``), the in-plane rotation and the number of
instances; per visible instance (at least one visible pixel): distance, elevation, size,
truncation and visible fraction; per object, its look inside its visible mask, on at most
``MAX_OBJECT_IMAGES`` images spread evenly over the split (reading every mask of a big split
would cost more than everything else). What is kept is a few floats per image and instance, so
memory grows by ~100 bytes per image whatever the images' size.
"""

from __future__ import annotations

import math
import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from . import geometry
from .imagestats import IMAGE_STATS, OBJECT_STATS, image_stats, object_stats
from .split import Split, SplitError, SplitImage

MAX_OBJECT_IMAGES = 1000
MIN_VISIB = 0.1  # an instance counts in "instances per image" from this visible fraction (BOP'19 targets)
INSTANCE_STATS = ("distance", "elevation", "size", "truncation", "visib_fract")
INSTANCE_PLACE = ("centre_offset",)  # not compared: where the instance is in its image
CHUNK = 16


@dataclass
class Collected:
    """Columns of numbers, one row per image / visible instance / measured object."""

    images: dict[str, np.ndarray] = field(default_factory=dict)  # IMAGE_STATS + inplane, instances
    # obj_id + INSTANCE_STATS, and where each instance is: its image's row and its centre offset
    instances: dict[str, np.ndarray] = field(default_factory=dict)
    objects: dict[str, np.ndarray] = field(default_factory=dict)  # obj_id + OBJECT_STATS
    up: str = "world"  # how the scene's up was known: "world" (cam_R_w2c) or "objects"
    n_images: int = 0
    samples: list[str] = field(default_factory=list)  # image files picked for the sheet


def _read_rgb(path) -> np.ndarray:
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            return np.asarray(im.convert("RGB"))
    except (UnidentifiedImageError, OSError, ValueError):
        raise SplitError(f"{path}: the image cannot be decoded") from None


def _read_mask(path) -> np.ndarray | None:
    from PIL import Image

    if path is None:
        return None
    try:
        with Image.open(path) as m:
            return np.asarray(m) > 0
    except OSError:
        raise SplitError(f"{path}: the mask cannot be decoded") from None


def measure_image(im: SplitImage, use_world_up: bool, with_objects: bool) -> dict:
    """Everything measured on one image (runs in a worker process)."""
    rgb = _read_rgb(im.rgb)
    up = geometry.up_from_world(im.R_w2c) if (use_world_up and im.R_w2c is not None) else \
        geometry.up_from_objects([i.R_m2c for i in im.instances])
    row = {"image": image_stats(rgb), "inplane": geometry.inplane(up) if up is not None else math.nan,
           "instances": [], "objects": []}
    n = 0
    for k, inst in enumerate(im.instances):
        if not inst.px_count_visib:
            continue
        n += inst.visib_fract >= MIN_VISIB
        row["instances"].append((inst.obj_id, geometry.distance(inst.t_m2c),
                                 geometry.elevation(inst.t_m2c, up) if up is not None else math.nan,
                                 geometry.box_size(inst.bbox_obj), geometry.truncation(inst.bbox_obj, im.width, im.height),
                                 float(inst.visib_fract), geometry.centre_offset(inst.t_m2c, im.K)))
        if with_objects and k < len(im.mask_visib):
            mask = _read_mask(im.mask_visib[k])
            if mask is not None and mask.shape == rgb.shape[:2]:
                s = object_stats(rgb, mask)
                if s is not None:
                    row["objects"].append((inst.obj_id, *(s[name] for name in OBJECT_STATS)))
    row["n_instances"] = n
    return row


def _measure_chunk(args) -> list[dict]:
    ims, use_world_up, flags = args
    return [measure_image(im, use_world_up, f) for im, f in zip(ims, flags)]


def collect(split: Split, jobs: int = 0, max_object_images: int = MAX_OBJECT_IMAGES, n_samples: int = 8) -> Collected:
    """Measure every image of ``split`` (gt info and masks must be present: ``gtinfo.complete``)."""
    ims = split.images
    n = len(ims)
    step = max(1, math.ceil(n / max_object_images))
    flags = [i % step == 0 for i in range(n)]
    use_world_up = split.synthetic
    chunks = [(ims[k:k + CHUNK], use_world_up, flags[k:k + CHUNK]) for k in range(0, n, CHUNK)]
    jobs = jobs or min(len(os.sched_getaffinity(0)), 8)
    if jobs > 1 and n > CHUNK:
        with ProcessPoolExecutor(jobs) as pool:
            rows = [r for chunk in pool.map(_measure_chunk, chunks) for r in chunk]
    else:
        rows = [r for c in chunks for r in _measure_chunk(c)]
    out = Collected(n_images=n, up="world" if use_world_up else "objects")
    out.images = {k: np.array([r["image"][k] for r in rows], np.float64) for k in IMAGE_STATS}
    out.images["inplane"] = np.array([r["inplane"] for r in rows], np.float64)
    out.images["instances"] = np.array([r["n_instances"] for r in rows], np.float64)
    cols = INSTANCE_STATS + INSTANCE_PLACE
    inst = np.array([t for r in rows for t in r["instances"]], np.float64).reshape(-1, 1 + len(cols))
    out.instances = {"obj_id": inst[:, 0].astype(int), **{k: inst[:, 1 + i] for i, k in enumerate(cols)},
                     "image": np.repeat(np.arange(len(rows)), [len(r["instances"]) for r in rows])}
    obj = np.array([t for r in rows for t in r["objects"]], np.float64).reshape(-1, 1 + len(OBJECT_STATS))
    out.objects = {"obj_id": obj[:, 0].astype(int), **{k: obj[:, 1 + i] for i, k in enumerate(OBJECT_STATS)}}
    picks = np.linspace(0, n - 1, min(n_samples, n)).round().astype(int) if n else []
    out.samples = [str(ims[i].rgb) for i in picks]
    return out
