"""Parquet tables: ``images``, ``instances`` and ``timings`` under ``<out>/parquet/``.

Bytes are a function of the records only: tables are built from Arrow arrays with an explicit
schema (no pandas metadata), rows in (index, gt_id) order, and every writer option that could
change the file is pinned. Wall-clock render time differs between two builds of the same spec,
so it lives in ``timings.parquet`` and nowhere else.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

import numpy as np

from ..output_api import DatasetWriter, Merge, Part
from .dataset import chunk_and_im_id, file_paths, rotation_list, sorted_images, vec_mm, write_if_changed
from .masks import visible_rles

# The images table's file columns, in this order: the colour image and the built-in products'
# kinds (null where an image has none); a kind another product writes follows them, by name.
FILE_COLUMNS = ("rgb", "depth", "exr", "normals", "nocs", "depth_noisy", "albedo")
TABLES = ("images", "instances", "timings")

# Pinned so that a pyarrow default change cannot silently change dataset bytes.
WRITE_OPTIONS: dict[str, Any] = dict(
    compression="zstd",
    compression_level=3,
    use_dictionary=True,
    write_statistics=True,
    version="2.6",
    data_page_version="1.0",
    row_group_size=1 << 20,
    data_page_size=1 << 20,
    write_page_index=False,
    store_schema=True,
)


@functools.cache
def schemas() -> dict[str, Any]:
    """The three tables' schemas without the file columns of other products (pyarrow is imported
    here, not when a spec is validated)."""
    import pyarrow as pa

    f64, i32 = pa.list_(pa.float64()), pa.list_(pa.int32())
    images = [("chunk", pa.int32()), ("im_id", pa.int32()), ("index", pa.int64()), ("arr", pa.int32()),
              ("cam", pa.int32()), ("scene", pa.string()), ("stage", pa.string()), ("backend", pa.string()),
              ("backend_version", pa.string()), ("quality", pa.string()), ("seed", pa.uint64()),
              ("width", pa.int32()), ("height", pa.int32()), ("K", f64), ("R_w2c", f64), ("t_w2c_mm", f64),
              ("depth_scale", pa.float64()), ("n_instances", pa.int32()),
              *((c, pa.string()) for c in FILE_COLUMNS), ("distortion", f64)]
    rle = pa.struct([("counts", pa.string()), ("size", i32)])
    instances = [("chunk", pa.int32()), ("im_id", pa.int32()), ("index", pa.int64()), ("gt_id", pa.int32()),
                 ("obj_id", pa.int32()), ("inst", pa.int32()), ("R_m2c", f64), ("t_m2c_mm", f64),
                 ("bbox_obj", i32), ("bbox_visib", i32), ("px_count_all", pa.int64()),
                 ("px_count_valid", pa.int64()), ("px_count_visib", pa.int64()), ("visib_fract", pa.float64()),
                 ("mask_visib_rle", rle)]
    # quality.control: error (null otherwise): samples per pixel spent, the image's estimated
    # relative MSE and its target, the paper preset's estimated relative MSE at this image
    timings = [("chunk", pa.int32()), ("im_id", pa.int32()), ("index", pa.int64()), ("render_seconds", pa.float64()),
               ("samples", pa.int64()), ("error_estimate", pa.float64()), ("error_target", pa.float64())]
    return {"images": pa.schema(images), "instances": pa.schema(instances), "timings": pa.schema(timings)}


def images_schema(extra: list[str]):
    """The images table's schema with a string column per other file kind (after ``distortion``)."""
    import pyarrow as pa

    base = schemas()["images"]
    return pa.schema(list(base) + [pa.field(k, pa.string()) for k in extra]) if extra else base


def table_bytes(table) -> bytes:
    import pyarrow as pa
    import pyarrow.parquet as pq

    sink = pa.BufferOutputStream()
    pq.write_table(table, sink, **WRITE_OPTIONS)
    return sink.getvalue().to_pybytes()


def _table(rows: list[dict[str, Any]], schema):
    import pyarrow as pa

    cols = {f.name: pa.array([r[f.name] for r in rows], type=f.type) for f in schema}
    return pa.Table.from_pydict(cols, schema=schema)


def error_columns(stats: dict) -> dict[str, Any]:
    """The timings table's error-target columns of one image (nulls unless it had a target)."""
    targeted = "error_target" in stats
    return {"samples": int(stats["samples"]) if targeted else None,
            "error_estimate": float(stats["error_estimate"]) if targeted else None,
            "error_target": float(stats["error_target"]) if targeted else None}


def write_parquet(merge: Merge, part: Part) -> dict[str, int]:
    """Write the three tables of a part (``images<suffix>.parquet``, ...); file paths are relative
    to ``out`` (into ``bop/`` when it is written)."""
    out = Path(merge.out)
    chunk_size = merge.spec.outputs.chunk_size
    images = sorted_images(part.images)
    extra = sorted({k for rec, _ in images for k, v in rec.files.items() if isinstance(v, str)} - set(FILE_COLUMNS))
    image_rows, inst_rows, timing_rows = [], [], []
    for rec, store in images:
        chunk, im_id = chunk_and_im_id(rec.index, chunk_size)
        found = file_paths(merge, part.split, rec, store)
        paths = {k: found.get(k) for k in (*FILE_COLUMNS, *extra)}
        image_rows.append(
            {
                "chunk": chunk, "im_id": im_id, "index": rec.index, "arr": rec.arr, "cam": rec.cam,
                "scene": rec.scene, "stage": rec.stage, "backend": rec.backend,
                "backend_version": rec.backend_version, "quality": rec.quality, "seed": rec.seed,
                "width": rec.width, "height": rec.height,
                "K": np.asarray(rec.K, dtype=np.float64).reshape(-1).tolist(),
                "R_w2c": rotation_list(rec.R_w2c, f"image {rec.index} R_w2c"),
                "t_w2c_mm": vec_mm(rec.t_w2c, f"image {rec.index} t_w2c"),
                "depth_scale": float(rec.depth_scale), "n_instances": len(rec.instances),
                **paths, "distortion": list(rec.distortion) if rec.distortion else None,
            }
        )
        timing_rows.append({"chunk": chunk, "im_id": im_id, "index": rec.index, "render_seconds": float(rec.render_seconds),
                            **error_columns(rec.stats)})
        inst_rows += _instance_rows(rec, store, chunk, im_id)

    folder, suffix, tables = out / "parquet", part.suffix, schemas()
    write_if_changed(folder / f"images{suffix}.parquet", table_bytes(_table(image_rows, images_schema(extra))))
    write_if_changed(folder / f"instances{suffix}.parquet", table_bytes(_table(inst_rows, tables["instances"])))
    write_if_changed(folder / f"timings{suffix}.parquet", table_bytes(_table(timing_rows, tables["timings"])))
    return {"parquet_images": len(image_rows), "parquet_instances": len(inst_rows)}


def _instance_rows(rec, store: Path, chunk: int, im_id: int) -> list[dict[str, Any]]:
    rows = []
    for gt_id, (g, rle) in enumerate(zip(rec.instances, visible_rles(rec, store))):
        rows.append(
            {
                "chunk": chunk, "im_id": im_id, "index": rec.index, "gt_id": gt_id,
                "obj_id": g.obj_id, "inst": g.inst,
                "R_m2c": rotation_list(g.R_m2c, f"image {rec.index} gt {gt_id} R_m2c"),
                "t_m2c_mm": vec_mm(g.t_m2c, f"image {rec.index} gt {gt_id} t_m2c"),
                "bbox_obj": [int(v) for v in g.bbox_obj],
                "bbox_visib": [int(v) for v in g.bbox_visib],
                "px_count_all": g.px_count_all, "px_count_valid": g.px_count_valid,
                "px_count_visib": g.px_count_visib, "visib_fract": float(g.visib_fract),
                "mask_visib_rle": rle,
            }
        )
    return rows


class ParquetWriter(DatasetWriter):
    name = "parquet"
    description = ("Parquet tables: parquet/images, instances (poses, boxes, pixel counts, visible-mask RLE) and "
                   "timings, one row per image / instance.")
    default = True

    def write(self, merge: Merge) -> dict[str, int]:
        counts: dict[str, int] = {}
        for part in merge.parts:
            for k, v in write_parquet(merge, part).items():
                counts[k] = counts.get(k, 0) + v
        return counts

    def owns(self, rel: str, merge: Merge) -> bool | None:
        parts = rel.split("/")
        if len(parts) != 2 or parts[0] != "parquet" or not parts[1].endswith(".parquet"):
            return None
        stem = parts[1].removesuffix(".parquet")
        table = next((t for t in TABLES if stem.startswith(t)), None)
        if table is None:
            return None
        return stem[len(table):] in {p.suffix for p in merge.parts}


WRITER = ParquetWriter()
