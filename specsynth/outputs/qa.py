"""Visual QA of a built dataset: contact sheets (`specsynth view`) and statistics (`specsynth stats`).

Reads only the BOP output (and the build summary), so it works on any BOP-format dataset folder.
"""

from __future__ import annotations

import json
import os
import stat
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from ..atomic import atomic_write_bytes, atomic_write_via
from ..files import (RepeatedKey, UnsafeOutput, inside, is_image_id, loads_json_strict, output_file, output_folder,
                     refuse_links_out)
from ..model.error import error_ratio


class DatasetFileError(ValueError):
    """A file of a built dataset that cannot be read; the message names it (never its contents)."""


MAX_JSON_BYTES = 256 << 20  # a BOP chunk's scene_gt.json of 1,000 crowded images is a few MB
MAX_BOX = 1 << 20  # pixels: no image is wider; a box beyond it is a damaged file, not an object


def read_json(path: Path, root: Path | None = None):
    """A JSON file of a dataset, or an error naming it (never its contents): a regular file (a FIFO
    would hang the reader), inside ``root`` once links are resolved, of a sane size, every key of
    an object once."""
    path = Path(path)
    try:
        st = os.stat(path)
    except OSError as e:
        raise DatasetFileError(f"{path}: unreadable JSON ({type(e).__name__})") from None
    if not stat.S_ISREG(st.st_mode):
        raise DatasetFileError(f"{path}: not a regular file")
    if root is not None and not inside(path, root):
        raise DatasetFileError(f"{path}: a link out of the dataset folder {root}")
    if st.st_size > MAX_JSON_BYTES:
        raise DatasetFileError(f"{path}: larger than {MAX_JSON_BYTES >> 20} MiB")
    try:
        return loads_json_strict(path.read_bytes())
    except RepeatedKey:
        raise DatasetFileError(f"{path}: an object names one key twice") from None
    except (OSError, ValueError, RecursionError) as e:  # RecursionError: nested too deep to decode
        raise DatasetFileError(f"{path}: unreadable JSON ({type(e).__name__})") from None


def open_image(path: Path):
    """The image loaded (not lazily), or an error naming the file."""
    try:
        im = Image.open(path)
        im.load()
        return im
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as e:
        raise DatasetFileError(f"{path}: unreadable image ({type(e).__name__})") from None


def read_parquet(path: Path, columns: tuple[str, ...] = ()):
    """A Parquet table of a dataset with at least ``columns``, or an error naming what is wrong."""
    import pyarrow.parquet as pq

    try:
        table = pq.read_table(path).to_pandas()
    except (OSError, ValueError) as e:
        raise DatasetFileError(f"{path}: unreadable Parquet ({type(e).__name__})") from None
    missing = [c for c in columns if c not in table.columns]
    if missing:
        raise DatasetFileError(f"{path}: no column {missing[0]!r}")
    return table


@dataclass(frozen=True)
class BopImage:
    chunk: Path
    im_id: int
    rgb: Path
    gt: list[dict]
    gt_info: list[dict]  # checked: bbox_visib (4 ints), visib_fract in [0, 1], px_count_visib
    camera: dict

    def mask_visib(self, gt_id: int) -> np.ndarray | None:
        p = self.chunk / "mask_visib" / f"{self.im_id:06d}_{gt_id:06d}.png"
        if not p.is_file():
            return None
        if not inside(p, self.chunk):
            raise DatasetFileError(f"{p}: a link out of the dataset")
        return np.asarray(open_image(p)) > 127


def _split_dirs(out: Path) -> list[Path]:
    """The chunk folders (``bop/<split>/<chunk>``), each named by its number and inside ``out``."""
    bop = out / "bop" if (out / "bop").is_dir() else out
    chunks = sorted(p.parent for p in bop.glob("*/*/scene_gt.json"))
    seen: dict[tuple[str, int], Path] = {}
    for chunk in chunks:
        name = chunk.name
        if not (name.isascii() and name.isdigit()):
            raise DatasetFileError(f"{chunk}: a chunk folder is named by its number (000000)")
        if not inside(chunk, out):
            raise DatasetFileError(f"{chunk}: a link out of the dataset folder {out}")
        key = (chunk.parent.name, int(name))
        if key in seen:
            raise DatasetFileError(f"{chunk}: the same chunk number as {seen[key]}")
        seen[key] = chunk
    return chunks


def _image_ids(table, path: Path) -> dict[int, object]:
    """A BOP per-image table (an object keyed by image id) -> {im_id: value}."""
    if not isinstance(table, dict):
        raise DatasetFileError(f"{path}: expected an object keyed by image id")
    out = {}
    for k, v in table.items():
        if not is_image_id(k):
            raise DatasetFileError(f"{path}: a key that is not an image id (digits, no leading zeros)")
        out[int(k)] = v
    return out


def _annotations(v, path: Path, im: int) -> list[dict]:
    if not isinstance(v, list) or not all(isinstance(e, dict) for e in v):
        raise DatasetFileError(f"{path}: image {im}: expected a list of objects")
    return v


def _number(v, path: Path, where: str, lo: float, hi: float) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not (lo <= v <= hi):  # NaN fails too
        raise DatasetFileError(f"{path}: {where}: expected a number in [{lo:g}, {hi:g}]")
    return float(v)


def _gt_entry(e: dict, path: Path, where: str) -> dict:
    oid = e.get("obj_id")
    if isinstance(oid, bool) or not isinstance(oid, int) or oid < 1:
        raise DatasetFileError(f"{path}: {where}: obj_id must be a positive integer")
    return e


def _info_entry(e: dict, path: Path, where: str) -> dict:
    """The gt_info fields the commands read, checked and as numbers (a damaged file is named)."""
    box = e.get("bbox_visib")
    if not isinstance(box, list) or len(box) != 4:
        raise DatasetFileError(f"{path}: {where}: bbox_visib must be a list of 4 numbers")
    x, y, w, h = (int(_number(b, path, f"{where}.bbox_visib", -MAX_BOX, MAX_BOX)) for b in box)
    return {**e, "bbox_visib": [x, y, w, h],
            "visib_fract": _number(e.get("visib_fract", 0.0), path, f"{where}.visib_fract", 0.0, 1.0),
            "px_count_visib": int(_number(e.get("px_count_visib", 0), path, f"{where}.px_count_visib", 0, MAX_BOX ** 2))}


def _chunk_tables(chunk: Path, root: Path) -> tuple[dict, dict, dict]:
    """scene_gt, scene_gt_info (empty without the file) and scene_camera of a chunk, by image id."""
    gt_path, info_path, cam_path = (chunk / f for f in ("scene_gt.json", "scene_gt_info.json", "scene_camera.json"))
    gt = {im: [_gt_entry(e, gt_path, f"image {im}, annotation {j}") for j, e in enumerate(_annotations(v, gt_path, im))]
          for im, v in _image_ids(read_json(gt_path, root), gt_path).items()}
    info = {}
    if os.path.lexists(info_path):  # a FIFO or a link out there is named, not taken for "no file"
        info = {im: [_info_entry(e, info_path, f"image {im}, annotation {j}")
                     for j, e in enumerate(_annotations(v, info_path, im))]
                for im, v in _image_ids(read_json(info_path, root), info_path).items()}
    cams = _image_ids(read_json(cam_path, root), cam_path)
    if not all(isinstance(c, dict) for c in cams.values()):
        raise DatasetFileError(f"{cam_path}: every image's entry must be an object")
    return gt, info, cams


def list_images(out: Path, missing: list[Path] | None = None) -> list[BopImage]:
    """Every annotated image with an RGB file; those without one are appended to ``missing``.
    Every table is checked as it is read: a damaged file is named before any image is drawn."""
    images = []
    out = Path(out)
    for chunk in _split_dirs(out):
        gt, info, cams = _chunk_tables(chunk, out)
        for im in sorted(gt):
            rgb = next((chunk / "rgb" / f"{im:06d}.{e}" for e in ("jpg", "png") if (chunk / "rgb" / f"{im:06d}.{e}").is_file()), None)
            if rgb is not None and not inside(rgb, out):  # a view or an export shows the dataset's own images
                raise DatasetFileError(f"{rgb}: a link out of the dataset folder {out}")
            if rgb is not None:
                images.append(BopImage(chunk, im, rgb, gt[im], info.get(im, []), cams.get(im, {})))
            elif missing is not None:
                missing.append(chunk / "rgb" / f"{im:06d}")
    return images


def _colour(obj_id: int) -> tuple[int, int, int]:
    # Deterministic, well-separated hues per object id.
    h = (obj_id * 0.618033988749895) % 1.0
    import colorsys

    r, g, b = colorsys.hsv_to_rgb(h, 0.9, 1.0)
    return int(r * 255), int(g * 255), int(b * 255)


def annotate_image(img: BopImage) -> Image.Image:
    """The image with visible-mask outlines, visible boxes and object ids drawn on it."""
    base = np.asarray(open_image(img.rgb).convert("RGB")).copy()
    for gt_id, g in enumerate(img.gt):
        m = img.mask_visib(gt_id)
        if m is None or not m.any():
            continue
        if m.shape != base.shape[:2]:
            raise DatasetFileError(f"{img.chunk / 'mask_visib'}: image {img.im_id}, annotation {gt_id}: the mask is "
                                   f"{m.shape[1]} x {m.shape[0]}, its image {base.shape[1]} x {base.shape[0]}")
        edge = m & ~(np.roll(m, 1, 0) & np.roll(m, -1, 0) & np.roll(m, 1, 1) & np.roll(m, -1, 1))
        base[edge] = _colour(g["obj_id"])
    im = Image.fromarray(base)
    draw = ImageDraw.Draw(im)
    font = ImageFont.load_default()
    for gt_id, g in enumerate(img.gt):
        info = img.gt_info[gt_id] if gt_id < len(img.gt_info) else {}
        x, y, w, h = info.get("bbox_visib", [-1, -1, -1, -1])
        if w < 0:
            continue
        c = _colour(g["obj_id"])
        draw.rectangle([x, y, x + w, y + h], outline=c, width=2)
        label = f"{g['obj_id']} ({info.get('visib_fract', 0):.2f})"
        draw.rectangle([x, max(0, y - 11), x + 6 * len(label) + 2, max(0, y - 11) + 11], fill=(0, 0, 0))
        draw.text((x + 1, max(0, y - 11)), label, fill=c, font=font)
    return im


def _crops(img: BopImage, size: int) -> list[Image.Image]:
    rgb = open_image(img.rgb).convert("RGB")
    out = []
    for gt_id, info in enumerate(img.gt_info):
        x, y, w, h = info.get("bbox_visib", [-1, -1, -1, -1])
        x0, y0 = max(x, 0), max(y, 0)  # a box past the image crops what of it is in the image
        x1, y1 = min(x + w + 1, rgb.width), min(y + h + 1, rgb.height)
        if x1 - x0 <= 3 or y1 - y0 <= 3:
            continue
        crop = rgb.crop((x0, y0, x1, y1))
        crop.thumbnail((size, size))
        tile = Image.new("RGB", (size, size), (24, 24, 24))
        tile.paste(crop, ((size - crop.width) // 2, (size - crop.height) // 2))
        ImageDraw.Draw(tile).text((2, 2), str(img.gt[gt_id]["obj_id"]), fill=(255, 255, 0))
        out.append(tile)
    return out


def contact_sheet(outs: list[Path], dest: Path, n: int = 8, seed: int = 0, width: int = 320) -> Path:
    """N sampled images (one column per output folder, same image ids) and per-object crops,
    written to ``dest`` (a PNG or JPEG file, put in place atomically: a link there is replaced)."""
    dest = output_file(dest, "--out")
    kind = SHEET_FORMATS.get(dest.suffix.lower())
    if kind is None:
        raise UnsafeOutput(f"--out {dest}: a contact sheet is an image; give a file name ending in "
                           f"{', '.join(SHEET_FORMATS)}")
    lists = [list_images(o) for o in outs]
    if not lists[0]:
        raise FileNotFoundError(f"{outs[0]}: no BOP images found (expected bop/<split>/<chunk>/scene_gt.json)")
    keyed = [{(im.chunk.name, im.im_id): im for im in lst} for lst in lists]
    common = sorted(set.intersection(*(set(k) for k in keyed)))
    if not common:
        raise DatasetFileError("the outputs share no image ids; build them from the same spec cameras")
    rng = np.random.default_rng(seed)
    pick = sorted(rng.choice(len(common), size=min(n, len(common)), replace=False))
    rows = []
    crop_size = width // 4
    for i in pick:
        tiles = []
        for k in keyed:
            im = k[common[i]]
            a = annotate_image(im)
            a = a.resize((width, round(a.height * width / a.width)))
            tiles.append(a)
        crops = _crops(keyed[0][common[i]], crop_size)[: 2 * len(outs) * 4]
        h = max(t.height for t in tiles)
        crop_rows = (len(crops) + 3) // 4
        row = Image.new("RGB", (width * len(tiles) + 4 * crop_size, max(h, crop_rows * crop_size)), (16, 16, 16))
        for j, t in enumerate(tiles):
            row.paste(t, (j * width, 0))
        for j, c in enumerate(crops):
            row.paste(c, (width * len(tiles) + (j % 4) * crop_size, (j // 4) * crop_size))
        ImageDraw.Draw(row).text((4, h - 12), f"{common[i][0]}/{common[i][1]:06d}", fill=(255, 255, 255))
        rows.append(row)
    sheet = Image.new("RGB", (max(r.width for r in rows), sum(r.height for r in rows) + 16), (0, 0, 0))
    ImageDraw.Draw(sheet).text((4, 2), "  |  ".join(str(o) for o in outs), fill=(255, 255, 255))
    y = 16
    for r in rows:
        sheet.paste(r, (0, y))
        y += r.height
    atomic_write_via(dest, lambda tmp: sheet.save(tmp, format=kind))
    return dest


SHEET_FORMATS = {".png": "PNG", ".jpg": "JPEG", ".jpeg": "JPEG"}


def _save_figure(fig, path: Path) -> None:
    """A matplotlib figure as a PNG put in place atomically (a link at ``path`` is replaced)."""
    atomic_write_via(path, lambda tmp: fig.savefig(tmp, dpi=80, format="png"))


def dataset_stats(out: Path, dest: Path) -> dict:
    """Plots (PNG) and a table of what a build produced; returns the table as a dict."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out, dest = Path(out), output_folder(dest, "--out")
    dest.mkdir(parents=True, exist_ok=True)
    refuse_links_out(dest)
    images = read_parquet(out / "parquet" / "images.parquet", ("scene", "stage", "R_w2c"))
    inst = read_parquet(out / "parquet" / "instances.parquet", ("obj_id", "t_m2c_mm", "px_count_all", "visib_fract"))
    if not len(images) or not len(inst):
        raise DatasetFileError(f"{out / 'parquet'}: no {'images' if not len(images) else 'instances'} to plot")
    summary = _summary(out / ".specsynth" / "summary.json")

    table: dict = {
        "images": int(len(images)),
        "instances": int(len(inst)),
        "images_per_scene_stage": {f"{s}/{t}": int(n) for (s, t), n in images.groupby(["scene", "stage"]).size().items()},
        "instances_per_object": {int(k): int(v) for k, v in inst.groupby("obj_id").size().items()},
        "cameras_rejected": summary.get("cameras_rejected"),
        "views_dropped": summary.get("views_dropped"),
        "objects_removed_by_physics": summary.get("objects_removed"),
        "objects_redropped": summary.get("objects_redropped"),
        "seconds_per_stage": {k: round(float(v["seconds"]), 2) for k, v in _object(summary.get("stages")).items()
                              if isinstance(v, dict) and isinstance(v.get("seconds"), (int, float))},
    }

    # Camera distance / elevation from the written poses (camera centre relative to the world Z axis).
    R = _stacked(images["R_w2c"], 9, out / "parquet" / "images.parquet", "R_w2c").reshape(-1, 3, 3)
    focus_dist = np.linalg.norm(_stacked(inst["t_m2c_mm"], 3, out / "parquet" / "instances.parquet", "t_m2c_mm"),
                                axis=1) / 1000.0
    optical_axis = R[:, 2, :]  # camera z axis in world coordinates
    elevation = np.degrees(np.arcsin(np.clip(-optical_axis[:, 2], -1, 1)))
    obj_px = inst["px_count_all"].to_numpy()

    fig, axes = plt.subplots(2, 3, figsize=(15, 8))
    axes[0, 0].hist(inst["visib_fract"], bins=20, range=(0, 1), color="tab:blue")
    axes[0, 0].set_title("visib_fract per instance")
    axes[0, 1].hist(np.sqrt(np.maximum(obj_px, 1)), bins=30, color="tab:orange")
    axes[0, 1].set_title("object size: sqrt(px_count_all) [px]")
    axes[0, 2].hist(focus_dist, bins=30, color="tab:green")
    axes[0, 2].set_title("object distance from camera [m]")
    axes[1, 0].hist(elevation, bins=18, range=(-90, 90), color="tab:red")
    axes[1, 0].set_title("camera elevation (optical axis) [deg]")
    objs = table["instances_per_object"]
    axes[1, 1].bar([str(k) for k in objs], list(objs.values()), color="tab:purple")
    axes[1, 1].set_title("instances per object id")
    sc = table["images_per_scene_stage"]
    axes[1, 2].barh(list(sc), list(sc.values()), color="tab:gray")
    axes[1, 2].set_title("images per scene/stage")
    fig.suptitle(f"{out}: {table['images']} images, {table['instances']} instances, "
                 f"{table['cameras_rejected']} cameras rejected, {table['objects_removed_by_physics']} objects removed")
    fig.tight_layout()
    _save_figure(fig, dest / "stats.png")
    plt.close(fig)
    table.update(error_stats(out, dest))
    atomic_write_bytes(dest / "stats.json", (json.dumps(table, indent=2, sort_keys=True) + "\n").encode())
    return table


def _summary(path: Path) -> dict:
    """A build's summary.json, or {} without one; a damaged one is named."""
    if not os.path.lexists(path):
        return {}
    summary = read_json(path, path.parent.parent)
    if not isinstance(summary, dict):
        raise DatasetFileError(f"{path}: expected an object")
    return summary


def _object(v) -> dict:
    return v if isinstance(v, dict) else {}


def _stacked(column, width: int, path: Path, name: str) -> np.ndarray:
    """A column of fixed-length number lists as an (n, width) float array, or an error naming it."""
    try:
        a = np.asarray(np.stack([np.asarray(v, np.float64).ravel() for v in column]), np.float64)
    except (ValueError, TypeError):
        a = None
    if a is None or a.ndim != 2 or a.shape[1] != width:
        raise DatasetFileError(f"{path}: column {name!r}: expected lists of {width} numbers")
    return a


def error_stats(out: Path, dest: Path) -> dict:
    """Images rendered to an error target (``quality.control: error``): samples per image and
    estimated error against target, plotted into ``quality.png``; {} for any other build."""
    import pandas as pd

    # Every part's: a stereo build's right eyes are images too (timings_right.parquet), as
    # summary.json counts them.
    parts = [read_parquet(p) for p in sorted((out / "parquet").glob("timings*.parquet"))]
    timings = pd.concat(parts, ignore_index=True) if parts else None
    if timings is None or "error_target" not in timings or timings["error_target"].isna().all():
        return {}
    import matplotlib.pyplot as plt

    t = timings.dropna(subset=["error_target"])
    ratio = error_ratio(t["error_estimate"], t["error_target"])
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.5))
    a.hist(t["samples"], bins=30, color="tab:blue")
    a.set_title("samples per pixel per image")
    b.loglog(t["error_target"], t["error_estimate"], ".", color="tab:orange")
    lo, hi = float(t["error_target"].min()), float(t["error_target"].max())
    b.plot([lo, hi], [lo, hi], "k-", lw=0.8, label="at the target")
    b.plot([lo, hi], [1.1 * lo, 1.1 * hi], "k:", lw=0.8, label="10 % above")
    b.set_xlabel("target: the paper preset's estimated relMSE")
    b.set_ylabel("the image's estimated relMSE")
    b.legend()
    fig.tight_layout()
    _save_figure(fig, dest / "quality.png")
    plt.close(fig)
    return {"error_control": {"images": int(len(t)), "samples_median": float(np.median(t["samples"])),
                              "error_ratio_median": round(float(np.median(ratio)), 4),
                              "within_10_percent": round(float(np.mean(ratio <= 1.1)), 4)}}
