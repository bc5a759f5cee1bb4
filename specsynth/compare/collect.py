"""Every statistic of a split, streamed: images are read, measured and dropped one at a time.

Per image: the appearance statistics (``imagestats``), the in-plane rotation and the number of
instances; per visible instance (at least one visible pixel): distance, elevation, size,
truncation and visible fraction; per object, its look inside its visible mask, on at most
``MAX_OBJECT_IMAGES`` images spread evenly over the split (reading every mask of a big split
would cost more than everything else). What is kept is a few numbers per image and instance (about
70 bytes per instance, 80 per image), whatever the images' size; the split is read scene by scene
as the images are measured.
"""

from __future__ import annotations

import math
import os
from array import array
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from .. import processes
from . import geometry
from .imagestats import IMAGE_STATS, OBJECT_STATS, image_stats, object_stats
from .split import MASK_MODES, Split, SplitError, SplitImage, check_orientation, open_image

MAX_OBJECT_IMAGES = 1000
MIN_VISIB = 0.1  # an instance counts in "instances per image" from this visible fraction (BOP'19 targets)
INSTANCE_STATS = ("distance", "elevation", "size", "truncation", "visib_fract")
INSTANCE_PLACE = ("centre_offset",)  # not compared: where the instance is in its image
CHUNK = 16


@dataclass
class Collected:
    """Columns of numbers, one row per image / visible instance / measured object."""

    images: dict[str, np.ndarray] = field(default_factory=dict)  # IMAGE_STATS + inplane, aim_offset, instances
    # obj_id + INSTANCE_STATS, and where each instance is: its image's row and its centre offset
    instances: dict[str, np.ndarray] = field(default_factory=dict)
    objects: dict[str, np.ndarray] = field(default_factory=dict)  # obj_id + OBJECT_STATS, and its image's row
    up: str = "world"  # how the scene's up was known: "world" (cam_R_w2c) or "objects"
    n_images: int = 0
    samples: list[str] = field(default_factory=list)  # image files picked for the sheet


GREY16 = ("I;16", "I;16B", "I;16L")


def _read_rgb(path) -> np.ndarray:
    """8-bit RGB. A 16-bit grey image is scaled to 8 bits (PIL's conversion would clip it at 255)."""
    with open_image(path) as im:
        im.load()
        check_orientation(im, path)  # again: a PNG's eXIf chunk may follow its pixels
        if im.mode in GREY16:
            grey = np.rint(np.asarray(im, np.float64) / 257.0).astype(np.uint8)
            return np.repeat(grey[..., None], 3, axis=2)
        if im.mode in ("I", "F"):
            raise SplitError(f"{path}: the image has 32-bit pixels; expected 8 or 16 bits per channel")
        return np.asarray(im if im.mode == "RGB" else im.convert("RGB"))


def _read_mask(path, shape: tuple[int, int]) -> np.ndarray:
    """A visible mask of an image of ``shape`` (rows, columns): one channel, the image's size."""
    with open_image(path, "mask") as m:
        if m.mode not in MASK_MODES:
            raise SplitError(f"{path}: a mask must be one 8-bit channel (a grey PNG)")
        if m.size != (shape[1], shape[0]):
            raise SplitError(f"{path}: the mask is {m.size[0]} x {m.size[1]} pixels, its image "
                             f"{shape[1]} x {shape[0]}")
        return np.asarray(m) > 0


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
            s = object_stats(rgb, _read_mask(im.mask_visib[k], rgb.shape[:2]))
            if s is not None:
                row["objects"].append((inst.obj_id, *(s[name] for name in OBJECT_STATS)))
    row["n_instances"] = n
    row["aim_offset"] = _aim_offset(im)
    return row


def _aim_offset(im: SplitImage) -> float:
    """The aim fraction of the visible instance nearest the image centre: the object a specsynth
    camera aims at (``geometry.aim_fraction``); nan without one."""
    seen = [i for i in im.instances if i.px_count_visib]
    if not seen:
        return math.nan
    nearest = min(seen, key=lambda i: geometry.centre_offset(i.t_m2c, im.K))
    return geometry.aim_fraction(nearest.t_m2c, im.K, im.width, im.height)


def _batches(split: Split, step: int, picks: set[int], samples: list[str]):
    """Chunks of (image, measure its objects?) in split order; records the sheet's sample files."""
    batch = []
    for i, im in enumerate(split.iter_images()):
        if i in picks:
            samples.append(str(im.rgb))
        batch.append((im, i % step == 0))
        if len(batch) == CHUNK:
            yield batch
            batch = []
    if batch:
        yield batch


def _measure_batch(args) -> list[dict]:
    batch, use_world_up = args
    return [measure_image(im, use_world_up, with_objects) for im, with_objects in batch]


def _init_worker() -> None:
    processes.one_blas_thread()
    processes.steady_malloc()


def _rows(batches, use_world_up: bool, jobs: int):
    """Measured rows in split order; at most a few chunks in flight, so memory does not grow with
    the split. Workers start from a fresh server process, not a copy of this one."""
    if jobs <= 1:
        for b in batches:
            yield from _measure_batch((b, use_world_up))
        return
    import multiprocessing as mp
    from collections import deque

    with ProcessPoolExecutor(jobs, mp_context=mp.get_context("forkserver"), initializer=_init_worker) as pool:
        pending: deque = deque()
        for b in batches:
            pending.append(pool.submit(_measure_batch, (b, use_world_up)))
            if len(pending) >= 4 * jobs:
                yield from pending.popleft().result()
        while pending:
            yield from pending.popleft().result()


def collect(split: Split, jobs: int = 0, max_object_images: int = MAX_OBJECT_IMAGES, n_samples: int = 8) -> Collected:
    """Measure every image of ``split`` (gt info and masks must be present: ``gtinfo.complete``)."""
    n = split.n_images
    step = max(1, math.ceil(n / max_object_images))
    picks = set(np.linspace(0, n - 1, min(n_samples, n)).round().astype(int).tolist()) if n else set()
    jobs = jobs or min(len(os.sched_getaffinity(0)), 8)
    out = Collected(n_images=n, up="world" if split.synthetic else "objects")
    images: dict[str, list] = {k: [] for k in (*IMAGE_STATS, "inplane", "aim_offset", "instances")}
    inst, obj, per_image, obj_per_image = array("d"), array("d"), [], []  # 8 bytes a number, not a Python float
    for r in _rows(_batches(split, step, picks, out.samples), split.synthetic, jobs if n > CHUNK else 1):
        for k in IMAGE_STATS:
            images[k].append(r["image"][k])
        images["inplane"].append(r["inplane"])
        images["aim_offset"].append(r["aim_offset"])
        images["instances"].append(r["n_instances"])
        for t in r["instances"]:
            inst.extend(t)
        for t in r["objects"]:
            obj.extend(t)
        per_image.append(len(r["instances"]))
        obj_per_image.append(len(r["objects"]))
    out.images = {k: np.array(v, np.float64) for k, v in images.items()}
    cols = INSTANCE_STATS + INSTANCE_PLACE
    a = np.frombuffer(inst, np.float64).copy().reshape(-1, 1 + len(cols))
    out.instances = {"obj_id": a[:, 0].astype(int), **{k: a[:, 1 + i] for i, k in enumerate(cols)},
                     "image": np.repeat(np.arange(len(per_image)), per_image)}
    b = np.frombuffer(obj, np.float64).copy().reshape(-1, 1 + len(OBJECT_STATS))
    out.objects = {"obj_id": b[:, 0].astype(int), **{k: b[:, 1 + i] for i, k in enumerate(OBJECT_STATS)},
                   "image": np.repeat(np.arange(len(obj_per_image)), obj_per_image)}
    return out
