"""The worker's steps (``specsynth.run.tasks.Steps``): each built from its own stage's inputs and
the backend plugin's capabilities, read once when it is built; nothing depends on which step of a
process ran first; what a step reports is what it stored."""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import pytest

from specsynth.model.records import ArrangementRecord
from specsynth.plan.compiler import compile_spec
from specsynth.run.build import build
from specsynth.run.reports import Arranged, Rendered, Viewed
from specsynth.run.store import Store
from specsynth.run.tasks import Steps
from specsynth.run.worker import BuildContext, Held
from specsynth.spec.yamlio import load_spec

SPEC = """\
name: steps
seed: 4
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
sensor: {auto_white_balance: true}
outputs: {image_format: png, albedo: true}
"""


@pytest.fixture(scope="module")
def viewed(tmp_path_factory) -> tuple[Path, object]:
    """A build stopped after its views: arrangement and view records in the store, no render."""
    d = tmp_path_factory.mktemp("steps")
    (d / "s.yaml").write_text(SPEC)
    graph = compile_spec(load_spec(d / "s.yaml"))
    build(graph, d / "out", jobs=1, until="view")
    return d, graph


def _steps(graph, out: Path) -> Steps:
    return Steps(BuildContext(inputs=graph.inputs, spec_dir=graph.spec_path.parent, out=out))


def test_a_render_step_reads_what_its_backend_draws_when_built(viewed):
    """The photo baseline draws the objects only: the render step knows it before its backend
    exists, so what occludes the objects and what the albedo shows never wait on a first render."""
    d, graph = viewed
    steps = _steps(graph, d / "out")
    try:
        setup = steps.render.setup
        assert setup.draws_scene is False and setup.occluders == "objects"
        arr = ArrangementRecord.from_json(steps.store.load("arrange", graph.arrange_job(0).key))
        scene = steps.world.frame(arr).scene
        assert setup.drawn(scene).meshes == scene.objects_only().meshes
        assert steps.render.backend.held is None  # nothing made or loaded yet
    finally:
        steps.close()


def _render_files(out: Path) -> dict[str, str]:
    root = out / ".specsynth" / "store" / "render"
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file() and p.name != "record.json"}


def test_renders_do_not_depend_on_which_step_ran_first_in_the_process(viewed, tmp_path):
    """The same renders in two fresh processes' steps: one renders first, the other has its view
    step load the arrangement into the shared annotator first. The files are the same bytes."""
    d, graph = viewed
    a, views, renders = graph.arrangement_jobs(0)
    pairs = list(zip(views, renders))
    outs = []
    for order, name in (("render first", "a"), ("views first", "b")):
        out = tmp_path / name
        shutil.copytree(d / "out", out)
        steps = _steps(graph, out)
        try:
            if order == "views first":
                assert steps.views.run(a.key, views) == []  # every view is stored: it only loads the arrangement
            done = steps.render.run(a.key, pairs)
        finally:
            steps.close()
        assert done and all(isinstance(r, Rendered) for r in done)
        outs.append(_render_files(out))
    assert outs[0] == outs[1] and any(k.endswith("albedo.png") for k in outs[0])


def test_each_report_carries_the_record_as_stored(tmp_path):
    (tmp_path / "s.yaml").write_text(SPEC)
    graph = compile_spec(load_spec(tmp_path / "s.yaml"))
    a, views, renders = graph.arrangement_jobs(0)
    steps = _steps(graph, tmp_path / "out")
    store = Store(tmp_path / "out")
    try:
        arranged = steps.arrange.run(a)
        assert isinstance(arranged, Arranged) and arranged.record == store.load("arrange", a.key)
        assert {m.name for m in arranged.models} == {"duck", "mug"} and arranged.distractors == ()
        assert steps.arrange.run(a) == Arranged(a.id, a.key, cached=True)
        viewed = steps.views.run(a.key, views)
        assert all(isinstance(v, Viewed) and v.record == store.load("view", j.key) for v, j in zip(viewed, views))
        accepted = [(v, r) for v, r, rep in zip(views, renders, viewed) if rep.accepted]
        rendered = steps.render.run(a.key, accepted)
        assert [r.record for r in rendered] == [store.load("render", r.key) for _, r in accepted]
    finally:
        steps.close()


def test_a_held_renderer_loads_an_arrangement_once_and_forgets_a_failed_load():
    loads = []

    class Renderer:
        def load(self, scene):
            loads.append(scene)
            if scene == "broken":
                raise RuntimeError("load failed")

        def close(self):
            loads.append("closed")

    held = Held(Renderer)
    held.load("k1", "scene 1")
    held.load("k1", "scene 1")
    assert loads == ["scene 1"] and held.held == "k1"
    with pytest.raises(RuntimeError):
        held.load("k2", "broken")
    assert held.held is None  # a load that raised leaves nothing marked as loaded
    held.load("k1", "scene 1")
    held.close()
    assert loads == ["scene 1", "broken", "scene 1", "closed"] and held.held is None
