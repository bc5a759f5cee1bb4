"""Stage inputs (``specsynth.plan.inputs``): every spec field is read by a stage or written only,
and an incremental rebuild after any edit equals a clean build of the edited spec, file for file."""

from __future__ import annotations

import hashlib
import inspect
import shutil
from pathlib import Path

import pytest
from hypothesis import HealthCheck, Phase, given, settings
from hypothesis import strategies as st
from pydantic import ValidationError, create_model

from specsynth.plan.compiler import compile_spec, stage_of_field
from specsynth.plan.inputs import PLANNED, STAGE_INPUTS, WRITTEN_ONLY, BuildInputs, unread_fields
from specsynth.run.build import build
from specsynth.run.verify import TIMINGS, output_files
from specsynth.run.worker import BuildContext
from specsynth.spec.models import DatasetSpec
from specsynth.spec.yamlio import load_spec

SPEC = """\
name: edits
seed: 5
intrinsics: {width: 64, height: 48, fx: 57.2, fy: 57.4, cx: 32.5, cy: 24.2}
objects:
  builtin: [duck, mug]
scenes:
  - name: room
arrangements:
  count: 1
cameras:
  per_arrangement: 2
  distance: [0.35, 0.7]
backend:
  name: photo
  backgrounds: builtin
outputs:
  image_format: png
"""


# ---------------------------------------------------------------------- every field accounted for


def test_every_spec_field_is_read_by_a_stage_or_by_no_job():
    assert unread_fields() == []
    taken = {path for m in STAGE_INPUTS.values() for _, path in m.spec_paths()}
    for path in [*WRITTEN_ONLY, *PLANNED]:  # a field no job reads is no stage's input, and exists
        assert not any(path == t or path.startswith(t + ".") or t.startswith(path + ".") for t in taken), path
        model = DatasetSpec
        for part in path.split("."):
            assert part in model.model_fields, path
            model = model.model_fields[part].annotation


def test_a_new_spec_field_is_not_missed():
    grown = create_model("Grown", __base__=DatasetSpec, exposure_lock=(bool, False))
    assert unread_fields(grown) == ["exposure_lock"]


def test_the_stage_a_field_re_runs_comes_from_the_inputs():
    assert stage_of_field("seed") == "arrange"
    assert stage_of_field("arrangements.physics.friction") == "arrange"
    assert stage_of_field("cameras.max_tries") == "view"
    assert stage_of_field("visibility.delta") == "view"  # read by both: the first re-runs the rest
    assert stage_of_field("sensor.depth.dropout") == "render"
    assert stage_of_field("outputs.normals") == "render"
    assert stage_of_field("outputs.coco") is None
    assert stage_of_field("arrangements.count") is None
    assert stage_of_field("cameras.stereo") == "render"  # the view draws cameras, not their optics
    assert stage_of_field("metadata.license.url") is None
    assert stage_of_field("objects.instances") == "arrange"
    assert stage_of_field("objects.materials.duck.color_gain") == "render"  # a dressing: nothing settles again


def test_a_material_edit_renders_again_and_keeps_the_arrangements_and_cameras(tmp_path):
    """Materials are the renders' inputs: a baseline or a refitted colour gain shares the PBR
    spec's arrangement and camera jobs, and the arrange jobs resolve each model in its own look."""
    f = tmp_path / "s.yaml"
    f.write_text(SPEC)
    plain = compile_spec(load_spec(f, []))
    dressed = compile_spec(load_spec(f, ["objects.materials={duck: {color_gain: [2, 1, 1]}, default: {roughness: 0.2}}"]))
    assert dressed.stage_digests["arrange"] == plain.stage_digests["arrange"]
    assert dressed.stage_digests["view"] == plain.stage_digests["view"]
    assert dressed.stage_digests["render"] != plain.stage_digests["render"]
    assert "materials" not in type(dressed.inputs.arrange.objects).model_fields
    assert dressed.inputs.render.materials["duck"].color_gain == (2.0, 1.0, 1.0)


def test_workers_get_the_inputs_not_the_spec(tmp_path):
    f = tmp_path / "s.yaml"
    f.write_text(SPEC)
    spec = load_spec(f, []).spec
    inputs = BuildInputs.of(spec)
    assert "spec" not in BuildContext.__dataclass_fields__
    assert inputs.render.outputs.image_format == "png" and not hasattr(inputs.render.outputs, "coco")
    assert inputs.render.backend.backgrounds == "builtin"  # the plugin's own options, not the base model's
    assert "backgrounds" in inputs.render.model_dump(mode="json")["backend"]
    with pytest.raises(ValidationError):
        inputs.view.intrinsics = spec.intrinsics  # frozen
    from specsynth.run import arrange, render, tasks, views, worker

    for module in (arrange, views, render, worker, tasks):  # the steps are given no way to the spec
        assert "DatasetSpec" not in inspect.getsource(module), module.__name__


def test_a_field_no_job_reads_changes_no_key(tmp_path):
    f = tmp_path / "s.yaml"
    f.write_text(SPEC)
    edits = ["name=other", "split=val_pbr", "metadata.contributor=someone", "outputs.coco=false",
             "outputs.chunk_size=3", "arrangements.count=4"]
    assert compile_spec(load_spec(f, edits)).stage_digests == compile_spec(load_spec(f, [])).stage_digests


def test_more_arrangements_re_run_none_of_the_first(tmp_path):
    f = tmp_path / "s.yaml"
    f.write_text(SPEC)
    one, three = (compile_spec(load_spec(f, [f"arrangements.count={n}"])) for n in (1, 3))
    assert list(one.jobs()) == list(three.jobs())[: len(list(one.jobs()))]


# ---------------------------------------------------------------------- incremental == clean

# (the --set path a user would type, the values an edit sets it to). Each stage's inputs are edited
# by several kinds, and written-only fields by a few.
EDITS = {
    # arrange
    "seed": [11, 2**40 - 3],
    "objects.builtin": ["[duck]", "[mug, duck]", "[duck, jenga]"],
    "objects.instances": ["[1, 2]", "[2, 2]"],
    "objects.orientation": ["random"],
    "objects.models_per_arrangement": ["[1, 1]"],
    "objects.materials": ["{default: {roughness: 0.9}}", "{duck: {color: [0.1, 0.8, 0.2]}}"],
    "arrangements.count": [2],
    "arrangements.drop_height": ["[0.1, 0.2]", "[0.0, 0.05]"],
    "arrangements.physics.friction": [0.2, 1.5],
    "arrangements.distractors": ["{count: [1, 2]}", "{count: [1, 1], annotate: true}"],
    "scenes.0.randomize.roughness": [0.3],
    # view
    "cameras.per_arrangement": [1, 3],
    "cameras.azimuth": ["[0, 90]", "[180, 270]"],
    "cameras.elevation": ["[30, 40]", "[60, 80]"],
    "cameras.elevation_sampling": ["area"],
    "cameras.distance": ["[0.5, 0.6]", "[0.3, 0.4]"],
    "cameras.inplane": ["[-20, 20]"],
    "cameras.max_tries": [1, 3],
    "cameras.clearance": [0.2],
    "visibility.threshold": [0.05, 0.6],
    "visibility.delta": [0.02],
    "intrinsics": ["{width: 64, height: 48, fx: 40.0, fy: 40.0, cx: 32.0, cy: 24.0}",
                   "{width: 48, height: 32, fx: 43.0, fy: 43.0, cx: 24.0, cy: 16.0}"],
    "intrinsics.clip": ["[0.2, 50.0]"],
    "intrinsics.distortion": ["[-0.1, 0.02, 0.0, 0.0, 0.0]"],
    # render
    "cameras.stereo": ["{baseline: 0.05}"],
    "quality.level": ["medium", "high"],
    "backend.lights": ["[0, 0]", "[2, 2]"],
    "backend.ambient": ["[0.5, 0.6]"],
    "backend.augment.brightness": [0.3],
    "sensor.shot_noise": [0.05],
    "sensor.exposure": ["[-1.0, 1.0]"],
    "sensor.white_balance": ["[4000, 7000]"],
    "sensor.depth": ["{dropout: 0.1}"],
    "outputs.image_format": ["jpg"],
    "outputs.depth": ["false"],
    "outputs.depth_scale": ["1.0", "auto"],
    "outputs.masks": ["false"],
    "outputs.normals": ["true"],
    "outputs.nocs": ["true"],
    "outputs.albedo": ["true"],
    # written only
    "name": ["renamed"],
    "split": ["val_pbr"],
    "metadata.contributor": ["someone"],
    "outputs.chunk_size": [1],
    "outputs.coco": ["false"],
    "outputs.bop": ["false"],
    "outputs.parquet": ["false"],
}


def _set(path: str, value) -> str:
    return f"{path}={value}"


def test_the_edits_reach_every_stage():
    stages = {stage_of_field(path.replace(".0.", ".")) for path in EDITS}
    assert {"arrange", "view", "render", None} <= stages and len(EDITS) >= 30


def _files(out: Path) -> dict[str, str]:
    """sha256 of every dataset file but for the render seconds (the files any two builds differ
    in, which ``specsynth diff`` skips too), and of the manifest (every job's key)."""
    files = [p for p in output_files(out) if p.name not in TIMINGS] + [out / ".specsynth" / "manifest.json"]
    return {p.relative_to(out).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest() for p in files}


def _build(spec_file: Path, out: Path, sets: list[str]) -> None:
    summary = build(compile_spec(load_spec(spec_file, sets)), out, jobs=1)
    assert not summary.failures, summary.failures


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> tuple[Path, Path]:
    d = tmp_path_factory.mktemp("edits")
    f = d / "edits.yaml"
    f.write_text(SPEC)
    _build(f, d / "base", [])
    return f, d / "base"


def _incremental_equals_clean(base: tuple[Path, Path], sets: list[str], work: Path) -> None:
    spec_file, built = base
    if work.exists():
        shutil.rmtree(work)
    shutil.copytree(built, work / "incremental")
    _build(spec_file, work / "incremental", sets)
    _build(spec_file, work / "clean", sets)
    assert _files(work / "incremental") == _files(work / "clean"), sets


# One to three edits at once, of any kinds: an edit's effect must not depend on another's.
some_edits = st.lists(st.sampled_from(sorted(EDITS)), min_size=1, max_size=3, unique=True).flatmap(
    lambda paths: st.tuples(*(st.sampled_from(EDITS[p]).map(lambda v, p=p: _set(p, v)) for p in paths)))


# No shrinking: each example is two builds, and the failing edits are few enough to read as drawn.
@settings(max_examples=25, deadline=None, phases=[Phase.explicit, Phase.reuse, Phase.generate],
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(edits=some_edits)
def test_an_incremental_rebuild_equals_a_clean_build(base, tmp_path, edits):
    _incremental_equals_clean(base, list(edits), tmp_path / "work")


@pytest.mark.slow
@pytest.mark.parametrize("edit", [_set(p, v) for p, values in sorted(EDITS.items()) for v in values])
def test_every_edit_rebuilds_like_a_clean_build(base, tmp_path, edit):
    _incremental_equals_clean(base, [edit], tmp_path / "work")
