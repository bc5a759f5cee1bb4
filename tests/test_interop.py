"""Interop with detector tooling, on a real build of the demo baseline: COCO boxes and metadata as
pycocotools and COCO loaders expect, built-in models centred as BOP expects (poses still agree
with the masks), the YOLO export read back, and the Parquet tables loaded with pandas and
Hugging Face ``datasets``."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image
from pycocotools import mask as mask_utils

from specsynth.assets.meshio import read_mesh
from specsynth.cli import main
from specsynth.outputs.coco import coco_box
from specsynth.outputs.yolo import ExportError, export_yolo, held_out, yolo_line

ROOT = Path(__file__).resolve().parents[1]
CHUNK = Path("bop/train_pbr/000000")


@pytest.fixture(scope="module")
def demo_bl(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("interop") / "demo_bl"
    rc = main(["build", str(ROOT / "specs/demo_bl.yaml"), "--out", str(out), "--jobs", "1", "--quiet",
               "--set", "arrangements.count=3", "--set", "metadata.date_created=2026-11-23",
               "--set", "metadata.version=2.1", "--set", "metadata.license={name: CC-BY-4.0, url: 'https://x.org/l'}"])
    assert rc == 0
    return out


def _coco(out: Path) -> dict:
    return json.loads((out / "coco" / "train_pbr.json").read_text())


def _chunk_json(out: Path, name: str) -> dict:
    return json.loads((out / CHUNK / name).read_text())


# --------------------------------------------------------------------------- 1. COCO boxes


def test_coco_boxes_are_pycocotools_boxes_of_their_own_masks(demo_bl):
    for doc in (_coco(demo_bl), _chunk_json(demo_bl, "scene_gt_coco.json")):
        assert doc["annotations"]
        for ann in doc["annotations"]:
            rle = {"counts": ann["segmentation"]["counts"].encode(), "size": ann["segmentation"]["size"]}
            assert ann["bbox"] == [int(v) for v in mask_utils.toBbox(rle)]
            assert ann["area"] == int(mask_utils.area(rle))


def test_bop_keeps_bops_box_convention(demo_bl):
    info = _chunk_json(demo_bl, "scene_gt_info.json")
    for im_id, gts in info.items():
        for gt_id, g in enumerate(gts):
            m = np.asarray(Image.open(demo_bl / CHUNK / "mask_visib" / f"{int(im_id):06d}_{gt_id:06d}.png")) > 0
            if not m.any():
                assert g["bbox_visib"] == [-1, -1, -1, -1]
                continue
            ys, xs = np.nonzero(m)
            assert g["bbox_visib"] == [xs.min(), ys.min(), xs.max() - xs.min(), ys.max() - ys.min()]


def test_coco_box_of_bop_box():
    assert coco_box([3, 4, 0, 0]) == [3, 4, 1, 1]  # one pixel
    assert coco_box([3, 4, 10, 5]) == [3, 4, 11, 6]
    assert coco_box([-1, -1, -1, -1]) == [-1, -1, -1, -1]


# --------------------------------------------------------------------------- 2. COCO metadata


def test_coco_metadata_comes_from_the_spec(demo_bl):
    for doc in (_coco(demo_bl), _chunk_json(demo_bl, "scene_gt_coco.json")):
        info = doc["info"]
        assert info["year"] == 2026 and info["version"] == "2.1" and info["date_created"] == "2026-11-23"
        assert {"description", "url", "contributor"} <= set(info)
        assert doc["licenses"] == [{"id": 1, "name": "CC-BY-4.0", "url": "https://x.org/l"}]
        assert doc["images"]
        for im in doc["images"]:
            assert im["license"] == 1 and im["date_captured"] == "2026-11-23 00:00:00"


def test_coco_metadata_has_fixed_defaults(tmp_path):
    from specsynth.outputs.coco import date_captured, info_and_licenses
    from specsynth.spec.models import Metadata

    doc = info_and_licenses(Metadata(), "d")
    assert doc["info"]["date_created"] == "1970-01-01" and doc["info"]["year"] == 1970
    assert doc["licenses"][0]["name"] == "unspecified"
    assert date_captured(Metadata()) == "1970-01-01 00:00:00"


# --------------------------------------------------------------------------- 3. model origins


def test_builtin_models_are_centred_and_poses_agree_with_masks(demo_bl):
    models = demo_bl / "bop" / "models"
    info = json.loads((models / "models_info.json").read_text())
    assert len(info) == 6
    for obj_id, m in info.items():
        for ax in "xyz":  # origin at the centre of the 3D bounding box
            assert abs(m[f"min_{ax}"] + m[f"size_{ax}"] / 2) < 1e-3, (obj_id, ax)

    gt, cams = _chunk_json(demo_bl, "scene_gt.json"), _chunk_json(demo_bl, "scene_camera.json")
    checked = 0
    for im_id, gts in gt.items():
        K = np.asarray(cams[im_id]["cam_K"]).reshape(3, 3)
        for gt_id, g in enumerate(gts):
            pts = read_mesh(models / f"obj_{g['obj_id']:06d}.ply").vertices.astype(np.float64)  # mm
            cam = pts @ np.asarray(g["cam_R_m2c"]).reshape(3, 3).T + np.asarray(g["cam_t_m2c"])
            uv = cam[:, :2] / cam[:, 2:] * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
            px = np.rint(uv).astype(int)  # OpenCV: pixel centres at integers
            mask = np.asarray(Image.open(demo_bl / CHUNK / "mask" / f"{int(im_id):06d}_{gt_id:06d}.png")) > 0
            inside = (px[:, 0] >= 0) & (px[:, 0] < mask.shape[1]) & (px[:, 1] >= 0) & (px[:, 1] < mask.shape[0])
            if inside.sum() < 20:
                continue
            grown = _dilate(mask, 1)
            assert grown[px[inside, 1], px[inside, 0]].mean() > 0.99, (im_id, gt_id)
            # The model's origin (its box centre) projects inside the silhouette's box in the mask.
            centre = _project(np.asarray(g["cam_t_m2c"]), K)
            if 0 <= centre[0] < mask.shape[1] and 0 <= centre[1] < mask.shape[0]:
                ys, xs = np.nonzero(mask)
                assert xs.min() - 1 <= centre[0] <= xs.max() + 1 and ys.min() - 1 <= centre[1] <= ys.max() + 1, (im_id, gt_id, centre)
                checked += 1
    assert checked > 10


def _project(p: np.ndarray, K: np.ndarray) -> np.ndarray:
    return p[:2] / p[2] * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]


def _dilate(m: np.ndarray, r: int) -> np.ndarray:
    out = m.copy()
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            out |= np.roll(np.roll(m, dy, 0), dx, 1)
    return out


def test_user_bop_models_keep_their_origin(tmp_path):
    """A user's BOP model whose origin is at a corner is written as given, not re-centred."""
    from specsynth.assets.resolve import resolve_objects
    from specsynth.outputs.bop import write_models
    from specsynth.spec.models import Objects

    src = tmp_path / "models"
    src.mkdir()
    corners = [(x, y, z) for x in (0, 40) for y in (0, 30) for z in (0, 20)]  # mm, origin at a corner
    faces = [(0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5), (0, 4, 5), (0, 5, 1),
             (2, 3, 7), (2, 7, 6), (0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3)]
    head = ["ply", "format ascii 1.0", "element vertex 8", "property float x", "property float y", "property float z",
            "element face 12", "property list uchar int vertex_indices", "end_header"]
    body = [f"{x} {y} {z}" for x, y, z in corners] + [f"3 {a} {b} {c}" for a, b, c in faces]
    (src / "obj_000001.ply").write_text("\n".join(head + body) + "\n")
    given = {"1": {"diameter": 53.85, "min_x": 0, "min_y": 0, "min_z": 0, "size_x": 40, "size_y": 30, "size_z": 20}}
    (src / "models_info.json").write_text(json.dumps(given))
    assets = resolve_objects(Objects(path=str(src)), tmp_path, cache=tmp_path / "cache")
    write_models(tmp_path / "out", assets)
    written = json.loads((tmp_path / "out" / "models_info.json").read_text())
    for f, v in given["1"].items():
        if f != "diameter":
            assert written["1"][f] == pytest.approx(v, abs=1e-3), f


# --------------------------------------------------------------------------- 4. YOLO


def test_yolo_export_reads_back_as_the_coco_boxes(demo_bl, tmp_path):
    dest = tmp_path / "yolo"
    rc = main(["export", "yolo", str(demo_bl), str(dest), "--min-visib", "0.1"])
    assert rc == 0
    data = yaml.safe_load((dest / "data.yaml").read_text())
    assert data["names"] == {0: "duck", 1: "mug", 2: "teddy", 3: "lego", 4: "jenga", 5: "torus"}
    assert data["nc"] == 6 and data["train"] == data["val"] == "images/train_pbr"
    coco = _coco(demo_bl)
    by_image: dict[int, list] = {}
    for a in coco["annotations"]:
        by_image.setdefault(a["image_id"], []).append(a)
    index_of = {im["file_name"].rsplit("/", 1)[-1]: im for im in coco["images"]}
    labels = sorted((dest / "labels" / "train_pbr").glob("*.txt"))
    assert len(labels) == len(coco["images"]) == len(list((dest / "images" / "train_pbr").iterdir()))
    total = 0
    for lab in labels:
        im = index_of[lab.stem.rsplit("_", 1)[-1] + ".jpg"]
        image = dest / "images" / "train_pbr" / (lab.stem + ".jpg")
        assert image.read_bytes() == (demo_bl / "coco" / im["file_name"]).read_bytes()
        assert not image.samefile(demo_bl / "coco" / im["file_name"])  # a copy, not a link
        rows = [list(map(float, line.split())) for line in lab.read_text().splitlines()]
        want = [a for a in by_image.get(im["id"], []) if not a["ignore"]]
        assert len(rows) == len(want)
        for row, a in zip(rows, want):
            assert int(row[0]) == a["category_id"] - 1
            assert all(0.0 <= v <= 1.0 for v in row[1:])
            x, y, w, h = a["bbox"]  # back from normalised centre/size to the COCO box of the mask
            back = [(row[1] - row[3] / 2) * im["width"], (row[2] - row[4] / 2) * im["height"],
                    row[3] * im["width"], row[4] * im["height"]]
            assert np.allclose(back, [x, y, w, h], atol=0.01)
            total += 1
    assert total > 20


def test_yolo_visibility_threshold_and_held_out_arrangements(demo_bl, tmp_path):
    everything = export_yolo(demo_bl, tmp_path / "all", min_visib=0.0)
    strict = export_yolo(demo_bl, tmp_path / "strict", min_visib=0.9)
    assert strict.boxes + strict.skipped_low_visibility == everything.boxes
    assert strict.skipped_low_visibility > 0

    s = export_yolo(demo_bl, tmp_path / "split", val_fraction=0.34)
    assert s.images == {"train_pbr": 8, "val": 4}  # one of three arrangements, 4 cameras each
    data = yaml.safe_load((tmp_path / "split" / "data.yaml").read_text())
    assert data["val"] == "images/val" and data["train"] == "images/train_pbr"
    import pyarrow.parquet as pq

    arr = {Path(p).stem: a for p, a in zip(*pq.read_table(demo_bl / "parquet" / "images.parquet",
                                                          columns=["rgb", "arr"]).to_pydict().values())}
    val_arrs = {arr[p.stem.rsplit("_", 1)[-1]] for p in (tmp_path / "split" / "images" / "val").iterdir()}
    train_arrs = {arr[p.stem.rsplit("_", 1)[-1]] for p in (tmp_path / "split" / "images" / "train_pbr").iterdir()}
    assert len(val_arrs) == 1 and not val_arrs & train_arrs

    again = export_yolo(demo_bl, tmp_path / "split", val_fraction=0.0)  # re-export into the same folder
    assert again.images == {"train_pbr": 12}
    assert not (tmp_path / "split" / "images" / "val").exists() or not any((tmp_path / "split" / "images" / "val").iterdir())


def test_yolo_export_refuses_foreign_or_inner_destinations(demo_bl, tmp_path):
    foreign = tmp_path / "mine"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("keep me")
    with pytest.raises(ExportError, match="not a YOLO export"):
        export_yolo(demo_bl, foreign)
    assert (foreign / "notes.txt").read_text() == "keep me"
    with pytest.raises(ExportError, match="inside the dataset"):
        export_yolo(demo_bl, demo_bl / "yolo")
    with pytest.raises(ExportError, match="no such split"):
        export_yolo(demo_bl, tmp_path / "v", val_split="val_pbr")
    assert main(["export", "yolo", str(tmp_path / "nothing"), str(tmp_path / "x")]) == 2


def test_yolo_line_matches_ultralytics_normalisation():
    # A box over the whole 640x480 image: pixels 0..639 -> centre 0.5, width 1.
    assert yolo_line(2, [0, 0, 639, 479], 640, 480) == "2 0.500000 0.500000 1.000000 1.000000"
    assert yolo_line(0, [10, 20, 0, 0], 100, 100) == "0 0.105000 0.205000 0.010000 0.010000"


def test_held_out_is_deterministic_and_exact():
    keys = [f"k{i}" for i in range(100)]
    assert held_out(keys, 0.1) == held_out(list(reversed(keys)), 0.1)
    assert len(held_out(keys, 0.1)) == 10 and len(held_out(keys[:3], 0.01)) == 1 and held_out(keys, 0) == set()


# --------------------------------------------------------------------------- 5. pandas and Hugging Face datasets


def test_parquet_tables_join_in_pyarrow_pandas_and_datasets(demo_bl):
    import pandas as pd
    import pyarrow.parquet as pq

    pqdir = demo_bl / "parquet"
    images = pq.read_table(pqdir / "images.parquet")
    instances = pq.read_table(pqdir / "instances.parquet")
    # Arrow's join takes scalar columns only (not the pose lists): select before joining.
    scalar = ["index", "gt_id", "obj_id", "visib_fract", "px_count_visib"]
    joined = instances.select(scalar).join(images.select(["index", "rgb", "scene", "width", "height"]), keys="index")
    assert joined.num_rows == instances.num_rows
    assert all((demo_bl / p).is_file() for p in joined.column("rgb").to_pylist())

    df = pd.read_parquet(pqdir / "instances.parquet").merge(pd.read_parquet(pqdir / "images.parquet"), on="index",
                                                           suffixes=("", "_image"))
    assert len(df) == instances.num_rows and (df["n_instances"] >= 1).all()
    assert df.groupby("index").size().to_dict() == dict(zip(*np.unique(df["index"], return_counts=True)))

    os.environ.setdefault("HF_HUB_OFFLINE", "1")  # local files only; read when datasets is imported
    os.environ.setdefault("HF_DATASETS_OFFLINE", "1")
    datasets = pytest.importorskip("datasets")
    # One table per load_dataset call: the two tables have different columns.
    ds = {name: datasets.load_dataset("parquet", data_files=str(pqdir / f"{name}.parquet"), split="train",
                                      cache_dir=str(demo_bl.parent / "hf-cache"))
          for name in ("images", "instances")}
    assert ds["images"].num_rows == images.num_rows and ds["instances"].num_rows == instances.num_rows
    first = ds["instances"][0]
    assert first["mask_visib_rle"]["size"] == [480, 640] and len(first["bbox_visib"]) == 4


# --------------------------------------------------------------------------- file modes


def test_output_files_follow_the_umask(demo_bl):
    """Datasets are shared: files get 0666 minus the umask (0644 by default), not mkstemp's 0600."""
    old = os.umask(0)
    os.umask(old)
    want = 0o666 & ~old
    files = [p for sub in ("bop", "coco", "parquet") for p in (demo_bl / sub).rglob("*") if p.is_file()]
    assert len(files) > 50
    modes = {oct(p.stat().st_mode & 0o777) for p in files}
    assert modes == {oct(want)}, modes
