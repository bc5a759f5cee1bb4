"""Registered outputs: every product and writer is an entry point, the spec's switches are their names,
and a package specsynth does not know adds a map and a format (examples/plugin_output) with no
change to the core."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from PIL import Image

from specsynth.output_api import DatasetWriter, ViewProduct, products, writers
from specsynth.plan.compiler import compile_spec
from specsynth.plugins import output_switches
from specsynth.run.build import build
from specsynth.spec.yamlio import SpecError, load_spec

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "plugin_output"
SPEC = """\
name: labels
seed: 4
intrinsics: {width: 96, height: 72, fx: 86.0, fy: 86.0, cx: 47.5, cy: 35.5}
objects: {builtin: [duck, mug, jenga]}
scenes: [{name: room}]
arrangements: {count: 1}
cameras: {per_arrangement: 2, distance: [0.35, 0.5]}
backend: {name: photo}
outputs: {image_format: png}
"""


@pytest.fixture
def labels_installed(tmp_path, monkeypatch):
    """The example package registered as pip would: a distribution's metadata with its entry
    points on the path (build workers are spawned with the same path)."""
    dist = tmp_path / "site" / "specsynth_labels-0.1.0.dist-info"
    dist.mkdir(parents=True)
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: specsynth-labels\nVersion: 0.1.0\n")
    (dist / "entry_points.txt").write_text(
        "[specsynth.products]\ninstance_map = specsynth_labels.instance_map:PRODUCT\n\n"
        "[specsynth.writers]\nboxes_csv = specsynth_labels.boxes_csv:WRITER\n")
    monkeypatch.syspath_prepend(str(EXAMPLE))
    monkeypatch.syspath_prepend(str(tmp_path / "site"))
    return tmp_path


def _spec(folder: Path, text: str = SPEC) -> Path:
    f = folder / "labels.yaml"
    f.write_text(text)
    return f


def test_every_output_is_registered_and_each_its_own_module():
    found_products, found_writers = products(), writers()
    assert {"albedo", "depth", "depth_noisy", "exr", "masks", "nocs", "normals", "right"} <= set(found_products)
    assert {"bop", "coco", "parquet", "yolo"} <= set(found_writers)
    for name, p in found_products.items():
        assert isinstance(p, ViewProduct) and p.name == name
    for name, w in found_writers.items():
        assert isinstance(w, DatasetWriter) and w.name == name
    modules = [type(o).__module__ for o in (*found_products.values(), *found_writers.values())]
    assert len(set(modules)) == len(modules)  # one module per output
    switches = {s.name for s in output_switches() if s.switch}
    assert switches == set(found_writers) | {n for n, p in found_products.items() if p.switch}


def test_an_unknown_output_names_the_known_ones(tmp_path):
    f = _spec(tmp_path)
    with pytest.raises(SpecError) as e:
        load_spec(f, ["outputs.normal=true"])
    msg = str(e.value)
    assert "--set outputs.normal" in msg and "unknown output 'normal'" in msg and "did you mean 'normals'" in msg
    assert "known are albedo, bop, coco, depth" in msg and "needs that package installed" in msg
    f.write_text(SPEC.replace("outputs: {image_format: png}", "outputs:\n  image_format: png\n  instance_map: true"))
    with pytest.raises(SpecError, match=r"labels.yaml:11:3: outputs.instance_map: unknown output 'instance_map'"):
        load_spec(f)


def test_a_writer_needs_what_it_reads(tmp_path):
    with pytest.raises(SpecError, match="yolo reads what bop writes: switch on bop too"):
        load_spec(_spec(tmp_path), ["outputs.yolo=true", "outputs.bop=false"])


def test_a_broken_output_says_what_to_reinstall(tmp_path, monkeypatch):
    dist = tmp_path / "site" / "specsynth_broken-0.1.0.dist-info"
    dist.mkdir(parents=True)
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: specsynth-broken\nVersion: 0.1.0\n")
    (dist / "entry_points.txt").write_text("[specsynth.products]\nglow = specsynth_broken_missing:PRODUCT\n")
    monkeypatch.syspath_prepend(str(tmp_path / "site"))
    with pytest.raises(SpecError, match=r"product 'glow' cannot be imported .*reinstall specsynth-broken"):
        load_spec(_spec(tmp_path), ["outputs.glow=true"])
    assert load_spec(_spec(tmp_path)).spec.outputs.products == ("depth", "masks")  # the others still work


def test_a_third_party_map_and_format_without_touching_the_core(labels_installed, tmp_path):
    core = "\n".join(p.read_text() for p in (ROOT / "specsynth").rglob("*.py"))
    assert "instance_map" not in core and "boxes_csv" not in core
    f = _spec(tmp_path)
    on = ["outputs.instance_map=true", "outputs.boxes_csv=true"]
    plain, labelled = compile_spec(load_spec(f)), compile_spec(load_spec(f, on))
    assert plain.stage_digests["render"] != labelled.stage_digests["render"]  # a product re-renders
    assert "specsynth-labels 0.1.0" in labelled.stage_inputs["render"]["products"]
    out = tmp_path / "out"
    s = build(labelled, out, jobs=1)
    assert not s.failures and s.images >= 1

    chunk = out / "bop" / "train_pbr" / "000000"
    gt = json.loads((chunk / "scene_gt.json").read_text())
    for im, objects in gt.items():
        labels = np.asarray(Image.open(chunk / "instance_map" / f"{int(im):06d}.png"))
        assert labels.dtype == np.uint16
        for k in range(len(objects)):
            visible = np.asarray(Image.open(chunk / "mask_visib" / f"{int(im):06d}_{k:06d}.png")) > 0
            assert np.array_equal(labels == k + 1, visible)
    images = pq.read_table(out / "parquet" / "images.parquet").to_pylist()
    assert all((out / r["instance_map"]).is_file() for r in images)
    rows = (out / "csv" / "train_pbr.csv").read_text().splitlines()
    info = json.loads((chunk / "scene_gt_info.json").read_text())
    assert len(rows) - 1 == sum(g["px_count_visib"] > 0 for v in info.values() for g in v)
    assert s.stages["render"].ran == s.images

    # Switched off again: the same folder rebuilt keeps neither.
    s2 = build(compile_spec(load_spec(f)), out, jobs=1)
    assert not s2.failures and not (out / "csv").exists() and not list(out.rglob("instance_map"))
    assert "instance_map" not in pq.read_schema(out / "parquet" / "images.parquet").names


def test_yolo_as_a_writer_equals_the_export(tmp_path):
    """outputs.yolo: the merge exports the build into <out>/yolo exactly as `specsynth export yolo`
    would into a folder of its own; switched off, the folder goes."""
    from specsynth.outputs.yolo import export_yolo

    f = _spec(tmp_path)
    out = tmp_path / "out"
    s = build(compile_spec(load_spec(f, ["outputs.yolo=true", "cameras.stereo={baseline: 0.05}"])), out, jobs=1)
    assert not s.failures and s.images >= 2
    export_yolo(out, tmp_path / "exported")

    def tree(root: Path) -> dict[str, bytes]:
        return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}

    made = tree(out / "yolo")
    assert made == tree(tmp_path / "exported")
    assert {"data.yaml", "labels/train_pbr_right/train_pbr_right_000000_000000.txt"} <= set(made)
    build(compile_spec(load_spec(f)), out, jobs=1)
    assert not (out / "yolo").exists() and (out / "bop" / "train_pbr").is_dir()


def test_a_spec_pickles_with_its_switches(tmp_path):
    """The outputs model is made from what is installed, at run time: a spec still crosses a
    process boundary (executors, caches) and comes back equal."""
    import copy
    import pickle

    spec = load_spec(_spec(tmp_path), ["outputs.normals=true", "outputs.coco=false"]).spec
    back = pickle.loads(pickle.dumps(spec))
    assert back == spec == copy.deepcopy(spec)
    assert back.outputs.products == ("depth", "masks", "normals") and "coco" not in back.outputs.selected("writer")
