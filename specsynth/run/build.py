"""Running a compiled job graph: ``plan`` and ``build``.

A build holds an exclusive lock on its output folder, runs only jobs whose content key has no
finished result in the store, then merges the records into the dataset formats. The parts are
modules of their own: ``schedule`` (calls, the executor loop, retries), ``pipeline`` (which calls
follow which, the run's bookkeeping), ``merge`` (the dataset) and ``manifest`` (the manifest, the
lock file and ``diff``).
"""

from __future__ import annotations

import fcntl
import os
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterator

from ..files import UnsafeOutput, output_folder, refuse_links_out
from ..plan.compiler import STAGES, JobGraph
from ..plugins import load_executor
from .manifest import diff, manifest_of, read_manifest, write_manifest
from .merge import COMPLETE, KEPT_FAILURES, merge
from .pipeline import Pipeline
from .schedule import EST_SECONDS, render_estimate, run_calls, split_group
from .staging import Staging
from .store import Store, write_json
from .summary import BuildSummary

# What the CLI, the tests and scripts import from here.
__all__ = ["COMPLETE", "KEPT_FAILURES", "BuildLocked", "BuildSummary", "UnsafeOutput", "build", "diff",
           "manifest_of", "output_lock", "plan", "read_manifest", "write_manifest"]


class BuildLocked(RuntimeError):
    pass


@contextmanager
def output_lock(out: Path) -> Iterator[None]:
    """Refuse a second concurrent build into the same folder instead of interleaving them."""
    meta = out / ".specsynth"
    meta.mkdir(parents=True, exist_ok=True)
    fd = os.open(meta / "build.lock", os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            other = os.pread(fd, 64, 0).decode(errors="replace").strip()
            raise BuildLocked(f"another build (pid {other or '?'}) is writing into {out}; wait for it or use another --out") from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode(), 0)
        yield
    finally:
        os.close(fd)


def plan(graph: JobGraph, out: Path) -> dict[str, Any]:
    """Per stage: jobs that exist, are cached, would run, with an estimated cost in seconds. Reads
    ``out`` as a build would: a link in it that leads out of it is refused, not followed."""
    out = output_folder(out)
    if out.is_dir():
        refuse_links_out(out)
    store = Store(out)
    done = {s: store.keys(s) for s in STAGES}
    counts = {s: {"jobs": 0, "cached": 0, "to_run": 0} for s in STAGES}
    for job in graph.jobs():
        c = counts[job.stage]
        c["jobs"] += 1
        if job.key in done[job.stage]:
            c["cached"] += 1
        else:
            c["to_run"] += 1
    per = {"arrange": EST_SECONDS["arrange"], "view": EST_SECONDS["view"], "render": render_estimate(graph)}
    for s in STAGES:
        counts[s]["est_seconds"] = round(counts[s]["to_run"] * per[s], 1)
    return {
        "spec": str(graph.spec_path),
        "out": str(out),
        "backend": graph.backend,
        "stages": counts,
        "note": "render counts are upper bounds: cameras rejected by the visibility pre-check create no render job",
    }


def _progress(console):
    from rich.progress import (
        BarColumn,
        MofNCompleteColumn,
        Progress,
        TextColumn,
        TimeElapsedColumn,
        TimeRemainingColumn,
    )

    return Progress(
        TextColumn("[bold]{task.description:<8}"), BarColumn(), MofNCompleteColumn(),
        TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn(),
        console=console, transient=False, disable=console is None,
    )


def build(graph: JobGraph, out: Path, *, executor: str = "local", jobs: int = 1, address: str | None = None,
          console=None, retries: int = 2, until: str = "merge", threads: int | None = None,
          log: Callable[[str], None] | None = None) -> BuildSummary:
    """Run the graph; ``until="view"`` stops after the camera stage (used by ``bench``).
    ``log`` gets a line per finished or failed call (``--verbose``).

    Stages are pipelined per arrangement: its cameras are sampled as soon as it has settled, and
    its images rendered as soon as its cameras are known. Stage seconds in the summary are
    worker-seconds (summed over workers); ``wall_seconds`` is the whole build.
    """
    from .worker import BuildContext

    t_build = time.perf_counter()
    out = output_folder(out)
    out.mkdir(parents=True, exist_ok=True)
    refuse_links_out(out)
    summary = BuildSummary(out=str(out), backend=graph.backend)
    with output_lock(out):
        Staging(out).recover()  # before anything else: the dataset in place is then a complete one
        store = Store(out)
        store.clean_tmp()
        ctx = BuildContext(inputs=graph.inputs, spec_dir=graph.spec_path.parent, out=out.resolve(), threads=threads or 0)
        ex = load_executor(executor)(ctx, jobs=jobs, address=address)
        workers = max(1, getattr(ex, "workers", jobs))
        try:
            with _progress(console) as prog:
                # wkey: which worker state a task uses (one Dask worker may serve several builds)
                pipe = Pipeline(graph, store, summary, prog, str(ctx.out), workers, until, log)
                run_calls(ex, pipe.first_calls(), pipe.on_done, pipe.on_error, window=2 * workers,
                          retries=retries, split=split_group)
        finally:
            ex.shutdown()
        pipe.record_timing(out)
        if until == "view":
            return summary
        merge(graph, out, pipe, summary)
        summary.wall_seconds = time.perf_counter() - t_build
        write_json(out / ".specsynth" / "summary.json", summary.to_json())
    return summary
