"""Writers: BOP layout read back with toolkit-equivalent loaders, Parquet, COCO, determinism, atomicity.

The BOP toolkit is not installable here, so ``_load_json``/``_load_ply`` below re-implement the
behaviour of ``bop_toolkit_lib.inout`` that matters (int keys, depth * depth_scale, the PLY header
rules and the binary types its ``struct`` table knows).
"""

from __future__ import annotations

import json
import os
import struct
from pathlib import Path

import imageio.v2 as iio
import numpy as np
import pytest
from PIL import Image

from specsynth.assets.meshio import MeshData, write_mesh
from specsynth.assets.resolve import ObjectAsset
from specsynth.model.ir import MaterialIR
from specsynth.model.records import ImageRecord, InstanceGT
from specsynth.outputs import dataset as dataset_mod
from specsynth.outputs import write_outputs
from specsynth.outputs.images import (
    DepthOverflowError,
    encode_depth,
    write_exr,
    write_jpg,
    write_mask,
    write_png,
)
from specsynth.spec.models import DatasetSpec

W, H = 64, 48
K = [[80.0, 0.0, 31.5], [0.0, 80.0, 23.5], [0.0, 0.0, 1.0]]


# --------------------------------------------------------------------------- fixtures


def _rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q @ np.diag(np.sign(np.diag(r)))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def _make_models(root: Path) -> list[ObjectAsset]:
    models = []
    for obj_id, with_uv in ((1, True), (3, False)):
        v = np.array([[0, 0, 0], [0.05, 0, 0], [0, 0.04, 0], [0, 0, 0.03]], dtype=np.float32) + obj_id * 0.001
        f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]], dtype=np.int32)
        n = v - v.mean(0)
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        mesh = MeshData(
            vertices=v,
            faces=f,
            normals=n.astype(np.float32),
            uv=np.array([[0, 0], [1, 0], [0, 1], [1, 1]], dtype=np.float32) if with_uv else None,
            colors=np.full((4, 4), 200, dtype=np.uint8),
        )
        path = root / f"mesh_{obj_id}.ply"
        write_mesh(path, mesh)
        tex = None
        if with_uv:
            tex = str(root / f"tex_{obj_id}.png")
            write_png(tex, np.full((4, 4, 3), 128, dtype=np.uint8))
        d = v.astype(np.float64)
        diam = max(np.linalg.norm(a - b) for a in d for b in d)
        models.append(
            ObjectAsset(
                obj_id=obj_id,
                name=f"obj_{obj_id:06d}",
                mesh_path=str(path),
                mesh_key=f"k{obj_id}",
                material=MaterialIR(texture=tex),
                diameter=float(diam),
                bbox_min=tuple(d.min(0)),
                extents=tuple(d.max(0) - d.min(0)),
                source=str(path),
            )
        )
    return models


def _make_image(store_root: Path, index: int, rng: np.random.Generator, depth_scale: float = 0.1):
    store = store_root / f"{index:04d}"
    store.mkdir(parents=True)
    depth_m = rng.uniform(0.3, 2.5, size=(H, W))
    depth_m[:4] = 0.0  # background rows
    depth, scale = encode_depth(depth_m, depth_scale)
    write_png(store / "depth.png", depth)
    write_jpg(store / "rgb.jpg", rng.integers(0, 256, size=(H, W, 3), dtype=np.uint8), 90)
    instances, masks, visib = [], [], []
    for gt in range(int(rng.integers(1, 4))):
        x0, y0 = int(rng.integers(0, W - 12)), int(rng.integers(0, H - 12))
        full = np.zeros((H, W), bool)
        full[y0 : y0 + 10, x0 : x0 + 12] = True
        vis = full.copy()
        vis[y0 : y0 + 3] = False
        if gt == 2:
            vis[:] = False  # fully occluded instance: no COCO annotation
        write_mask(store / f"mask_{gt:06d}.png", full)
        write_mask(store / f"mask_visib_{gt:06d}.png", vis)
        masks.append(f"mask_{gt:06d}.png")
        visib.append(f"mask_visib_{gt:06d}.png")
        ys, xs = np.nonzero(vis)
        bbox_v = [int(xs.min()), int(ys.min()), int(np.ptp(xs)), int(np.ptp(ys))] if len(xs) else [-1] * 4  # BOP: w = xmax - xmin
        instances.append(
            InstanceGT(
                obj_id=(1, 3)[gt % 2],
                inst=gt,
                R_m2c=_rotation(rng).tolist(),
                t_m2c=rng.uniform(-0.2, 0.8, size=3).tolist(),
                bbox_obj=[x0, y0, 12, 10],
                bbox_visib=bbox_v,
                px_count_all=int(full.sum()),
                px_count_valid=int(full.sum()),
                px_count_visib=int(vis.sum()),
                visib_fract=float(vis.sum() / full.sum()),
            )
        )
    rec = ImageRecord(
        arr=index // 2, cam=index % 2, index=index, scene="room", stage="table", backend="photo",
        backend_version="1.0", quality="low", seed=1000 + index, width=W, height=H, K=K,
        R_w2c=_rotation(rng).tolist(), t_w2c=rng.uniform(-1, 1, size=3).tolist(), depth_scale=scale,
        instances=instances, files={"rgb": "rgb.jpg", "depth": "depth.png", "mask": masks, "mask_visib": visib},
        render_seconds=float(rng.uniform(0.1, 2.0)),
    )
    return (rec, store), depth_m


def _spec(**outputs) -> DatasetSpec:
    return DatasetSpec(
        name="unit",
        objects={"builtin": ["duck"]},
        scenes=[{"name": "room"}],
        backend={"name": "photo"},
        intrinsics={"width": W, "height": H, "fx": 80.0, "fy": 80.0, "cx": 31.5, "cy": 23.5},
        outputs={"chunk_size": 3, **outputs},
    )


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    root = tmp_path_factory.mktemp("src")
    rng = np.random.default_rng(7)
    models = _make_models(root)
    indices = [0, 1, 2, 4, 5, 7]  # a gap (dropped view) and three chunks of size 3
    made = [_make_image(root / "store", i, rng) for i in indices]
    return models, [m[0] for m in made], {m[0][0].index: m[1] for m in made}


@pytest.fixture(scope="module")
def built(dataset, tmp_path_factory):
    models, images, _ = dataset
    out = tmp_path_factory.mktemp("out")
    counts = write_outputs(out, _spec(), images, models)
    return out, counts


# --------------------------------------------------------------------------- toolkit-equivalent loaders


def _load_json(path: Path, keys_to_int: bool = False):
    def hook(d):
        return {int(k) if k.lstrip("-").isdigit() else k: v for k, v in d.items()}

    with open(path) as f:
        return json.load(f, object_hook=hook) if keys_to_int else json.load(f)


_PLY_FORMATS = {"float": ("f", 4), "double": ("d", 8), "int": ("i", 4), "uchar": ("B", 1)}


def _load_ply(path: Path) -> dict:
    """inout.load_ply's header rules; binary records unpacked with the same struct table."""
    f = open(path, "rb")
    n_pts = n_faces = 0
    pt_props, face_props = [], []
    section, texture_file, binary = None, None, False
    while True:
        line = f.readline().decode("utf8").rstrip("\n").rstrip("\r")
        if line.startswith("comment TextureFile"):
            texture_file = line.split()[-1]
        elif line.startswith("element vertex"):
            n_pts, section = int(line.split()[-1]), "vertex"
        elif line.startswith("element face"):
            n_faces, section = int(line.split()[-1]), "face"
        elif line.startswith("element"):
            section = None
        elif line.startswith("property list") and section == "face":
            e = line.split()
            assert e[-1] in ("vertex_indices", "vertex_index")
            face_props = [e[2]] + [e[3]] * 3
        elif line.startswith("property") and section == "vertex":
            pt_props.append((line.split()[-1], line.split()[-2]))
        elif line.startswith("format"):
            binary = "binary" in line
        elif line.startswith("end_header"):
            break
    assert binary
    names = [p[0] for p in pt_props]
    model = {"pts": np.zeros((n_pts, 3)), "faces": np.zeros((n_faces, 3))}
    if texture_file:
        model["texture_file"] = texture_file
    for pid in range(n_pts):
        vals = {}
        for name, typ in pt_props:
            fmt, size = _PLY_FORMATS[typ]  # KeyError here = a type the toolkit cannot read
            vals[name] = struct.unpack(fmt, f.read(size))[0]
        model["pts"][pid] = [vals["x"], vals["y"], vals["z"]]
        if {"nx", "ny", "nz"} <= set(names):
            model.setdefault("normals", np.zeros((n_pts, 3)))[pid] = [vals["nx"], vals["ny"], vals["nz"]]
        if {"red", "green", "blue"} <= set(names):
            model.setdefault("colors", np.zeros((n_pts, 3)))[pid] = [vals["red"], vals["green"], vals["blue"]]
        if {"texture_u", "texture_v"} <= set(names):
            model.setdefault("texture_uv", np.zeros((n_pts, 2)))[pid] = [vals["texture_u"], vals["texture_v"]]
    for fid in range(n_faces):
        vals = [struct.unpack(_PLY_FORMATS[t][0], f.read(_PLY_FORMATS[t][1]))[0] for t in face_props]
        assert vals[0] == 3
        model["faces"][fid] = vals[1:]
    assert f.read() == b""
    f.close()
    return model


def _all_files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _is_rotation(R: np.ndarray) -> bool:
    R = np.asarray(R, dtype=np.float64).reshape(3, 3)
    return np.abs(R @ R.T - np.eye(3)).max() < 1e-6 and abs(np.linalg.det(R) - 1) < 1e-6


# --------------------------------------------------------------------------- per-view encoders


def test_depth_round_trip_within_half_scale(tmp_path):
    rng = np.random.default_rng(0)
    d = rng.uniform(0.05, 6.0, size=(30, 40))
    d[0, :5] = 0.0
    d[1, :5] = np.inf
    for scale in (0.1, 1.0):
        q, used = encode_depth(d, scale)
        assert used == scale and q.dtype == np.uint16
        write_png(tmp_path / "d.png", q)
        back = iio.imread(tmp_path / "d.png").astype(np.float32) * used  # inout.load_depth * scale
        assert (back[0, :5] == 0).all() and (back[1, :5] == 0).all()
        valid = np.isfinite(d) & (d > 0)
        assert np.abs(back[valid] - d[valid] * 1000).max() <= used / 2 + 1e-3


def test_depth_overflow_detected_and_auto_fits():
    d = np.full((4, 4), 7.0)  # 7 m = 70000 units at 0.1
    with pytest.raises(DepthOverflowError, match=r"depth_scale 0\.1.*use depth_scale: 0\.25"):
        encode_depth(d, 0.1)
    q, used = encode_depth(d, "auto")
    assert used == 0.25 and q.max() == 28000
    assert encode_depth(np.full((2, 2), 1.0), "auto")[1] == 0.1
    with pytest.raises(DepthOverflowError):
        encode_depth(np.full((2, 2), 700.0), "auto")
    with pytest.raises(ValueError, match="NaN"):
        encode_depth(np.full((2, 2), np.nan), 0.1)


def test_encoders_deterministic_and_readable(tmp_path):
    rng = np.random.default_rng(1)
    rgb = rng.integers(0, 256, size=(16, 20, 3), dtype=np.uint8)
    mask = rng.random((16, 20)) > 0.5
    lin = rng.random((16, 20, 3)).astype(np.float32)
    for d in ("a", "b"):
        write_png(tmp_path / d / "x.png", rgb)
        write_jpg(tmp_path / d / "x.jpg", rgb, 95)
        write_mask(tmp_path / d / "m.png", mask)
        write_exr(tmp_path / d / "x.exr", lin)
    assert _all_files(tmp_path / "a") == _all_files(tmp_path / "b")
    assert (np.asarray(Image.open(tmp_path / "a/x.png")) == rgb).all()
    m = np.asarray(Image.open(tmp_path / "a/m.png"))
    assert m.dtype == np.uint8 and set(np.unique(m)) <= {0, 255} and ((m > 0) == mask).all()
    import OpenEXR

    with OpenEXR.File(str(tmp_path / "a/x.exr")) as f:
        assert np.array_equal(f.channels()["RGB"].pixels, lin)
    assert not [p for p in tmp_path.rglob("*") if p.name.endswith(".tmp")]


# --------------------------------------------------------------------------- BOP


def test_bop_layout_loads_like_the_toolkit(built, dataset):
    out, counts = built
    models, images, depths = dataset
    bop = out / "bop"
    cam = _load_json(bop / "camera.json")
    assert (cam["width"], cam["height"], cam["fx"], cam["cy"], cam["depth_scale"]) == (W, H, 80.0, 23.5, 0.1)

    info = _load_json(bop / "models" / "models_info.json", keys_to_int=True)
    assert sorted(info) == [1, 3]
    for asset in models:
        ply = _load_ply(bop / "models" / f"obj_{asset.obj_id:06d}.ply")
        i = info[asset.obj_id]
        assert np.allclose(ply["pts"].min(0), [i["min_x"], i["min_y"], i["min_z"]])
        assert np.allclose(ply["pts"].min(0), np.asarray(asset.bbox_min) * 1000, atol=1e-3)
        assert np.allclose(ply["pts"].max(0) - ply["pts"].min(0), [i["size_x"], i["size_y"], i["size_z"]])
        assert i["diameter"] == pytest.approx(asset.diameter * 1000)
        assert ply["faces"].shape == (4, 3) and "normals" in ply and "colors" in ply
        if asset.obj_id == 1:
            assert ply["texture_file"] == "obj_000001.png" and "texture_uv" in ply
            assert (bop / "models" / "obj_000001.png").is_file()

    n_inst = 0
    for rec, store in images:
        chunk, im_id = divmod(rec.index, 3)
        cdir = bop / "train_pbr" / f"{chunk:06d}"
        sc = _load_json(cdir / "scene_camera.json", keys_to_int=True)[im_id]
        gt = _load_json(cdir / "scene_gt.json", keys_to_int=True)[im_id]
        gi = _load_json(cdir / "scene_gt_info.json", keys_to_int=True)[im_id]
        assert np.allclose(np.reshape(sc["cam_K"], (3, 3)), K)
        assert np.allclose(sc["cam_t_w2c"], np.asarray(rec.t_w2c) * 1000)
        depth_mm = iio.imread(cdir / "depth" / f"{im_id:06d}.png").astype(np.float32) * sc["depth_scale"]
        d = depths[rec.index]
        assert np.abs(depth_mm[d > 0] - d[d > 0] * 1000).max() <= sc["depth_scale"] / 2 + 1e-3
        assert (depth_mm[d == 0] == 0).all()
        assert (cdir / "rgb" / f"{im_id:06d}.jpg").read_bytes() == (store / "rgb.jpg").read_bytes()
        assert len(gt) == len(gi) == len(rec.instances)
        for gt_id, (g, e, ei) in enumerate(zip(rec.instances, gt, gi)):
            assert e["obj_id"] == g.obj_id
            assert np.allclose(e["cam_t_m2c"], np.asarray(g.t_m2c) * 1000)
            assert ei["bbox_visib"] == g.bbox_visib and ei["px_count_visib"] == g.px_count_visib
            for kind in ("mask", "mask_visib"):
                m = iio.imread(cdir / kind / f"{im_id:06d}_{gt_id:06d}.png")
                src = store / rec.files[kind][gt_id]
                assert np.array_equal(m, iio.imread(src))
        n_inst += len(gt)
    assert counts["bop_instances"] == n_inst and counts["bop_chunks"] == 3
    # keys sorted numerically, one entry per line, like inout.save_json
    text = (bop / "train_pbr" / "000000" / "scene_gt.json").read_text()
    assert text.startswith('{\n  "0": [') and text.count("\n") == 4


def test_rotations_stay_orthonormal_through_json_and_parquet(built, dataset):
    import pyarrow.parquet as pq

    out, _ = built
    _, images, _ = dataset
    for cdir in sorted((out / "bop" / "train_pbr").iterdir()):
        for im in _load_json(cdir / "scene_gt.json", keys_to_int=True).values():
            assert all(_is_rotation(g["cam_R_m2c"]) for g in im)
        for c in _load_json(cdir / "scene_camera.json", keys_to_int=True).values():
            assert _is_rotation(c["cam_R_w2c"])
    inst = pq.read_table(out / "parquet" / "instances.parquet").to_pylist()
    assert all(_is_rotation(r["R_m2c"]) for r in inst)
    src = [g.R_m2c for rec, _ in images for g in rec.instances]
    assert [np.reshape(r["R_m2c"], (3, 3)).tolist() for r in inst] == src  # exact, in gt order
    imgs = pq.read_table(out / "parquet" / "images.parquet").to_pylist()
    assert all(_is_rotation(r["R_w2c"]) for r in imgs)


def test_corrupt_rotation_is_rejected(dataset, tmp_path):
    models, images, _ = dataset
    rec, store = images[0]
    bad = ImageRecord.from_json(rec.to_json())
    bad.instances[0].R_m2c = (np.asarray(bad.instances[0].R_m2c) * 1.01).tolist()
    with pytest.raises(ValueError, match="not orthonormal"):
        write_outputs(tmp_path, _spec(), [(bad, store)], models)


# --------------------------------------------------------------------------- Parquet and COCO


def test_parquet_rows_match_scene_gt_and_duckdb_queries(built, dataset):
    import duckdb
    import pyarrow.parquet as pq
    from pycocotools import mask as mask_utils

    out, _ = built
    _, images, _ = dataset
    n_gt = sum(
        len(v)
        for cdir in (out / "bop" / "train_pbr").iterdir()
        for v in _load_json(cdir / "scene_gt.json", keys_to_int=True).values()
    )
    pqdir = out / "parquet"
    assert pq.read_metadata(pqdir / "instances.parquet").num_rows == n_gt
    assert pq.read_metadata(pqdir / "images.parquet").num_rows == len(images)
    assert pq.read_schema(pqdir / "images.parquet").pandas_metadata is None
    assert "render_seconds" not in pq.read_schema(pqdir / "images.parquet").names

    con = duckdb.connect()
    rows = con.execute(
        f"select i.index, count(*) from '{pqdir / 'images.parquet'}' i "
        f"join '{pqdir / 'instances.parquet'}' n using (chunk, im_id) group by i.index order by i.index"
    ).fetchall()
    assert rows == [(rec.index, len(rec.instances)) for rec, _ in images]
    (n_t,) = con.execute(f"select count(*) from '{pqdir / 'timings.parquet'}' where render_seconds > 0").fetchone()
    assert n_t == len(images)
    rgb = con.execute(f"select rgb from '{pqdir / 'images.parquet'}' order by index limit 1").fetchone()[0]
    assert (out / rgb).is_file()

    first = pq.read_table(pqdir / "instances.parquet").to_pylist()[0]
    rec, store = images[0]
    rle = first["mask_visib_rle"]
    m = mask_utils.decode({"counts": rle["counts"].encode(), "size": rle["size"]})
    assert np.array_equal(m.astype(bool), iio.imread(store / rec.files["mask_visib"][0]) > 0)


def test_coco_files_load_in_pycocotools(built, dataset):
    from pycocotools import mask as mask_utils
    from pycocotools.coco import COCO

    out, counts = built
    _, images, _ = dataset
    by_index = {rec.index: (rec, store) for rec, store in images}
    split = COCO(str(out / "coco" / "train_pbr.json"))
    n_visible = 0
    for index, (rec, store) in by_index.items():
        anns = sorted(split.loadAnns(split.getAnnIds(imgIds=[index])), key=lambda a: a["id"])
        visible = [i for i, g in enumerate(rec.instances) if g.px_count_visib > 0]
        assert len(anns) == len(visible)  # annotations follow gt order, empty ones left out
        for ann, gt_id in zip(anns, visible):
            g = rec.instances[gt_id]
            vis = iio.imread(store / rec.files["mask_visib"][gt_id]) > 0
            assert np.array_equal(split.annToMask(ann).astype(bool), vis)
            assert ann["category_id"] == g.obj_id and ann["iscrowd"] == 0
            assert ann["bbox"] == [int(v) for v in mask_utils.toBbox(ann["segmentation"] | {"counts": ann["segmentation"]["counts"].encode()})]
            assert ann["bbox"] == [*g.bbox_visib[:2], g.bbox_visib[2] + 1, g.bbox_visib[3] + 1] and ann["area"] == vis.sum()
            assert ann["ignore"] == (g.visib_fract < 0.1)
            n_visible += 1
    assert n_visible == sum(g.px_count_visib > 0 for rec, _ in images for g in rec.instances)
    assert counts["coco_annotations"] == n_visible
    for img in split.loadImgs(split.getImgIds()):
        assert (out / "coco" / img["file_name"]).resolve().is_file()

    for cdir in sorted((out / "bop" / "train_pbr").iterdir()):
        c = COCO(str(cdir / "scene_gt_coco.json"))
        for img in c.loadImgs(c.getImgIds()):
            assert (cdir / img["file_name"]).is_file()
        assert sorted(c.getCatIds()) == [1, 3]


# --------------------------------------------------------------------------- determinism and merge safety


def test_two_builds_are_byte_identical_except_timings(dataset, tmp_path):
    models, images, _ = dataset
    write_outputs(tmp_path / "a", _spec(), images, models)
    slower = [(ImageRecord.from_json({**r.to_json(), "render_seconds": r.render_seconds + 1}), s) for r, s in images]
    write_outputs(tmp_path / "b", _spec(), list(reversed(slower)), models)
    a, b = _all_files(tmp_path / "a"), _all_files(tmp_path / "b")
    assert a.keys() == b.keys()
    differ = [k for k in a if a[k] != b[k]]
    assert differ == [os.path.join("parquet", "timings.parquet")]

    # Re-merging into the same folder rewrites nothing.
    stat = {p: p.stat() for p in (tmp_path / "a").rglob("*") if p.is_file()}
    counts = write_outputs(tmp_path / "a", _spec(), images, models)
    assert counts["bop_written"] == 0 and counts["bop_removed"] == 0
    for p, st in stat.items():
        assert (p.stat().st_ino, p.stat().st_mtime_ns) == (st.st_ino, st.st_mtime_ns), p


def test_rerun_removes_files_of_dropped_images(dataset, tmp_path):
    models, images, _ = dataset
    write_outputs(tmp_path, _spec(), images, models)
    (tmp_path / "bop" / "train_pbr" / "000002" / "notes.txt").write_text("mine")
    keep = [e for e in images if e[0].index in (0, 4)]
    write_outputs(tmp_path, _spec(), keep, models)
    fresh = tmp_path / "fresh"
    write_outputs(fresh, _spec(), keep, models)
    got = {k: v for k, v in _all_files(tmp_path).items() if not k.startswith("fresh")}
    got.pop(os.path.join("bop", "train_pbr", "000002", "notes.txt"))  # user files survive
    assert got == _all_files(fresh)
    assert not (tmp_path / "bop" / "train_pbr" / "000002" / "rgb").exists()


def test_interrupted_merge_leaves_no_partial_json(dataset, tmp_path, monkeypatch):
    models, images, _ = dataset
    real_replace = os.replace
    calls = {"n": 0}

    def flaky_replace(src, dst):
        calls["n"] += 1
        if str(dst).endswith(".json") and calls["n"] > 12:
            # Simulate a crash after the temp file is complete but before the rename.
            raise KeyboardInterrupt("killed mid-merge")
        return real_replace(src, dst)

    monkeypatch.setattr(os, "replace", flaky_replace)
    with pytest.raises(KeyboardInterrupt):
        write_outputs(tmp_path, _spec(), images, models)
    monkeypatch.setattr(os, "replace", real_replace)

    files = list(tmp_path.rglob("*"))
    assert not [p for p in files if p.name.endswith(".tmp")]
    jsons = [p for p in files if p.suffix == ".json"]
    assert jsons  # the crash happened mid-way, not before the first file
    for p in jsons:
        json.loads(p.read_text())  # complete or absent, never half-written

    write_outputs(tmp_path, _spec(), images, models)
    write_outputs(tmp_path / "fresh", _spec(), images, models)
    got = {k: v for k, v in _all_files(tmp_path).items() if not k.startswith("fresh")}
    assert got == _all_files(tmp_path / "fresh")


def test_outputs_switches(dataset, tmp_path):
    models, images, _ = dataset
    counts = write_outputs(tmp_path, _spec(bop=False, coco=False), images, models)
    assert not (tmp_path / "bop").exists() and not (tmp_path / "coco").exists()
    import pyarrow.parquet as pq

    rgb = pq.read_table(tmp_path / "parquet" / "images.parquet").column("rgb").to_pylist()
    assert all((tmp_path / p).is_file() for p in rgb)
    assert counts["parquet_instances"] == sum(len(r.instances) for r, _ in images)
    assert dataset_mod.chunk_and_im_id(2500, 1000) == (2, 500)


def test_build_without_masks_gives_box_only_coco(dataset, tmp_path):
    import pyarrow.parquet as pq
    from pycocotools.coco import COCO

    models, images, _ = dataset
    bare = [(ImageRecord.from_json({**r.to_json(), "files": {"rgb": "rgb.jpg", "depth": "depth.png"}}), s)
            for r, s in images]
    write_outputs(tmp_path, _spec(masks=False), bare, models)
    assert not list((tmp_path / "bop").rglob("mask*/*.png"))
    c = COCO(str(tmp_path / "coco" / "train_pbr.json"))
    anns = c.loadAnns(c.getAnnIds())
    assert anns and all("segmentation" not in a and a["area"] > 0 for a in anns)
    rles = pq.read_table(tmp_path / "parquet" / "instances.parquet").column("mask_visib_rle").to_pylist()
    assert rles and all(r is None for r in rles)
