"""End-to-end builds on built-in assets with the photo backend: cache, diff, determinism, plan."""

from __future__ import annotations

import hashlib
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from specsynth.plan.compiler import compile_spec
from specsynth.run.build import build, diff, plan, read_manifest
from specsynth.scenes import FIXED_ROOMS, builtin_scenes
from specsynth.spec.yamlio import load_spec

SPEC = """\
# yaml-language-server: $schema=../schemas/dataset-spec.schema.json
name: tiny
seed: 3
intrinsics: {width: 160, height: 120, fx: 143.1, fy: 143.4, cx: 81.3, cy: 60.5}
objects:
  builtin: [duck, mug, jenga]
scenes:
  - name: room
arrangements:
  count: 2
cameras:
  per_arrangement: 3
  distance: [0.35, 0.7]
backend:
  name: photo
outputs:
  image_format: png
"""


def tree_digest(root: Path, skip=("timings.parquet",)) -> dict[str, str]:
    """sha256 of every output file outside the internal .specsynth folder."""
    out = {}
    for p in sorted(root.rglob("*")):
        rel = p.relative_to(root)
        if p.is_file() and rel.parts[0] != ".specsynth" and p.name not in skip:
            out[str(rel)] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


@pytest.fixture(scope="module")
def spec_file(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("spec")
    f = d / "tiny.yaml"
    f.write_text(SPEC)
    return f


def graph(spec_file, *overrides):
    return compile_spec(load_spec(spec_file, list(overrides)))


@pytest.fixture(scope="module")
def built(spec_file, tmp_path_factory) -> tuple[Path, object]:
    out = tmp_path_factory.mktemp("out") / "a"
    summary = build(graph(spec_file), out, jobs=1)
    assert not summary.failures, summary.failures
    return out, summary


def test_first_build_writes_a_dataset(built):
    out, s = built
    assert s.images > 0
    assert s.stages["arrange"].ran == 2 and s.stages["view"].ran == 6
    assert s.images == s.views_accepted
    chunk = out / "bop" / "train_pbr" / "000000"
    gt = json.loads((chunk / "scene_gt.json").read_text())
    assert len(gt) == s.images
    assert (out / "parquet" / "instances.parquet").is_file()


def test_second_build_runs_nothing_and_diff_is_empty(built, spec_file):
    out, _ = built
    before = tree_digest(out)
    m1 = read_manifest(out)
    s = build(graph(spec_file), out, jobs=1)
    assert s.stages["arrange"].ran == s.stages["view"].ran == s.stages["render"].ran == 0
    assert s.stages["render"].cached == s.images
    assert tree_digest(out) == before
    assert diff(m1, read_manifest(out))["identical"]


def test_plan_reports_everything_cached(built, spec_file):
    out, _ = built
    p1 = plan(graph(spec_file), out)
    assert p1["stages"]["arrange"] == {"jobs": 2, "cached": 2, "to_run": 0, "est_seconds": 0.0}
    assert p1 == plan(graph(spec_file), out)


def test_camera_change_reruns_only_views_and_renders(built, spec_file, tmp_path):
    out, _ = built
    m1 = read_manifest(out)
    g2 = graph(spec_file, "cameras.distance=[0.4,0.8]")
    p = plan(g2, out)
    assert p["stages"]["arrange"]["to_run"] == 0
    assert p["stages"]["view"]["to_run"] == 6
    d = diff(m1, {"stage_inputs": g2.stage_inputs, "jobs": {s: {} for s in ("arrange", "view", "render")} | {
        "arrange": {j.id: j.key for j in g2.jobs() if j.stage == "arrange"},
        "view": {j.id: j.key for j in g2.jobs() if j.stage == "view"},
        "render": {j.id: j.key for j in g2.jobs() if j.stage == "render"},
    }})
    assert d["arrange"]["modified"] == 0
    assert d["view"]["modified"] == 6 and "spec:cameras.distance" in d["view"]["causes"]
    assert "upstream:view" in d["render"]["causes"]


def cli_build(spec_file: Path, out: Path, *args: str) -> None:
    """A build in a fresh process, as a user runs it (importing bpy into a process, as a test
    may have done in this one, changes llvmpipe's pixels slightly)."""
    r = subprocess.run([sys.executable, "-m", "specsynth.cli", "build", str(spec_file), "--out", str(out), "--quiet", *args],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr


def test_jobs_1_and_2_give_identical_files(spec_file, tmp_path):
    cli_build(spec_file, tmp_path / "a", "--jobs", "1")
    cli_build(spec_file, tmp_path / "b", "--jobs", "2")
    assert tree_digest(tmp_path / "b") == tree_digest(tmp_path / "a")


def test_cli_build_and_diff(spec_file, built, tmp_path):
    out, _ = built
    r = subprocess.run([sys.executable, "-m", "specsynth.cli", "diff", str(out), str(out), "--json"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["identical"]
    r = subprocess.run([sys.executable, "-m", "specsynth.cli", "plan", str(spec_file), "--out", str(out), "--json"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["stages"]["render"]["cached"] >= 1


def test_view_and_stats_write_readable_files(built, tmp_path):
    from PIL import Image

    from specsynth.outputs.qa import contact_sheet, dataset_stats

    out, s = built
    sheet = contact_sheet([out, out], tmp_path / "sheet.png", n=2)
    im = Image.open(sheet)
    assert im.width >= 2 * 320 and im.height > 100
    assert len(set(im.convert("L").getdata())) > 50  # real picture content, not a blank canvas
    table = dataset_stats(out, tmp_path / "stats")
    assert table["images"] == s.images and table["instances"] == s.instances
    png = Image.open(tmp_path / "stats" / "stats.png")
    assert png.width > 600 and png.height > 400
    r = subprocess.run([sys.executable, "-m", "specsynth.cli", "view", str(out), "--out", str(tmp_path / "v.png"), "-n", "1"],
                       capture_output=True, text=True)
    assert r.returncode == 0 and (tmp_path / "v.png").stat().st_size > 10_000, r.stderr


def test_outputs_are_consistent_across_formats(built):
    """Parquet rows == scene_gt instances; COCO loads; depth decodes to metres within depth_scale/2."""
    import duckdb
    from pycocotools.coco import COCO

    out, s = built
    chunk = out / "bop" / "train_pbr" / "000000"
    gt = json.loads((chunk / "scene_gt.json").read_text())
    n = duckdb.sql(f"select count(*) from '{out}/parquet/instances.parquet'").fetchall()[0][0]
    assert n == sum(len(v) for v in gt.values()) == s.instances
    coco = COCO(str(chunk / "scene_gt_coco.json"))
    assert len(coco.getImgIds()) == s.images


def test_summary_accounts_for_what_was_skipped(built, spec_file):
    out, first = built
    assert set(first.saved) == {"visibility_precheck", "scene_loaded_once_per_arrangement", "cache"}
    assert first.saved["cache"] == 0.0
    again = build(graph(spec_file), out, jobs=1)
    assert again.saved["cache"] > 0  # every render came from the store


def test_texture_bytes_are_part_of_the_keys(tmp_path):
    from PIL import Image

    tex = tmp_path / "tex.png"
    Image.new("RGB", (8, 8), (0, 0, 0)).save(tex)
    f = tmp_path / "t.yaml"
    f.write_text(SPEC.replace("  builtin: [duck, mug, jenga]\n", "  builtin: [duck]\n  materials:\n    duck: {texture: tex.png}\n"))
    before = graph(f).stage_digests
    Image.new("RGB", (8, 8), (255, 0, 0)).save(tex)
    after = graph(f).stage_digests
    assert after["render"] != before["render"]  # a material's texture is the renders' alone
    assert after["arrange"] == before["arrange"] and after["view"] == before["view"]


def test_unknown_stage_and_missing_texture_fail_validation_located(tmp_path):
    from specsynth.spec.yamlio import SpecError

    f = tmp_path / "t.yaml"
    f.write_text(SPEC.replace("  - name: room\n", "  - name: room\n    stages: [table, nope]\n")
                 .replace("  builtin: [duck, mug, jenga]\n", "  builtin: [duck]\n  materials:\n    duck: {texture: missing.png}\n"))
    with pytest.raises(SpecError) as ei:
        graph(f)
    got = {(p.path, p.line) for p in ei.value.problems}
    assert ("objects.materials.duck.texture", 8) in got and ("scenes.0.stages", 11) in got, got


def test_manifest_lists_only_finished_jobs(tmp_path):
    f = tmp_path / "t.yaml"
    f.write_text(SPEC)
    out = tmp_path / "out"
    g = graph(f)
    build(g, out, jobs=1, until="view")  # no render ran
    from specsynth.run.build import write_manifest

    write_manifest(g, out, [g.arrangement_jobs(a) for a in range(g.n_arrangements)])
    m = read_manifest(out)
    assert len(m["jobs"]["arrange"]) == 2 and len(m["jobs"]["view"]) == 6 and m["jobs"]["render"] == {}


def test_photo_background_folder_is_relative_to_the_spec(tmp_path):
    from PIL import Image

    (tmp_path / "photos").mkdir()
    Image.new("RGB", (64, 48), (10, 200, 30)).save(tmp_path / "photos" / "green.png")
    f = tmp_path / "t.yaml"
    f.write_text(SPEC.replace("  name: photo\n", "  name: photo\n  backgrounds: photos\n").replace("count: 2", "count: 1"))
    r = subprocess.run([sys.executable, "-m", "specsynth.cli", "build", str(f), "--out", str(tmp_path / "out"), "--quiet"],
                       capture_output=True, text=True, cwd="/")
    assert r.returncode == 0, r.stdout + r.stderr
    rgb = next((tmp_path / "out" / "bop").rglob("rgb/*.png"))
    corner = np.asarray(Image.open(rgb))[:4, :4].reshape(-1, 3).mean(0)
    assert corner[1] > corner[0] + 50  # the folder's green photo, found from cwd=/


def test_render_jobs_store_the_rles_the_merge_would_encode(built):
    """The merge reads each view's visible-mask RLEs from its render job instead of decoding
    every mask PNG serially; they must be exactly what decoding the masks gives."""
    from specsynth.outputs.masks import RLE_FILE, encode_rle, read_mask

    out, s = built
    dirs = [p.parent for p in (out / ".specsynth" / "store" / "render").rglob(RLE_FILE)]
    assert len(dirs) == s.images
    for d in dirs:
        rec = json.loads((d / "record.json").read_text())
        assert json.loads((d / RLE_FILE).read_text()) == [encode_rle(read_mask(d / m)) for m in rec["files"]["mask_visib"]]


def test_timeline_covers_every_job_the_build_ran_and_only_those(spec_file, tmp_path):
    out = tmp_path / "timed"
    s = build(graph(spec_file), out, jobs=1)
    trace = json.loads((out / ".specsynth" / "trace.json").read_text())["traceEvents"]
    boxes = [e for e in trace if e["ph"] == "X"]
    for stage in ("arrange", "view", "render"):  # a box per call; "(n)" when it holds n jobs
        n = sum(int(e["name"].rsplit("(", 1)[1][:-1]) if e["name"].endswith(")") else 1 for e in boxes if e["cat"] == stage)
        assert n == s.stages[stage].ran > 0
    assert {e["tid"] for e in boxes} == {0} and s.workers == 1
    assert all(e["ts"] >= 0 and e["dur"] > 0 for e in boxes)
    assert 0 < s.utilisation <= 1 and s.run_seconds <= s.wall_seconds
    # a rebuild that runs nothing must not leave the first build's timeline behind
    s = build(graph(spec_file), out, jobs=1)
    trace = json.loads((out / ".specsynth" / "trace.json").read_text())
    assert trace["traceEvents"] == [] and s.run_seconds == 0


def test_workers_use_one_blas_thread_and_give_it_back(spec_file, tmp_path):
    from threadpoolctl import threadpool_info

    from specsynth.run.tasks import BuildContext, close_worker, init_worker

    def blas():
        return {i["filepath"]: i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}

    before = blas()
    g = graph(spec_file)
    ctx = BuildContext(inputs=g.inputs, spec_dir=spec_file.parent, out=tmp_path, threads=2)
    init_worker(ctx)
    try:
        assert blas() and all(n == 1 for n in blas().values())
    finally:
        close_worker(str(tmp_path))
    assert blas() == before


def test_a_torn_record_reruns_its_job_and_the_output_is_whole(spec_file, tmp_path):
    """A record.json cut short (power loss, full disk) used to stop every later build with a bare
    JSONDecodeError; now its job runs again and the dataset comes out as a clean build's."""
    from specsynth.run.store import CorruptRecord, Store

    clean, torn = tmp_path / "clean", tmp_path / "torn"
    build(graph(spec_file), clean, jobs=1)
    build(graph(spec_file), torn, jobs=1)
    store = Store(torn)
    for stage in ("arrange", "render"):
        rec = store.path(stage, sorted(store.keys(stage))[0]) / "record.json"
        rec.write_bytes(rec.read_bytes()[: len(rec.read_bytes()) // 2])
        with pytest.raises(CorruptRecord, match=str(rec)):
            store.load(stage, rec.parent.name)
    again = build(graph(spec_file), torn, jobs=1)
    assert again.stages["arrange"].ran == 1 and not again.failures
    assert tree_digest(torn) == tree_digest(clean)
    assert all(json.loads((store.path(s, k) / "record.json").read_bytes()) for s in ("arrange", "render") for k in store.keys(s))


def _triangles(meshes) -> np.ndarray:
    from specsynth.assets.meshfiles import primitives as procedural
    from specsynth.assets.meshio import read_mesh

    parts = [procedural.transform_mesh(read_mesh(m.mesh_path), m.matrix) for m in meshes]
    return np.concatenate([p.vertices[p.faces] for p in parts]) if parts else np.zeros((0, 3, 3))


def _first_hit(origin: np.ndarray, dirs: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Distance along each unit ray to the nearest triangle, either face (Moller-Trumbore in plain
    numpy: an oracle that shares nothing with the annotator's OpenGL renders); inf on a miss."""
    out = np.full(len(dirs), np.inf)
    if not len(tris):
        return out
    v0, e1, e2 = tris[:, 0], tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    s = origin - v0
    q = np.cross(s, e1)
    for i, d in enumerate(dirs):
        p = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, p)
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / det
            u = np.einsum("ij,ij->i", s, p) * inv
            v = (q @ d) * inv
            t = np.einsum("ij,ij->i", e2, q) * inv
            ok = (np.abs(det) > 1e-12) & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-6)
        if ok.any():
            out[i] = t[ok].min()
    return out


def _in_window(tris, R, t, K, us, vs) -> np.ndarray:
    """The triangles that can be hit through pixels (us, vs): those whose projection overlaps the
    pixels' box, and those crossing the camera plane."""
    z = (tris @ R.T + t)
    front = z[..., 2] > 1e-3
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        p = (z @ K.T)[..., :2] / z[..., 2:3]
        lo, hi = p.min(1), p.max(1)
        overlap = (lo[:, 0] <= us.max() + 1) & (hi[:, 0] >= us.min() - 1) & (lo[:, 1] <= vs.max() + 1) & (hi[:, 1] >= vs.min() - 1)
    return tris[(front.all(1) & overlap) | (front.any(1) & ~front.all(1))]


EVERY_SCENE = builtin_scenes()


@pytest.mark.filterwarnings("ignore::UserWarning")  # library models with missing maps say so
@pytest.mark.parametrize("scene", EVERY_SCENE)
def test_every_accepted_camera_stands_in_free_space(scene, tmp_path):
    """Over arrangements of every built-in scene the code lists: no accepted camera is within 5 cm
    of a wall, a piece of furniture or an object (3 of 48 demo cameras were inside room2's walls,
    with labels that called their objects fully visible), and the labels match the pixels: the
    focused object's visible mask and visible fraction agree with rays cast through the pixels
    against every triangle of the scene."""
    import trimesh.triangles

    from specsynth.annotate.engine import Annotator
    from specsynth.model.records import ArrangementRecord, ViewRecord
    from specsynth.run.store import Store
    from specsynth.run.worker import Optics, World

    W, H = 96, 72
    spec = tmp_path / "s.yaml"
    spec.write_text(SPEC.replace("  - name: room\n", f"  - name: {scene}\n").replace("count: 2", "count: 1" if scene in FIXED_ROOMS else "count: 4").replace("per_arrangement: 3", "per_arrangement: 6" if scene in FIXED_ROOMS else "per_arrangement: 3")
                    .replace("distance: [0.35, 0.7]", "distance: [0.3, 2.0]")
                    .replace("{width: 160, height: 120, fx: 143.1, fy: 143.4, cx: 81.3, cy: 60.5}",
                             f"{{width: {W}, height: {H}, fx: 85.8, fy: 86.1, cx: 48.2, cy: 36.3}}"))
    g = graph(spec)
    delta = g.spec.visibility.delta
    out = tmp_path / "out"
    build(g, out, jobs=1, until="view")
    store = Store(out)
    scenes, optics = World(g.inputs.arrange, spec.parent), Optics(g.inputs.view.intrinsics)
    ann = Annotator(W, H)
    checked = compared = 0
    try:
        arrs = {a.arr: a for a in (ArrangementRecord.from_json(store.load("arrange", k)) for k in store.keys("arrange"))}
        views = [ViewRecord.from_json(store.load("view", k)) for k in store.keys("view")]
        for arr_id, arr in sorted(arrs.items()):
            rs = scenes.render_scene(arr)
            ann.load(rs)
            world = _triangles(rs.meshes)
            objects = {o.inst: _triangles([o]) for o in rs.objects()}
            for v in (v for v in views if v.arr == arr_id and v.accepted):
                R, t = np.asarray(v.R_w2c), np.asarray(v.t_w2c)
                eye = -R.T @ t
                near = world[np.all(world.min(1) <= eye + 0.05, 1) & np.all(world.max(1) >= eye - 0.05, 1)]
                if len(near):
                    closest = trimesh.triangles.closest_point(near, np.repeat(eye[None], len(near), 0))
                    assert np.linalg.norm(closest - eye, axis=1).min() >= 0.05 - 1e-6, (scene, v.cam, eye)
                checked += 1
                # Labels against pixels: a ray through each pixel centre of the focused object's
                # silhouette; visible where the object is hit no more than delta behind the
                # nearest surface (BOP's rule), away from the mask's edges.
                cam = optics.camera(R, t)
                a = ann.annotate(cam, delta)
                k = [o.inst for o in rs.objects()].index(v.focus_inst)
                amodal, visib = a.masks[k], a.masks_visib[k]
                inner = amodal.copy()
                for dy, dx in ((-1, 0), (1, 0), (0, -1), (0, 1)):
                    inner[max(dy, 0):H + min(dy, 0), max(dx, 0):W + min(dx, 0)] &= amodal[max(-dy, 0):H + min(-dy, 0), max(-dx, 0):W + min(-dx, 0)]
                vs, us = np.nonzero(amodal)
                if inner.sum() < 8:
                    continue
                pix = np.stack([us, vs, np.ones_like(us)], 1).astype(float)
                d_cam = pix @ np.linalg.inv(cam.K_array).T  # z = 1 in the camera frame
                dirs = d_cam @ R / np.linalg.norm(d_cam, axis=1, keepdims=True)
                z_of = np.linalg.norm(d_cam, axis=1)  # distance along a ray per metre of depth
                obj_t = _first_hit(eye, dirs, objects[v.focus_inst])
                scene_t = _first_hit(eye, dirs, _in_window(world, R, t, cam.K_array, us, vs))
                hit = np.isfinite(obj_t)
                on = inner[vs, us]
                assert hit[on].all(), (scene, v.cam)  # the silhouette is the object's
                seen = hit & ((obj_t - scene_t) / z_of <= delta)
                agree = (seen == visib[vs, us])[on].mean()
                assert agree >= 0.95, (scene, v.cam, agree)
                assert abs(seen.sum() / hit.sum() - v.focus_visib_fract) <= 0.1, (scene, v.cam, seen.sum() / hit.sum(), v.focus_visib_fract)
                compared += 1
    finally:
        ann.close()
    assert checked >= 4 and compared >= 3, (checked, compared)


def test_outputs_are_copies_and_a_rebuild_restores_edited_ones(spec_file, tmp_path):
    """Outputs used to be hard links into the store: editing one edited the cache, and a rebuild
    did not repair it."""
    from specsynth.run.store import Store

    out = tmp_path / "out"
    build(graph(spec_file), out, jobs=1)
    clean = tree_digest(out)
    rgb = sorted((out / "bop" / "train_pbr" / "000000" / "rgb").iterdir())[0]
    mask = sorted((out / "bop" / "train_pbr" / "000000" / "mask_visib").iterdir())[0]
    assert rgb.stat().st_nlink == 1  # not linked to the store
    store_files = {p: p.read_bytes() for p in Store(out).root.rglob("*.png")}
    rgb.write_bytes(b"edited by hand")
    mask.unlink()
    assert {p: p.read_bytes() for p in Store(out).root.rglob("*.png")} == store_files  # the cache is untouched
    build(graph(spec_file), out, jobs=1)
    assert tree_digest(out) == clean


def tree_state(root: Path) -> dict[str, tuple]:
    """Every entry under root, links not followed: kind, bytes or link target, mode, mtime."""
    state = {}
    for p in sorted(root.rglob("*")):
        st = p.lstat()
        if p.is_symlink():
            what = ("link", os.readlink(p))
        elif p.is_dir():
            what = ("dir",)
        else:
            what = ("file", p.read_bytes())
        state[str(p.relative_to(root))] = (*what, st.st_mode, st.st_mtime_ns)
    return state


@pytest.mark.parametrize("link, to", [
    ("bop", "folder"),
    (".specsynth", "folder"),
    ("bop/train_pbr/000000/rgb", "folder"),
    ("coco/train_pbr.json", "file"),
    ("parquet/images.parquet", "nothing"),  # a dangling link: writing through it would create the file
])
def test_a_link_out_of_the_output_folder_is_refused_and_nothing_outside_changes(spec_file, tmp_path, link, to):
    """The build stops, naming the link, before it writes, deletes or touches anything: in the
    output folder (every entry's bytes, mode and mtime) and outside it."""
    import shutil

    from specsynth.cli import main
    from specsynth.run.build import UnsafeOutput

    out = tmp_path / "out"
    build(graph(spec_file), out, jobs=1)
    outside = tmp_path / "precious"
    outside.mkdir()
    (outside / "000000.png").write_bytes(b"keep me")
    (outside / "keep.txt").write_text("keep me")
    target = out / link
    if target.is_dir():
        shutil.rmtree(target)
    else:
        target.unlink()
    where = {"folder": outside, "file": outside / "keep.txt", "nothing": outside / "images.parquet"}[to]
    target.symlink_to(where)
    assert target.is_symlink() and target.exists() == (to != "nothing")
    before_out, before = tree_state(out), tree_state(outside)
    with pytest.raises(UnsafeOutput, match=f"^{re.escape(str(target))}: a symbolic link out of the output folder"):
        build(graph(spec_file), out, jobs=1)
    assert main(["build", str(spec_file), "--out", str(out), "--quiet"]) == 2
    assert tree_state(outside) == before and not (outside / "images.parquet").exists()
    assert tree_state(out) == before_out  # nothing written, deleted or touched before the refusal


def test_diff_verifies_files_against_what_each_build_recorded(spec_file, tmp_path, capsys):
    """`specsynth diff A B` compared manifests only: an output edited or deleted after its build
    went unnoticed."""
    from specsynth.cli import main

    a, b = tmp_path / "a", tmp_path / "b"
    build(graph(spec_file), a, jobs=1)
    build(graph(spec_file), b, jobs=1)
    assert main(["diff", str(a), str(b)]) == 0 and "no change" in capsys.readouterr().out
    rgb = sorted((b / "bop" / "train_pbr" / "000000" / "rgb").iterdir())[0]
    rgb.write_bytes(rgb.read_bytes()[:-10] + b"0123456789")  # same size, other bytes
    (a / "coco" / "train_pbr.json").unlink()
    assert main(["diff", str(a), str(b), "--json"]) == 0
    d = json.loads(capsys.readouterr().out)
    rel = rgb.relative_to(b).as_posix()
    assert not d["identical"]
    assert d["files"]["b_since_built"]["changed"] == [rel] and d["files"]["a_since_built"]["missing"] == ["coco/train_pbr.json"]
    assert d["files"]["differ"] == [] and d["files"]["recorded"]  # the records themselves agree


def test_a_full_disk_names_the_file_and_keeps_finished_jobs(spec_file, tmp_path, monkeypatch):
    """ENOSPC used to surface as a bare `[Errno 28]`: now it names the file, the bytes needed and
    free, nothing finished is lost, and the next build completes the dataset as a clean one."""
    import errno

    from specsynth import atomic

    clean, out = tmp_path / "clean", tmp_path / "out"
    build(graph(spec_file), clean, jobs=1)
    build(graph(spec_file), out, jobs=1, until="view")  # arrangements and cameras are done
    done = sorted(Store_keys(out, "arrange"))
    real = atomic.os.fdopen

    attempts: list[tuple[Path, int]] = []  # (the file being written, its bytes)

    class Full:
        def __init__(self, f):
            self.f = f

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.f.close()

        def write(self, data):
            tmp = Path(os.readlink(f"/proc/self/fd/{self.f.fileno()}"))  # ".<name>.<id>.tmp" beside <name>
            attempts.append((tmp.parent / tmp.name[1:].rsplit(".", 2)[0], len(data)))
            raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(atomic.os, "fdopen", lambda fd, mode="r": Full(real(fd, mode)))
    with pytest.raises(OSError, match=r"no space left on the device of (\S+): writing ([\d,]+) bytes, ([\d,]+) bytes free") as e:
        build(graph(spec_file), out, jobs=1)
    m = re.search(r"of (\S+): writing ([\d,]+) bytes, ([\d,]+) bytes free", str(e.value))
    named, needed, free = Path(m[1]), int(m[2].replace(",", "")), int(m[3].replace(",", ""))
    assert attempts and (named, needed) == attempts[-1]  # the write that stopped the build: its file and size
    assert out.resolve() in named.resolve().parents and needed > 0 and free > 0
    assert sorted(Store_keys(out, "arrange")) == done  # nothing finished was lost
    monkeypatch.setattr(atomic.os, "fdopen", real)
    again = build(graph(spec_file), out, jobs=1)
    assert not again.failures and tree_digest(out) == tree_digest(clean)


def Store_keys(out, stage):
    from specsynth.run.store import Store

    return Store(out).keys(stage)


@pytest.mark.parametrize("cmd, victim", [
    ("view", "bop/train_pbr/000000/scene_gt.json"),
    ("view", "bop/train_pbr/000000/rgb/000000.png"),
    ("stats", "parquet/instances.parquet"),
    ("diff", ".specsynth/manifest.json"),
])
def test_reading_commands_name_a_corrupt_file(spec_file, tmp_path, capsys, cmd, victim):
    """view/stats/diff on a corrupt JSON, image or Parquet file said only what broke, not where."""
    from specsynth.cli import main

    out = tmp_path / "out"
    build(graph(spec_file), out, jobs=1)
    secret = b"root:x:0:0:supersecret"
    (out / victim).write_bytes(secret + b"\x00\xff" * 8)
    args = {"view": ["view", str(out), "--out", str(tmp_path / "s.png")],
            "stats": ["stats", str(out), "--out", str(tmp_path / "st")],
            "diff": ["diff", str(out), str(out)]}[cmd]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert str(out / victim) in err and "supersecret" not in err


def test_a_mesh_with_out_of_range_faces_is_named(tmp_path):
    from specsynth.assets.meshio import MeshData
    from specsynth.assets.resolve import AssetError, finish_mesh

    bad = MeshData(vertices=np.zeros((3, 3), np.float32), faces=np.array([[0, 1, 7]], np.int32))
    with pytest.raises(AssetError, match=r"broken.ply: face indices out of range \(0..2, found 0..7\)"):
        finish_mesh(bad, "broken.ply")


@pytest.mark.slow
def test_photo_baseline_bytes_do_not_depend_on_load_or_workers(tmp_path):
    """Two clean builds of the demo baseline (HDRI and photo backgrounds, augmentation): one with
    two workers, one with one worker while two processes burn both cores. Every file identical
    (1-3 JPEGs of 200 once differed between clean builds: numpy's float32 arctan2 in the HDRI
    background, see test_photo_backend.py::test_pano_background_does_not_depend_on_the_heap)."""
    demo_bl = Path(__file__).resolve().parents[1] / "specs" / "demo_bl.yaml"
    over = ["arrangements.count=6", "intrinsics={width: 320, height: 240, fx: 286.2, fy: 286.8, cx: 162.6, cy: 121.0}"]
    a = build(compile_spec(load_spec(demo_bl, over)), tmp_path / "a", jobs=2)
    burners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    try:
        b = build(compile_spec(load_spec(demo_bl, over)), tmp_path / "b", jobs=1)
    finally:
        for p in burners:
            p.kill()
    assert not a.failures and not b.failures and a.images == b.images > 10
    da, db = tree_digest(tmp_path / "a"), tree_digest(tmp_path / "b")
    assert da.keys() == db.keys()
    assert [k for k in da if da[k] != db[k]] == []


def test_accepted_cameras_keep_an_open_view_when_near_share_is_set(tmp_path):
    """With visibility.near_share 0.1, no accepted camera has more than a tenth of its image nearer
    than 0.8 of its distance to the target (counted by rays through the pixel centres of the 1/8
    image, cast against every triangle of the scene); without the check, the same seed accepts
    views with the floor nearer than that over a fifth of the image or more."""
    from specsynth.model.records import ArrangementRecord, ViewRecord
    from specsynth.run.store import Store
    from specsynth.run.worker import World

    W, H, step, near = 96, 72, 8, 0.8

    def shares(near_share: float) -> list[float]:
        spec = tmp_path / f"s{near_share}.yaml"
        spec.write_text(SPEC.replace("count: 2", "count: 3").replace("per_arrangement: 3", "per_arrangement: 4")
                        .replace("{width: 160, height: 120, fx: 143.1, fy: 143.4, cx: 81.3, cy: 60.5}",
                                 f"{{width: {W}, height: {H}, fx: 85.8, fy: 86.1, cx: 48.2, cy: 36.3}}")
                        + f"visibility: {{near_share: {near_share}, near_distance: {near}}}\n")
        g = graph(spec)
        out = tmp_path / f"out{near_share}"
        build(g, out, jobs=1, until="view")
        store, world = Store(out), World(g.inputs.arrange, spec.parent)
        arrs = {a.arr: a for a in (ArrangementRecord.from_json(store.load("arrange", k)) for k in store.keys("arrange"))}
        us, vs = np.meshgrid((np.arange(W // step) + 0.5) * step - 0.5, (np.arange(H // step) + 0.5) * step - 0.5)
        pix = np.stack([us.ravel(), vs.ravel(), np.ones(us.size)], 1)
        K = np.array([[85.8, 0, 48.2], [0, 86.1, 36.3], [0, 0, 1]])
        found = []
        for v in (ViewRecord.from_json(store.load("view", k)) for k in store.keys("view")):
            if not v.accepted:
                continue
            R, t = np.asarray(v.R_w2c), np.asarray(v.t_w2c)
            tris = _triangles(world.render_scene(arrs[v.arr]).meshes)
            d_cam = pix @ np.linalg.inv(K).T
            dirs = d_cam @ R / np.linalg.norm(d_cam, axis=1, keepdims=True)
            z = _first_hit(-R.T @ t, dirs, tris) / np.linalg.norm(d_cam, axis=1)
            found.append(float(np.mean(z < near * v.distance)))
        return found

    open_views = shares(0.1)
    assert len(open_views) >= 6 and max(open_views) <= 0.1 + 1.5 / 108, open_views
    assert max(shares(1.0)) >= 0.2


def test_a_backgrounds_folder_under_home_is_fingerprinted_by_its_photos(tmp_path, monkeypatch):
    """backend.backgrounds: ~/photos is the folder render jobs read; a photo changed there changes
    the render stage's inputs (its listing had been taken of a folder named '~' beside the spec,
    missing, so a changed photo rebuilt nothing)."""
    from PIL import Image

    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    photos = tmp_path / "home" / "photos"
    photos.mkdir(parents=True)
    Image.new("RGB", (64, 48), (10, 200, 30)).save(photos / "green.png")
    f = tmp_path / "t.yaml"
    f.write_text(SPEC.replace("  name: photo\n", "  name: photo\n  backgrounds: ~/photos\n"))

    def listing():
        inputs = compile_spec(load_spec(f)).stage_inputs["render"]
        return next(v for k, v in inputs.items() if k == "folder:~/photos")

    before = listing()
    assert not before.startswith("missing:")
    Image.new("RGB", (64, 50), (200, 10, 30)).save(photos / "green.png")
    assert listing() != before
