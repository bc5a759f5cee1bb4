"""Swapping the backend is a one-line change that keeps cameras, poses and masks identical."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest

from specsynth.plan.compiler import compile_spec
from specsynth.run.build import build
from specsynth.spec.yamlio import load_spec

SPEC = """\
name: swap
seed: 5
intrinsics: {width: 96, height: 72, fx: 86.0, fy: 86.2, cx: 47.3, cy: 35.6}
objects:
  builtin: [duck, mug, jenga]
scenes:
  - name: room
arrangements:
  count: 1
cameras:
  per_arrangement: 2
  distance: [0.35, 0.6]
quality:
  level: low
backend:
  name: cycles
outputs:
  image_format: png
  depth_scale: 0.25
"""


def _files(out: Path, pattern: str) -> dict[str, str]:
    return {str(p.relative_to(out)): hashlib.sha256(p.read_bytes()).hexdigest() for p in sorted(out.glob(pattern))}


@pytest.mark.slow
@pytest.mark.parametrize("other", ["{name: mitsuba}", "{name: photo}"])
def test_swapping_backend_keeps_annotations(tmp_path, other):
    f = tmp_path / "swap.yaml"
    f.write_text(SPEC)
    a = build(compile_spec(load_spec(f)), tmp_path / "cycles", jobs=1)
    b = build(compile_spec(load_spec(f, [f"backend={other}"])), tmp_path / "other", jobs=1)
    assert not a.failures and not b.failures, (a.failures, b.failures)
    assert a.images == b.images > 0
    chunk = "bop/train_pbr/000000"
    for name in ("scene_gt.json", "scene_camera.json"):
        assert (tmp_path / "cycles" / chunk / name).read_bytes() == (tmp_path / "other" / chunk / name).read_bytes()
    if "mitsuba" in other:  # both draw the full scene: same occluders, same masks and gt_info
        for pattern in (f"{chunk}/mask/*.png", f"{chunk}/mask_visib/*.png", f"{chunk}/depth/*.png", f"{chunk}/scene_gt_info.json"):
            assert _files(tmp_path / "cycles", pattern) == _files(tmp_path / "other", pattern), pattern
    rgb_a = _files(tmp_path / "cycles", f"{chunk}/rgb/*.png")
    rgb_b = _files(tmp_path / "other", f"{chunk}/rgb/*.png")
    assert rgb_a.keys() == rgb_b.keys() and rgb_a != rgb_b  # same images, different renderer


DEMO = Path(__file__).resolve().parents[1] / "specs" / "demo.yaml"
TINY = ["arrangements.count=1", "cameras.per_arrangement=1",
        "intrinsics={width: 96, height: 72, fx: 86.0, fy: 86.0, cx: 47.5, cy: 35.5}"]


@pytest.mark.slow
@pytest.mark.parametrize("name", ["cycles", "mitsuba", "photo"])
def test_demo_spec_renders_with_each_backend_by_one_line(tmp_path, name):
    """specs/demo.yaml (cycles, denoise: true) with only ``--set backend.name=X``."""
    loaded = load_spec(DEMO, [f"backend.name={name}", *TINY])
    assert loaded.spec.backend.denoise is True
    s = build(compile_spec(loaded), tmp_path / name, jobs=1)
    assert not s.failures, s.failures
    assert s.images == 1 and s.instances > 0
    rgb = next((tmp_path / name / "bop" / "train_pbr" / "000000" / "rgb").glob("*.png"))
    import numpy as np
    from PIL import Image

    assert np.asarray(Image.open(rgb)).std() > 5
    assert set(s.render_phases) >= {"load", "annotate", "encode", "write"}
    if name != "photo":
        assert any(k.startswith("render.") and k != "render.other" for k in s.render_phases)
