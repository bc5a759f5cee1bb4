"""Scale-out and crash safety: Dask LocalCluster, SIGKILL + resume, a crashing renderer, the lock."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_build import cli_build, tree_digest

from specsynth.plan.compiler import compile_spec
from specsynth.run.build import BuildLocked, build, output_lock
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


def _store_has(out: Path, stage: str) -> bool:
    if stage == "merge":  # the main process is writing the dataset's files
        return (out / "bop").is_dir() and any((out / "bop").rglob("*.png"))
    d = out / ".specsynth" / "store" / stage
    return d.is_dir() and any(d.rglob("record.json"))


@pytest.mark.parametrize("kill_after", ["arrange", "view", "render", "merge"])
def test_sigkill_then_resume_is_byte_identical(spec_file, reference, tmp_path, kill_after):
    out = tmp_path / "killed"
    proc = subprocess.Popen(
        [sys.executable, "-m", "specsynth.cli", "build", str(spec_file), "--out", str(out), "--jobs", "2", "--quiet"],
        start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    deadline = time.time() + 240
    while time.time() < deadline and proc.poll() is None and not _store_has(out, kill_after):
        time.sleep(0.05)
    if proc.poll() is not None:
        pytest.skip("the build finished before it could be killed")
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    # Nothing half-written is visible under a final name: a kill while the dataset is written can
    # leave only hidden temp files (".<name>.<id>.tmp"), which the next build removes.
    temps = [p for p in out.rglob("*.tmp") if ".specsynth" not in p.parts]
    assert all(p.name.startswith(".") for p in temps) and (kill_after == "merge" or not temps)
    s = build(compile_spec(load_spec(spec_file)), out, jobs=2)
    assert not s.failures, s.failures
    assert not [p for p in out.rglob("*.tmp") if ".specsynth" not in p.parts]
    assert tree_digest(out) == tree_digest(reference)


def test_crashing_renderer_is_retried_then_reported(spec_file, tmp_path):
    g0 = compile_spec(load_spec(spec_file, ["backend.name=crashy_backend:PLUGIN"]))
    victim = g0.render_job(1, 1)
    overrides = ["backend.name=crashy_backend:PLUGIN", f"backend.crash_seed={victim.seed}"]
    g = compile_spec(load_spec(spec_file, overrides))
    s = build(g, tmp_path / "crash", jobs=2, retries=1)
    failed = [f for f in s.failures if f["stage"] == "render"]
    assert len(failed) == 1 and failed[0]["job"] == "arr=000001/cam=001", s.failures
    assert "BrokenProcessPool" in failed[0]["error"]
    assert s.stages["render"].failed == 1
    assert s.images == s.views_accepted - 1  # the rest of the build completed
    assert json.loads((tmp_path / "crash" / "failures.json").read_text()) == s.failures


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
    ex = DaskExecutor(BuildContext(spec=g.spec, spec_dir=spec_file.parent, out=tmp_path), jobs=2)
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
    ctx = BuildContext(spec=g.spec, spec_dir=spec_file.parent, out=tmp_path)
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
    for minutes; they now die with it (PR_SET_PDEATHSIG)."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "specsynth.cli", "build", str(spec_file), "--out", str(tmp_path / "o"), "--jobs", "2",
         "--quiet"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )
    deadline = time.time() + 120
    workers: set[int] = set()
    while time.time() < deadline and proc.poll() is None and len(workers) < 2:
        workers = {c for c in _children(proc.pid) if "spawn_main" in Path(f"/proc/{c}/cmdline").read_text(errors="replace")} \
            if Path(f"/proc/{proc.pid}").exists() else set()
        time.sleep(0.05)
    if proc.poll() is not None or len(workers) < 2:
        pytest.skip("the build ended before its workers could be seen")
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    deadline = time.time() + 20  # a worker still importing its renderer dies when it gets to its initializer
    while time.time() < deadline and any(_alive(w) for w in workers):
        time.sleep(0.1)
    assert not any(_alive(w) for w in workers)
