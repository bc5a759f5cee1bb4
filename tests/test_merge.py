"""The merge (``specsynth.run.merge``): it reuses what the workers reported (records, resolved
models) and resolves again only what it was not given; it writes the new dataset aside and swaps
it in (``specsynth.run.staging``), so a merge that fails or is killed, anywhere, leaves the last
dataset whole and the next build completes the new one."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_build import tree_digest

from specsynth.assets.resolve import resolve_objects
from specsynth.atomic import atomic_write_bytes
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


def _dataset(out: Path) -> dict[str, bytes]:
    return {p.relative_to(out).as_posix(): p.read_bytes() for p in sorted(out.rglob("*"))
            if p.is_file() and p.relative_to(out).parts[0] != ".specsynth"}


def test_a_merge_that_raises_leaves_the_last_dataset_and_the_next_build_completes_it(spec_file, tmp_path, monkeypatch):
    """A writer fails after others have written (a full disk, say): the rebuild raises, the last
    dataset is still in place byte for byte and marked complete, and the next build completes
    the new one as a clean build writes it."""
    from specsynth.outputs import parquet

    out = tmp_path / "out"
    build(compile_spec(load_spec(spec_file)), out, jobs=1)
    last = _dataset(out)
    reseeded = compile_spec(load_spec(spec_file, ["seed=10"]))
    real = parquet.write_if_changed

    def disk_full(path, data):
        raise OSError(28, "No space left on device", str(path))

    monkeypatch.setattr(parquet, "write_if_changed", disk_full)
    with pytest.raises(OSError):
        build(reseeded, out, jobs=1)
    assert _dataset(out) == last and (out / ".specsynth" / "complete.json").is_file()
    monkeypatch.setattr(parquet, "write_if_changed", real)
    build(reseeded, out, jobs=1)
    build(reseeded, tmp_path / "clean", jobs=1)
    assert tree_digest(out) == tree_digest(tmp_path / "clean") and _dataset(out) != last


def test_what_a_user_put_in_the_dataset_survives_the_swap(spec_file, tmp_path, monkeypatch):
    """Files and links of the user's in the dataset's folders are kept (the new dataset is made
    of links to the last one's files); without an atomic exchange (another filesystem), the
    swap takes the old folder out and puts the new one in."""
    from specsynth.run import staging

    out = tmp_path / "out"
    build(compile_spec(load_spec(spec_file)), out, jobs=1)
    (out / "bop" / "NOTES.txt").write_text("mine")
    (out / "mine").mkdir()
    (out / "mine" / "x.txt").write_text("also mine")
    (out / "latest").symlink_to("bop/train_pbr")
    monkeypatch.setattr(staging, "_exchange", lambda a, b: False)
    build(compile_spec(load_spec(spec_file, ["seed=10"])), out, jobs=1)
    assert (out / "bop" / "NOTES.txt").read_text() == "mine" and (out / "mine" / "x.txt").read_text() == "also mine"
    assert os.readlink(out / "latest") == "bop/train_pbr" and (out / "latest" / "000000").is_dir()
    assert not (out / ".specsynth" / "staging").exists()


def test_a_link_that_would_point_out_of_the_folder_from_the_staging_folder_is_refused(tmp_path):
    """A relative link is copied into the staging folder as it is: one that climbs to the root
    and back down to the dataset's file from ``out`` would, from three folders deeper, climb
    only part of the way and point elsewhere. It is refused, and nothing is followed."""
    from specsynth.files import UnsafeOutput
    from specsynth.run.staging import Staging

    out = (tmp_path / "out").resolve()
    out.mkdir()
    (out / "a.txt").write_text("a")
    depth = len(out.parts) - 1  # folders from / to out: climbing that many from out reaches /
    (out / "up").symlink_to("../" * depth + (out / "a.txt").as_posix().lstrip("/"))
    assert (out / "up").read_text() == "a"
    with pytest.raises(UnsafeOutput, match="point out of the output folder"):
        Staging(out).begin()
    assert (out / "up").read_text() == "a"


# ---------------------------------------------------------------------- the swap, killed anywhere

NAMES = ("ATTRIBUTION.md", "bop", "coco", "parquet", "specsynth.lock")
_files = st.dictionaries(st.sampled_from(("a.png", "b.json", "c.txt")), st.binary(max_size=3), max_size=3)
_dataset_trees = st.dictionaries(st.sampled_from(NAMES), st.one_of(st.binary(max_size=3), _files), max_size=5)


class Killed(BaseException):
    """The process dying at this point (not an error any code under test handles)."""


def _write_tree(root: Path, tree: dict) -> None:
    for name, entry in tree.items():
        if isinstance(entry, bytes):
            atomic_write_bytes(root / name, entry)
        else:
            (root / name).mkdir(exist_ok=True)
            _write_tree(root / name, entry)


def _read_tree(root: Path) -> dict:
    return {p.name: p.read_bytes() if p.is_file() else _read_tree(p)
            for p in root.iterdir() if p.name != ".specsynth"}


def _make_like(root: Path, tree: dict) -> None:
    """``root``'s entries brought to ``tree`` as the writers do: stale ones removed, every file
    put in place by a new file renamed over it."""
    for p in list(root.iterdir()):
        if p.name == ".specsynth":
            continue
        want = tree.get(p.name)
        if (want is None or isinstance(want, bytes) != p.is_file()) and p.is_dir():
            shutil.rmtree(p)
        elif want is None or isinstance(want, bytes) != p.is_file():
            p.unlink()
        elif not isinstance(want, bytes):
            _make_like(p, want)
    _write_tree(root, tree)


def _dies_at(k: int):
    """A context in which the k-th (0-based) rename, exchange or removal kills the process."""
    from specsynth.run import staging

    steps = {"n": 0}

    def dying(real):
        def call(*args, **kwargs):
            steps["n"] += 1
            if steps["n"] > k:
                raise Killed
            return real(*args, **kwargs)
        return call

    mp = pytest.MonkeyPatch()
    for name in ("rename", "replace", "unlink", "rmdir"):
        mp.setattr(staging.os, name, dying(getattr(os, name)))
    mp.setattr(staging, "_exchange", dying(staging._exchange))
    return mp


def _killed(k: int, fn) -> bool:
    """Whether ``fn`` was killed at its k-th step."""
    mp = _dies_at(k)
    try:
        fn()
        return False
    except Killed:
        return True
    finally:
        mp.undo()


def _whole(out: Path, old: dict, new: dict) -> dict:
    """The folder's dataset, checked: each top-level entry one dataset's, whole; the complete
    mark only on one dataset whole."""
    from specsynth.run import staging

    now = _read_tree(out)
    assert all(now.get(n) in (old.get(n), new.get(n)) for n in NAMES)
    if (out / staging.COMPLETE).exists():
        assert now in (old, new)
    return now


def _swap_killed_at(out: Path, old: dict, new: dict, kill_at: int, again_at: int) -> bool:
    """A swap of ``old`` by ``new`` killed at its step ``kill_at``, its recovery at ``again_at``,
    then recovered: checked at each point; whether the first kill happened."""
    from specsynth.run import staging

    (out / ".specsynth").mkdir(parents=True)
    _write_tree(out, old)
    (out / staging.COMPLETE).write_text("{}")
    s = staging.Staging(out)
    new_dir = s.begin()
    _make_like(new_dir, new)
    (new_dir / staging.COMPLETE).write_text("{}")
    killed = _killed(kill_at, s.commit)
    now = _whole(out, old, new)
    expected = new if s.journal.exists() else now  # without a journal: not begun, or done
    assert expected in (old, new)
    _killed(again_at, staging.Staging(out).recover)
    _whole(out, old, new)
    staging.Staging(out).recover()
    assert _read_tree(out) == expected and (out / staging.COMPLETE).exists()
    assert not (out / staging.STAGING).exists()
    return killed


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(old=_dataset_trees, new=_dataset_trees, again_at=st.integers(0, 30))
def test_a_swap_killed_at_any_step_leaves_whole_entries_and_recovers_to_the_new_dataset(tmp_path, old, new, again_at):
    """Every rename and removal of a swap is a point the process may die at (each is tried), and
    so is every one of the next build's recovery: there each top-level entry is the last
    dataset's or the new one's, whole, and the folder is marked complete only when it holds one
    dataset whole. Recovery (what the next build does first) gives the new dataset once the
    journal was written, else the last one (the next merge is then done again)."""
    base = tmp_path / f"run{len(list(tmp_path.iterdir()))}"
    kill_at = 0
    while _swap_killed_at(base / str(kill_at), old, new, kill_at, again_at):
        kill_at += 1
    assert kill_at > len(set(old) | set(new))  # a step per entry at least was a kill point
