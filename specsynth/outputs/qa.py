"""Visual QA of a built dataset: contact sheets (`specsynth view`) and statistics (`specsynth stats`).

Reads only the BOP output (and the build summary), so it works on any BOP-format dataset folder.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from ..atomic import atomic_write_bytes, atomic_write_via
from ..files import UnsafeOutput, output_file, output_folder, refuse_links_out
from ..model.error import error_ratio


class DatasetFileError(ValueError):
    """A file of a built dataset that cannot be read; the message names it (never its contents)."""


def read_json(path: Path):
    try:
        return json.loads(Path(path).read_bytes())
    except (OSError, ValueError, RecursionError) as e:  # RecursionError: nested too deep to decode
        raise DatasetFileError(f"{path}: unreadable JSON ({type(e).__name__})") from None


def open_image(path: Path):
    """The image loaded (not lazily), or an error naming the file."""
    try:
        im = Image.open(path)
        im.load()
        return im
    except (OSError, ValueError, SyntaxError) as e:
        raise DatasetFileError(f"{path}: unreadable image ({type(e).__name__})") from None


def read_parquet(path: Path):
    import pyarrow.parquet as pq

    try:
        return pq.read_table(path).to_pandas()
    except (OSError, ValueError) as e:
        raise DatasetFileError(f"{path}: unreadable Parquet ({type(e).__name__})") from None


@dataclass(frozen=True)
class BopImage:
    chunk: Path
    im_id: int
    rgb: Path
    gt: list[dict]
    gt_info: list[dict]
    camera: dict

    def mask_visib(self, gt_id: int) -> np.ndarray | None:
        p = self.chunk / "mask_visib" / f"{self.im_id:06d}_{gt_id:06d}.png"
        return np.asarray(open_image(p)) > 127 if p.is_file() else None


def _split_dirs(out: Path) -> list[Path]:
    bop = out / "bop" if (out / "bop").is_dir() else out
    chunks = [p.parent for p in bop.glob("*/*/scene_gt.json")]
    return sorted(chunks)


def list_images(out: Path, missing: list[Path] | None = None) -> list[BopImage]:
    """Every annotated image with an RGB file; those without one are appended to ``missing``."""
    images = []
    for chunk in _split_dirs(Path(out)):
        gt = read_json(chunk / "scene_gt.json")
        info = read_json(chunk / "scene_gt_info.json") if (chunk / "scene_gt_info.json").is_file() else {}
        cams = read_json(chunk / "scene_camera.json")
        for k in sorted(gt, key=int):
            im = int(k)
            rgb = next((chunk / "rgb" / f"{im:06d}.{e}" for e in ("jpg", "png") if (chunk / "rgb" / f"{im:06d}.{e}").is_file()), None)
            if rgb is not None:
                images.append(BopImage(chunk, im, rgb, gt[k], info.get(k, []), cams.get(k, {})))
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
        if w <= 2 or h <= 2:
            continue
        crop = rgb.crop((x, y, x + w + 1, y + h + 1))
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
        raise ValueError("the outputs share no image ids; build them from the same spec cameras")
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
    images = read_parquet(out / "parquet" / "images.parquet")
    inst = read_parquet(out / "parquet" / "instances.parquet")
    summary_path = out / ".specsynth" / "summary.json"
    summary = read_json(summary_path) if summary_path.is_file() else {}

    table: dict = {
        "images": int(len(images)),
        "instances": int(len(inst)),
        "images_per_scene_stage": {f"{s}/{t}": int(n) for (s, t), n in images.groupby(["scene", "stage"]).size().items()},
        "instances_per_object": {int(k): int(v) for k, v in inst.groupby("obj_id").size().items()},
        "cameras_rejected": summary.get("cameras_rejected"),
        "views_dropped": summary.get("views_dropped"),
        "objects_removed_by_physics": summary.get("objects_removed"),
        "objects_redropped": summary.get("objects_redropped"),
        "seconds_per_stage": {k: round(v["seconds"], 2) for k, v in summary.get("stages", {}).items()},
    }

    # Camera distance / elevation from the written poses (camera centre relative to the world Z axis).
    R = np.stack(images["R_w2c"].to_numpy()).reshape(-1, 3, 3)
    focus_dist = np.linalg.norm(np.stack(inst["t_m2c_mm"].to_numpy()).reshape(-1, 3), axis=1) / 1000.0
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
