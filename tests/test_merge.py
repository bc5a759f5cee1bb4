"""The merge (``specsynth.run.merge``): it reuses what the workers reported (records, resolved
models) and resolves again only what it was not given."""

from __future__ import annotations

from pathlib import Path

import pytest
from test_build import tree_digest

from specsynth.assets.resolve import resolve_objects
from specsynth.run import merge
from specsynth.plan.compiler import compile_spec
from specsynth.run.build import build
from specsynth.spec.yamlio import load_spec

SPEC = """\
name: merge
seed: 9
intrinsics: {width: 64, height: 48, fx: 57.2, fy: 57.4, cx: 32.5, cy: 24.2}
objects:
  builtin: [duck, mug]
scenes:
  - name: room
arrangements:
  count: 2
  distractors: {count: [1, 1], objects: [teddy], annotate: true}
cameras:
  per_arrangement: 2
  distance: [0.35, 0.7]
backend:
  name: photo
  backgrounds: builtin
outputs: {image_format: png}
"""


@pytest.fixture()
def spec_file(tmp_path) -> Path:
    f = tmp_path / "merge.yaml"
    f.write_text(SPEC)
    return f


def test_the_merge_uses_the_models_the_workers_resolved(spec_file, tmp_path, monkeypatch):
    """A clean build resolves no model in the main process (its arrange jobs reported them, the
    annotated distractor among them); a rebuild that ran no arrange job resolves them itself.
    Both write the same dataset."""
    calls = []

    def counted(objects, spec_dir, cache=None):
        calls.append(sorted(objects.builtin))
        return resolve_objects(objects, spec_dir, cache)

    monkeypatch.setattr(merge, "resolve_objects", counted)
    graph = compile_spec(load_spec(spec_file))
    s = build(graph, tmp_path / "out", jobs=1)
    assert not s.failures and s.images and calls == []
    assert s.merge_phases.keys() >= {"collect", "models", "write", "index"}
    first = tree_digest(tmp_path / "out")
    assert any("obj_000003" in k for k in first)  # the annotated distractor's model
    s = build(graph, tmp_path / "out", jobs=1)
    assert s.stages["arrange"].cached == 2 and calls == [["duck", "mug"], ["teddy"]]
    assert tree_digest(tmp_path / "out") == first
