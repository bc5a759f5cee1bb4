"""Parquet tables: ``images``, ``instances`` and ``timings`` under ``<out>/parquet/``.

Bytes are a function of the records only: tables are built from Arrow arrays with an explicit
schema (no pandas metadata), rows in (index, gt_id) order, and every writer option that could
change the file is pinned. Wall-clock render time differs between two builds of the same spec,
so it lives in ``timings.parquet`` and nowhere else.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from .coco import visible_rles
from .dataset import (
    ImageEntry,
    chunk_and_im_id,
    image_relpaths,
    rotation_list,
    sorted_images,
    vec_mm,
    write_if_changed,
)

_F64_LIST = pa.list_(pa.float64())
_I32_LIST = pa.list_(pa.int32())

IMAGES_SCHEMA = pa.schema(
    [
        ("chunk", pa.int32()),
        ("im_id", pa.int32()),
        ("index", pa.int64()),
        ("arr", pa.int32()),
        ("cam", pa.int32()),
        ("scene", pa.string()),
        ("stage", pa.string()),
        ("backend", pa.string()),
        ("backend_version", pa.string()),
        ("quality", pa.string()),
        ("seed", pa.uint64()),
        ("width", pa.int32()),
        ("height", pa.int32()),
        ("K", _F64_LIST),
        ("R_w2c", _F64_LIST),
        ("t_w2c_mm", _F64_LIST),
        ("depth_scale", pa.float64()),
        ("n_instances", pa.int32()),
        ("rgb", pa.string()),
        ("depth", pa.string()),
        ("exr", pa.string()),
        ("normals", pa.string()),
        ("nocs", pa.string()),
        ("depth_noisy", pa.string()),
        ("albedo", pa.string()),
        ("distortion", _F64_LIST),
    ]
)

RLE_TYPE = pa.struct([("counts", pa.string()), ("size", _I32_LIST)])

INSTANCES_SCHEMA = pa.schema(
    [
        ("chunk", pa.int32()),
        ("im_id", pa.int32()),
        ("index", pa.int64()),
        ("gt_id", pa.int32()),
        ("obj_id", pa.int32()),
        ("inst", pa.int32()),
        ("R_m2c", _F64_LIST),
        ("t_m2c_mm", _F64_LIST),
        ("bbox_obj", _I32_LIST),
        ("bbox_visib", _I32_LIST),
        ("px_count_all", pa.int64()),
        ("px_count_valid", pa.int64()),
        ("px_count_visib", pa.int64()),
        ("visib_fract", pa.float64()),
        ("mask_visib_rle", RLE_TYPE),
    ]
)

TIMINGS_SCHEMA = pa.schema(
    [
        ("chunk", pa.int32()),
        ("im_id", pa.int32()),
        ("index", pa.int64()),
        ("render_seconds", pa.float64()),
        # quality.control: error (null otherwise): samples per pixel spent, the image's estimated
        # relative MSE and its target, the paper preset's estimated relative MSE at this image
        ("samples", pa.int64()),
        ("error_estimate", pa.float64()),
        ("error_target", pa.float64()),
    ]
)

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


def table_bytes(table: pa.Table) -> bytes:
    sink = pa.BufferOutputStream()
    pq.write_table(table, sink, **WRITE_OPTIONS)
    return sink.getvalue().to_pybytes()


def _table(rows: list[dict[str, Any]], schema: pa.Schema) -> pa.Table:
    cols = {f.name: pa.array([r[f.name] for r in rows], type=f.type) for f in schema}
    return pa.Table.from_pydict(cols, schema=schema)


def error_columns(stats: dict) -> dict[str, Any]:
    """The timings table's error-target columns of one image (nulls unless it had a target)."""
    targeted = "error_target" in stats
    return {"samples": int(stats["samples"]) if targeted else None,
            "error_estimate": float(stats["error_estimate"]) if targeted else None,
            "error_target": float(stats["error_target"]) if targeted else None}


def write_parquet(
    out: Path,
    split: str,
    images: Sequence[ImageEntry],
    chunk_size: int,
    *,
    bop_layout: bool = True,
    rles: dict[int, list] | None = None,
    suffix: str = "",
) -> dict[str, int]:
    """Write the three tables (``images<suffix>.parquet``, ...); paths are relative to ``out`` (into
    ``bop/`` when it is written)."""
    out = Path(out)
    image_rows, inst_rows, timing_rows = [], [], []
    for rec, store in sorted_images(images):
        chunk, im_id = chunk_and_im_id(rec.index, chunk_size)
        if bop_layout:
            paths = image_relpaths(split, rec, chunk_size)
        else:
            def rel(name: str | None) -> str | None:
                return None if not name else os.path.relpath(Path(store) / name, out).replace(os.sep, "/")

            paths = {"rgb": rel(rec.rgb_file), "depth": rel(rec.depth_file), "exr": rel(rec.exr_file),
                     "normals": rel(rec.normals_file), "nocs": rel(rec.nocs_file),
                     "depth_noisy": rel(rec.depth_noisy_file), "albedo": rel(rec.albedo_file)}
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
        img_rles = rles[rec.index] if rles is not None and rec.index in rles else visible_rles(rec, store)
        for gt_id, (g, rle) in enumerate(zip(rec.instances, img_rles)):
            inst_rows.append(
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

    folder = out / "parquet"
    write_if_changed(folder / f"images{suffix}.parquet", table_bytes(_table(image_rows, IMAGES_SCHEMA)))
    write_if_changed(folder / f"instances{suffix}.parquet", table_bytes(_table(inst_rows, INSTANCES_SCHEMA)))
    write_if_changed(folder / f"timings{suffix}.parquet", table_bytes(_table(timing_rows, TIMINGS_SCHEMA)))
    return {"parquet_images": len(image_rows), "parquet_instances": len(inst_rows)}
