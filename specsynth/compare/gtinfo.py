"""Masks and ``scene_gt_info`` for a split that has none, from its poses and models.

The annotation engine renders every annotated model at its ground-truth pose with the BOP
toolkit's ``calc_gt_info`` rules (each object alone on a 3x canvas for ``bbox_obj`` and
``px_count_all``; visible where its distance is within ``delta`` of the scene's). The scene's
depth is the split's own depth image when it has one (as the toolkit does); without depth the
annotated objects are the only occluders (as the photo baseline's labels), which misses
occlusion by anything else in the photograph. The result is cached under ``<cache>/gtinfo/`` by
everything it depends on (the ground truth's, cameras', depth images' and models' bytes, the depth
scales, the renderer's version), so a split is annotated once.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..assets.library.cache import cache_dir
from ..atomic import atomic_write_bytes
from ..model.ir import CameraIR, MeshInstance, RenderScene, as_tuple
from .split import DEPTH_MODES, Split, SplitError, SplitImage, check_models, open_image

DELTA = 0.015  # metres: BOP's calc_gt_info default for real test images (15 mm)
VERSION = 1  # bump when what is computed here changes


def _digest_files(paths) -> str:
    h = hashlib.sha256()
    for p in paths:
        h.update(str(Path(p).name).encode())
        with open(p, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()


def _key(split: Split, models: dict[int, Path], with_depth: bool) -> str:
    from ..plugins import dist_version

    gt = _digest_files([s / "scene_gt.json" for s in split.scenes])
    # per image: what is rendered (its camera) and how its depth image reads as millimetres
    cams = [[im.key, im.K.tolist(), im.width, im.height, im.depth_scale if with_depth else None]
            for im in split.iter_images()]
    depth = _digest_files([im.depth for im in split.iter_images() if im.depth]) if with_depth else None
    return hashlib.sha256(json.dumps({"v": VERSION, "gt": gt, "cams": cams, "depth": depth, "delta": DELTA,
                                      "models": _digest_files(models[i] for i in sorted(models)),
                                      "pyrender": dist_version("pyrender")}).encode()).hexdigest()


def _uses_depth(split: Split) -> bool:
    """Whether computed masks take the split's depth images as the scene (every image has one)."""
    return split.has_depth and all(im.depth is not None for im in split.iter_images())


def annotated_occluders_only(split: Split) -> bool:
    """Whether ``split``'s visible masks are (or will be) computed with its annotated objects as the
    only occluders: it has no masks, and not every image has a depth image."""
    return not (split.has_gt_info and split.has_masks) and not _uses_depth(split)


def complete(split: Split, models_dir: Path | None = None, *, log=None, annotated_occluders: bool = False) -> Split:
    """``split`` with every instance's gt info and visible mask, computed where the split has none.
    ``annotated_occluders``: computed in any case, with the annotated objects as the only occluders
    (what a split without masks and depth gets), so that two splits are measured alike."""
    if split.has_gt_info and split.has_masks and not annotated_occluders:
        return split
    models = check_models(split, models_dir or split.models)
    with_depth = not annotated_occluders and _uses_depth(split)
    folder = cache_dir() / "gtinfo" / _key(split, models, with_depth)
    done = folder / "done.json"
    if not done.is_file():
        if log:
            why = ("as the other split's are" if annotated_occluders else
                   f"no {'masks' if split.has_gt_info else 'scene_gt_info.json or masks'}")
            log(f"{split.path}: {why}; computing masks from its poses and models "
                f"({'its depth images' if with_depth else 'the annotated objects'} as the occluders), once, into {folder}")
        _annotate_all(split, models, folder, with_depth)
        atomic_write_bytes(done, json.dumps({"images": split.n_images, "depth": with_depth}).encode())
    return replace(split, computed=folder, has_gt_info=True, has_masks=True)


def _scene_of(im: SplitImage, assets: dict) -> RenderScene:
    meshes = []
    for inst in im.instances:
        a = assets[inst.obj_id]
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = inst.R_m2c, inst.t_m2c
        meshes.append(MeshInstance(name=f"obj_{inst.obj_id:06d}_{inst.gt_index:03d}", mesh_path=a.mesh_path,
                                   mesh_key=a.mesh_key, pose=as_tuple(T), obj_id=inst.obj_id, inst=inst.gt_index))
    return RenderScene(meshes=tuple(meshes))


def _depth_m(im: SplitImage) -> np.ndarray:
    """The image's depth in metres (its header was checked by open_split; its pixels are read here)."""
    with open_image(im.depth, "depth image") as d:
        if d.mode not in DEPTH_MODES or d.size != (im.width, im.height):  # changed since it was opened
            raise SplitError(f"{im.depth}: a depth image must be one channel of 16 bits, the image's size")
        return np.asarray(d, np.float64).astype(np.float32) * np.float32(im.depth_scale / 1000.0)


def _annotate_all(split: Split, models: dict[int, Path], folder: Path, with_depth: bool) -> None:
    from ..annotate.engine import Annotator
    from ..assets.resolve import resolve_objects
    from ..outputs.images import write_mask
    from ..spec.models import Objects

    assets = {a.obj_id: a for a in resolve_objects(Objects(path=str(Path(next(iter(models.values()))).parent),
                                                           ids=sorted(models)), Path("."))}
    by_scene: dict[int, dict[str, list]] = {}
    annotators: dict[tuple[int, int], Annotator] = {}
    try:
        for im in split.iter_images():
            size = (im.width, im.height)
            if size not in annotators:
                annotators[size] = Annotator(*size)
            ann = annotators[size]
            ann.load(_scene_of(im, assets))
            cam = CameraIR(K=as_tuple(im.K), width=im.width, height=im.height, R_w2c=as_tuple(np.eye(3)),
                           t_w2c=(0.0, 0.0, 0.0), near=0.01, far=100.0)
            res = ann.annotate(cam, DELTA, "objects", scene_depth=_depth_m(im) if with_depth else None)
            scene_dir = folder / f"{im.scene_id:06d}"
            entries = []
            for k, g in enumerate(res.instances):
                write_mask(scene_dir / "mask_visib" / f"{im.im_id:06d}_{k:06d}.png", res.masks_visib[k])
                entries.append({"bbox_obj": g.bbox_obj, "bbox_visib": g.bbox_visib, "px_count_all": g.px_count_all,
                                "px_count_valid": g.px_count_valid, "px_count_visib": g.px_count_visib,
                                "visib_fract": g.visib_fract})
            by_scene.setdefault(im.scene_id, {})[str(im.im_id)] = entries
    finally:
        for ann in annotators.values():
            ann.close()
    for scene_id, info in by_scene.items():
        atomic_write_bytes(folder / f"{scene_id:06d}" / "scene_gt_info.json", json.dumps(info, sort_keys=True).encode())
