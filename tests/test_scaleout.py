"""Scale-out and crash safety: Dask LocalCluster, SIGKILL + resume, a crashing renderer, the lock."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from test_build import cli_build, tree_digest

from specsynth.plan.compiler import compile_spec
from specsynth.run.build import BuildLocked, build, output_lock
from specsynth.run.staging import STAGING
from specsynth.spec.yamlio import load_spec

ROOT = Path(__file__).resolve().parents[1]
SPEC = """\
name: scale
seed: 11
intrinsics: {width: 128, height: 96, fx: 115.0, fy: 115.0, cx: 63.5, cy: 47.5}
objects:
  builtin: [duck, mug, lego, jenga]
scenes:
  - name: room2
arrangements:
  count: 4
cameras:
  per_arrangement: 3
  distance: [0.4, 0.8]
backend:
  name: photo
outputs:
  image_format: png
"""


@pytest.fixture(scope="module")
def spec_file(tmp_path_factory) -> Path:
    f = tmp_path_factory.mktemp("spec") / "scale.yaml"
    f.write_text(SPEC)
    return f


@pytest.fixture(scope="module")
def reference(spec_file, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("ref") / "out"
    cli_build(spec_file, out, "--jobs", "1")
    return out


def test_dask_local_cluster_gives_the_same_bytes(spec_file, reference, tmp_path):
    pytest.importorskip("distributed")
    s = build(compile_spec(load_spec(spec_file)), tmp_path / "dask", executor="dask", jobs=2)
    assert not s.failures, s.failures
    trace = json.loads((tmp_path / "dask" / ".specsynth" / "trace.json").read_text())["traceEvents"]
    assert s.workers == 2 and {e["tid"] for e in trace if e["ph"] == "X"} == {0, 1}  # both worked
    a, b = tree_digest(tmp_path / "dask"), tree_digest(reference)
    assert a == b, sorted(k for k in a.keys() | b.keys() if a.get(k) != b.get(k))[:10]


def paused_build(spec_file: Path, out: Path, stage: str, marker: Path, *, new_session: bool,
                 extra: tuple[str, ...] = ()) -> subprocess.Popen:
    """`specsynth build --jobs 2` (and ``extra`` arguments) in a child that stops for good at
    ``stage`` (tests/paused_build.py) once ``marker`` holds its pid; a child that ends or hangs
    before that fails the test."""
    proc = subprocess.Popen(
        [sys.executable, str(Path(__file__).with_name("paused_build.py")), stage, str(marker), "--",
         "build", str(spec_file), "--out", str(out), "--jobs", "2", "--quiet", *extra],
        start_new_session=new_session, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
    )
    deadline = time.time() + 240
    while time.time() < deadline and proc.poll() is None and not marker.exists():
        time.sleep(0.05)
    if not marker.exists():
        proc.kill()
        err = proc.communicate()[1].decode(errors="replace")[-2000:]
        pytest.fail(f"the build did not stop at {stage} (exit status {proc.poll()}): {err}")
    assert proc.poll() is None  # stopped, not finished
    return proc


@pytest.mark.parametrize("kill_after", ["arrange", "view", "render", "merge"])
def test_sigkill_then_resume_is_byte_identical(spec_file, reference, tmp_path, kill_after):
    """The build is stopped where it is to be killed (its first finished job of that stage, or its
    fifth dataset file in place), then the whole process group gets SIGKILL while the workers are
    still at their jobs."""
    out = tmp_path / "killed"
    proc = paused_build(spec_file, out, kill_after, tmp_path / "stopped", new_session=True)
    d = out / ".specsynth" / "store" / kill_after
    if kill_after == "merge":  # the dataset is written aside, then swapped in
        assert len([p for p in (out / STAGING / "new" / "bop").rglob("*") if p.is_file()]) >= 5
        assert not (out / ".specsynth" / "outputs.json").exists()  # the merge had not finished
    else:
        assert any(d.rglob("record.json"))
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert proc.returncode == -signal.SIGKILL
    # Nothing half-written is visible under a final name: a kill while the dataset is written can
    # leave only hidden temp files (".<name>.<id>.tmp"), which the next build removes.
    temps = [p for p in out.rglob("*.tmp") if ".specsynth" not in p.parts]
    assert all(p.name.startswith(".") for p in temps) and (kill_after == "merge" or not temps)
    s = build(compile_spec(load_spec(spec_file)), out, jobs=2)
    assert not s.failures, s.failures
    assert not [p for p in out.rglob("*.tmp") if ".specsynth" not in p.parts]
    assert tree_digest(out) == tree_digest(reference)


def _dataset(out: Path) -> dict[str, bytes]:
    """Every file of the dataset in ``out`` (all but specsynth's own .specsynth), by path."""
    return {p.relative_to(out).as_posix(): p.read_bytes() for p in sorted(out.rglob("*"))
            if p.is_file() and p.relative_to(out).parts[0] != ".specsynth"}


RESEED = ("--set", "seed=12")  # a rebuild in which every file changes


@pytest.fixture(scope="module")
def reseeded(spec_file, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("reseeded") / "out"
    cli_build(spec_file, out, "--jobs", "1", *RESEED)
    return out


def test_a_merge_killed_midway_leaves_the_last_dataset_and_the_next_build_completes_it(spec_file, reference,
                                                                                       reseeded, tmp_path):
    """A complete dataset is rebuilt with another seed and the rebuild is killed (SIGKILL of its
    process group) while its merge writes the new dataset, after its fifth file: the last dataset
    is still in place byte for byte, and the next build completes the new one as a clean build."""
    out = tmp_path / "out"
    shutil.copytree(reference, out)
    last = _dataset(out)
    proc = paused_build(spec_file, out, "merge", tmp_path / "stopped", new_session=True, extra=RESEED)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert _dataset(out) == last and (out / ".specsynth" / "complete.json").is_file()
    s = build(compile_spec(load_spec(spec_file, ["seed=12"])), out, jobs=2)
    assert not s.failures and not s.kept_previous
    assert tree_digest(out) == tree_digest(reseeded) and not (out / STAGING).exists()


def test_a_swap_killed_midway_is_finished_by_the_next_build_before_anything_else(spec_file, reference,
                                                                                 reseeded, tmp_path):
    """Killed once the new dataset's bop/ is in place, before its coco/ and parquet/ are: each
    top-level entry is the last dataset's or the new one's, whole, and the folder is not marked
    complete; the next build, even of another spec, finishes the swap before it runs a job (this
    one stops after its cameras, before any merge)."""
    out = tmp_path / "out"
    shutil.copytree(reference, out)
    last, new = _dataset(out), _dataset(reseeded)
    proc = paused_build(spec_file, out, "swap", tmp_path / "stopped", new_session=True, extra=RESEED)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    now = _dataset(out)
    tops = {k.split("/")[0] for k in now.keys() | last.keys() | new.keys()}
    for top in tops:
        part = {k: v for k, v in now.items() if k.split("/")[0] == top}
        assert part in ({k: v for k, v in last.items() if k.split("/")[0] == top},
                        {k: v for k, v in new.items() if k.split("/")[0] == top}), top
    assert now != last and not (out / ".specsynth" / "complete.json").exists()
    build(compile_spec(load_spec(spec_file, ["seed=1"])), out, jobs=1, until="view")
    assert tree_digest(out) == tree_digest(reseeded) and not (out / STAGING).exists()
    assert (out / ".specsynth" / "complete.json").is_file()


def _crashy(spec_file: Path, cam: int, *extra: str):
    g0 = compile_spec(load_spec(spec_file, ["backend.name=crashy_backend:PLUGIN"]))
    victim = g0.render_job(1, cam)
    overrides = ["backend.name=crashy_backend:PLUGIN", f"backend.crash_seed={victim.seed}", *extra]
    return compile_spec(load_spec(spec_file, overrides))


def test_crashing_renderer_is_retried_then_reported(spec_file, tmp_path, monkeypatch):
    """A render that segfaults its worker every time. Its arrangement's renders go to a worker
    together (another arrangement is still to come): the group runs once among the others (the
    crash takes the pool down, so every call in flight is suspect and none uses up a retry), then
    alone, then once more alone for its one retry; then it is split into single renders, and the
    bad one runs the same three times and is reported with its tries; the rest complete."""
    log = tmp_path / "runs.log"
    monkeypatch.setenv("CRASHY_LOG", str(log))  # the crashy backend logs each run's pid
    s = build(_crashy(spec_file, 1), tmp_path / "crash", jobs=2, retries=1)
    failed = [f for f in s.failures if f["stage"] == "render"]
    assert len(failed) == 1 and failed[0]["job"] == "arr=000001/cam=001", s.failures
    assert "BrokenProcessPool" in failed[0]["error"]
    pids = log.read_text().split()
    assert failed[0]["tries"] == 3 and len(pids) == 6  # in its group 1 + 1 alone + 1 retry; then alone the same
    assert len(set(pids)) == 6  # each crash killed its worker: every try ran in a new process
    assert s.stages["render"].failed == 1
    assert s.images == s.views_accepted - 1  # the rest of the build completed
    assert json.loads((tmp_path / "crash" / "failures.json").read_text()) == s.failures


def test_a_renderer_that_crashes_once_is_retried_and_its_image_kept(spec_file, tmp_path, monkeypatch):
    from PIL import Image

    log = tmp_path / "runs.log"
    monkeypatch.setenv("CRASHY_LOG", str(log))
    s = build(_crashy(spec_file, 1, "backend.crash_times=1"), tmp_path / "once", jobs=2, retries=1)
    assert s.failures == [] and s.images == s.views_accepted == 12
    pids = log.read_text().split()
    assert len(pids) == 2 and pids[0] != pids[1]  # crashed in one worker, rendered in a new one
    rgbs = sorted((tmp_path / "once" / "bop" / "train_pbr" / "000000" / "rgb").iterdir())
    flat7 = [p.name for p in rgbs if (np.asarray(Image.open(p)) == 7).all()]  # the retry's render
    assert len(rgbs) == 12 and flat7 == ["000004.png"]  # arr 1, cam 1


def test_second_build_into_same_folder_is_refused(spec_file, tmp_path):
    out = tmp_path / "locked"
    with output_lock(out):
        with pytest.raises(BuildLocked):
            with output_lock(out):
                pass
        r = subprocess.run([sys.executable, "-m", "specsynth.cli", "build", str(spec_file), "--out", str(out)],
                           capture_output=True, text=True)
        assert r.returncode == 2
        assert "another build" in r.stderr and "Traceback" not in r.stderr


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _settings_probe():
    """What a worker runs to report its settings (a closure: pickled by value, no test imports)."""

    def settings():
        import os

        import dask

        return (os.environ.get("MALLOC_TRIM_THRESHOLD_"), dask.config.get("distributed.worker.profile.enabled"),
                dask.config.get("distributed.admin.tick.interval"),
                dask.config.get("distributed.worker.memory.monitor-interval"))

    return settings


SPECSYNTH_DASK = (None, False, "1s", "1s")  # what _settings_probe reports under specsynth.yaml


def test_specsynth_dask_settings_are_dask_settings():
    """A misspelt key would be accepted by Dask and do nothing."""
    pytest.importorskip("distributed")
    import dask
    import distributed  # noqa: F401  (loads Dask's defaults for its keys)
    import yaml

    from specsynth.run.executors.dask import CONFIG_DIR, _dotted

    ours = _dotted(yaml.safe_load((CONFIG_DIR / "specsynth.yaml").read_text()))
    missing = object()
    assert [k for k in ours if dask.config.get(k, missing) is missing] == []


def test_local_cluster_workers_get_specsynth_dask_settings(spec_file, tmp_path):
    """No malloc trim threshold (it turns off glibc's adaptive mmap threshold), no profiler, slower
    housekeeping timers."""
    pytest.importorskip("distributed")
    from specsynth.run.executors.dask import DaskExecutor
    from specsynth.run.tasks import BuildContext

    g = compile_spec(load_spec(spec_file))
    ex = DaskExecutor(BuildContext(inputs=g.inputs, spec_dir=spec_file.parent, out=tmp_path), jobs=2)
    try:
        assert list(ex.client.run(_settings_probe()).values()) == [SPECSYNTH_DASK] * 2
    finally:
        ex.shutdown()


def test_plain_dask_scheduler_and_workers(spec_file, reference, tmp_path):
    """The documented setup: `dask scheduler` + `dask worker` processes, then --executor dask://HOST:PORT.

    Workers with --nthreads 2, so Dask hands each process two jobs at once: they must run one at a
    time (a worker's renderer and loaded arrangement are process-wide), with the bytes unchanged."""
    pytest.importorskip("distributed")
    bindir = Path(sys.executable).parent
    port = _free_port()
    procs = [subprocess.Popen([str(bindir / "dask"), "scheduler", "--host", "127.0.0.1", "--port", str(port),
                               "--no-dashboard"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        from specsynth.run.executors.dask import CONFIG_DIR

        env = {**os.environ, "DASK_CONFIG": str(CONFIG_DIR)}  # as docs/scaleout.md says
        procs.append(subprocess.Popen([str(bindir / "dask"), "worker", f"tcp://127.0.0.1:{port}", "--nworkers", "2",
                                       "--nthreads", "2", "--no-dashboard"], env=env,
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        from distributed import Client

        with Client(f"tcp://127.0.0.1:{port}", timeout=60) as c:
            c.wait_for_workers(2, timeout=120)
            assert list(c.run(_settings_probe()).values()) == [SPECSYNTH_DASK] * 2
        cli_build(spec_file, tmp_path / "remote", "--executor", f"dask://127.0.0.1:{port}")
        assert tree_digest(tmp_path / "remote") == tree_digest(reference)
    finally:
        for p in reversed(procs):
            p.terminate()
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()


def test_local_workers_split_the_cores_unless_told(spec_file, tmp_path):
    from dataclasses import replace

    from specsynth.run.executors.local import LocalExecutor
    from specsynth.run.tasks import BuildContext, available_cores

    g = compile_spec(load_spec(spec_file))
    ctx = BuildContext(inputs=g.inputs, spec_dir=spec_file.parent, out=tmp_path)
    for jobs, given, expected in ((2, 0, max(1, available_cores() // 2)), (2, 3, 3), (1, 0, 0)):  # 0: all cores
        ex = LocalExecutor(replace(ctx, threads=given), jobs=jobs)
        try:
            assert ex._ctx.threads == expected
        finally:
            ex.shutdown()


def test_slurm_example_job_script():
    """The Slurm example's job script, as dask-jobqueue would submit it (no Slurm here to run it)."""
    pytest.importorskip("dask_jobqueue")
    sys.path.insert(0, str(ROOT / "examples"))
    try:
        from slurm_build import make_cluster
    finally:
        sys.path.remove(str(ROOT / "examples"))
    from specsynth.run.executors.dask import CONFIG_DIR

    with make_cluster(cores=16, scheduler_options={"host": "127.0.0.1"}) as cluster:
        script = cluster.job_script()
    assert f"export DASK_CONFIG={CONFIG_DIR}" in script
    assert "--nworkers 16" in script and "--nthreads 1" in script and "#SBATCH --exclusive" in script
    assert "#SBATCH -n 1" in script and "#SBATCH --cpus-per-task=16" in script


def _children(pid: int) -> set[int]:
    out = set()
    for task in Path(f"/proc/{pid}/task").glob("*"):
        try:
            out |= {int(c) for c in (task / "children").read_text().split()}
        except OSError:
            pass
    return out


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().split()[2] != "Z"
    except OSError:
        return False


def test_pool_workers_exit_when_the_build_is_killed(spec_file, tmp_path):
    """kill -9 of the build process (only it, not its group) used to leave its workers running
    for minutes; they now die with it (PR_SET_PDEATHSIG). The build is stopped after its first
    arrangement (tests/paused_build.py), so it cannot end before its workers are seen."""
    proc = paused_build(spec_file, tmp_path / "o", "arrange", tmp_path / "stopped", new_session=False)
    deadline = time.time() + 120
    workers: set[int] = set()
    while time.time() < deadline and len(workers) < 2:
        workers = {c for c in _children(proc.pid) if "spawn_main" in Path(f"/proc/{c}/cmdline").read_text(errors="replace")}
        time.sleep(0.05)
    assert len(workers) == 2 and all(_alive(w) for w in workers)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    deadline = time.time() + 20  # a worker still importing its renderer dies when it gets to its initializer
    while time.time() < deadline and any(_alive(w) for w in workers):
        time.sleep(0.1)
    assert not any(_alive(w) for w in workers)


def test_a_job_failing_on_dask_workers_is_reported_once_without_worker_tracebacks(tmp_path):
    """Distributed's workers logged each failed attempt with its traceback (six copies for one
    corrupt mesh); the build's own error is the one line a user needs."""
    pytest.importorskip("distributed")
    (tmp_path / "bad.ply").write_text("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                                      "property float z\nelement face 1\nproperty list uchar int vertex_indices\n"
                                      "end_header\n0 0 0\nnot-a-number 1 0\n0 1 0\n3 0 1 2\n")
    spec = tmp_path / "bad.yaml"
    spec.write_text(SPEC.replace("  builtin: [duck, mug, lego, jenga]", "  meshes: [{path: bad.ply, unit: m}]"))
    r = subprocess.run([sys.executable, "-m", "specsynth.cli", "build", str(spec), "--out", str(tmp_path / "out"),
                        "--executor", "dask", "--jobs", "2", "--quiet"], capture_output=True, text=True, timeout=300)
    assert r.returncode != 0 and "bad.ply: corrupt PLY" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr and "Compute Failed" not in r.stderr, r.stderr
