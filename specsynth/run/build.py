"""Running a compiled job graph: plan, build, manifest, lock and diff.

A build holds an exclusive lock on its output folder, runs only jobs whose content key has no
finished result in the store, then merges the records into BOP / Parquet / COCO files.
"""

from __future__ import annotations

import fcntl
import heapq
import itertools
import json
import os
import queue
import time
from collections import deque
from contextlib import contextmanager
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from .. import notices
from ..files import UnsafeOutput, refuse_links_out  # noqa: F401  (UnsafeOutput: the CLI's)
from ..model.error import error_ratio
from ..model.records import ImageRecord
from ..plan import keys
from ..plan.compiler import STAGES, JobGraph
from ..plugins import PluginNotFound, backend_plugin, load_executor
from .store import Store, write_json

# Rough seconds per job on a 2-core machine (docs/performance.md), for `plan` estimates only.
EST_SECONDS = {"arrange": 0.5, "view": 0.08}


class BuildLocked(RuntimeError):
    pass


# Written when a merge completes without failures, removed when one starts: a dataset that a
# failing rebuild must not replace.
COMPLETE = Path(".specsynth") / "complete.json"
KEPT_FAILURES = Path(".specsynth") / "failures.json"


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


@dataclass
class StageStats:
    total: int = 0
    cached: int = 0
    ran: int = 0
    failed: int = 0
    seconds: float = 0.0


@dataclass
class BuildSummary:
    out: str
    backend: str
    stages: dict[str, StageStats] = field(default_factory=lambda: {s: StageStats() for s in (*STAGES, "merge")})
    views_accepted: int = 0
    views_dropped: int = 0
    cameras_rejected: int = 0
    rejected_seconds: float = 0.0
    objects_removed: int = 0
    objects_redropped: int = 0
    images: int = 0
    instances: int = 0
    failures: list[dict[str, str | int]] = field(default_factory=list)
    # What skipping saved, in seconds (estimates from this build's own measured render times).
    saved: dict[str, float] = field(default_factory=dict)
    glossy_bounces_skipped: int = 0  # renders whose scene had no glossy material
    # Worker-seconds of this build's renders by phase (render.<backend phase>, load, annotate,
    # encode, write): where the render stage's time went.
    render_phases: dict[str, float] = field(default_factory=dict)
    wall_seconds: float = 0.0
    workers: int = 0
    # From the first job's start to the last job's end, and the share of it the workers were busy
    # (worker-seconds / (workers x that span)); the rest is start-up, scheduling and the tail.
    run_seconds: float = 0.0
    utilisation: float = 0.0
    # True when this build failed or rendered nothing and the folder's last complete dataset was
    # left as it was; the failures are then in KEPT_FAILURES, not the dataset's failures.json.
    kept_previous: bool = False
    # quality.control: error: samples per image and estimated error / target over the images
    # (medians, 95th percentiles) and the share whose estimate is within 10 % of the target or below.
    error_control: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        d = self.__dict__.copy()
        d["stages"] = {k: v.__dict__ for k, v in self.stages.items()}
        return d


def _samples(graph: JobGraph) -> int:
    """The backends' rule: an explicit (or calibrated) `samples`, else max(AA, diffuse rays, specular rays)."""
    q = graph.spec.quality.resolved()
    options = graph.spec.backend
    try:
        options = backend_plugin(options.name).options_for(options, graph.spec.quality)
    except PluginNotFound:
        pass
    return options.samples or q.samples


def _render_estimate(graph: JobGraph) -> float:
    """Estimated seconds per render, from the backend plugin's own cost model."""
    try:
        a, b = backend_plugin(graph.spec.backend.name).cost
    except PluginNotFound:
        a, b = 1.0, 0.1
    return a + b * _samples(graph)


def plan(graph: JobGraph, out: Path) -> dict[str, Any]:
    """Per stage: jobs that exist, are cached, would run, with an estimated cost in seconds."""
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
    per = {"arrange": EST_SECONDS["arrange"], "view": EST_SECONDS["view"], "render": _render_estimate(graph)}
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


def _is_crash(e: BaseException) -> bool:
    """A worker process died (segfault, OOM kill): every job in flight on the pool failed with it."""
    return type(e).__name__ in ("BrokenProcessPool", "KilledWorker")


@dataclass
class Call:
    """One task submission: ``n`` jobs of ``stage`` for arrangement ``arr``."""

    fn: Callable
    args: tuple
    stage: str
    ident: str
    n: int
    arr: int
    tries: int = 0  # retries used up
    runs: int = 0  # runs that failed (with a crash, also those a crashing neighbour took down)

    @property
    def priority(self) -> tuple[bool, int, int]:
        # Arrangements first, then later stages, then older arrangements. Physics is the long,
        # unpredictable job (p90 2-3 s per arrangement): run last, one settling left a worker idle
        # ~2 s at the end of a 20 s build (measured: 94-96 % of the run busy, 99.5 % this way). Its
        # cameras and images then follow as each arrangement settles, and an arrangement's renders
        # go before the next one's cameras, so the workers' loaded scenes are reused.
        return (self.stage != "arrange", STAGES[::-1].index(self.stage), self.arr)


def _run(ex, calls: list[Call], on_done: Callable[[Call, Any], list[Call]],
         on_error: Callable[[Call, BaseException], list[Call]], *, window: int, retries: int,
         split: Callable[[Call], list[Call] | None] = lambda c: None) -> None:
    """Submit calls with at most ``window`` in flight, in priority order, taking results as they
    finish; ``on_done`` / ``on_error`` return follow-up calls (the next stage of an arrangement).

    A failed call is retried up to ``retries`` times. A retry is safe because a job counts only
    once its record is in the store: a re-submitted group re-runs exactly the jobs that have no
    finished result. When a worker crashes, every call in flight fails with it; those are re-run
    one at a time so that only the call that really crashes uses up its retries. A group that
    still fails is split into single jobs (``split``) so one bad job does not take its whole
    arrangement down.
    """
    from .tasks import timed

    order = itertools.count()
    heap: list[tuple[tuple[int, int], int, Call]] = []
    suspects: deque[Call] = deque()
    inflight: dict[int, tuple[Call, bool]] = {}
    finished: queue.SimpleQueue = queue.SimpleQueue()

    def push(cs):
        for c in cs or ():
            heapq.heappush(heap, (c.priority, next(order), c))

    def submit(c: Call, isolated: bool) -> None:
        token = next(order)
        inflight[token] = (c, isolated)
        fut = ex.submit(timed, c.fn, *c.args)
        # Both concurrent.futures and Dask futures call back from their own thread: only hand over.
        fut.add_done_callback(lambda f, token=token: finished.put((token, f)))

    push(calls)
    while heap or suspects or inflight:
        if suspects:
            if not inflight:
                submit(suspects.popleft(), True)
        else:
            while heap and len(inflight) < window:
                submit(heapq.heappop(heap)[2], False)
        token, fut = finished.get()
        c, isolated = inflight.pop(token)
        try:
            res = fut.result()
        except Exception as e:  # one failed job must not stop the build
            c.runs += 1
            if _is_crash(e) and not isolated:
                suspects.append(c)
            elif c.tries < retries:
                c.tries += 1
                if _is_crash(e):
                    suspects.append(c)
                else:
                    push([c])
            else:
                push(split(c) or on_error(c, e))
            continue
        push(on_done(c, res))


def split_group(c: Call) -> list[Call] | None:
    """A failed view or render group as single-job calls; None for an arrangement or a single job."""
    if c.stage == "arrange":  # args (worker key, job): nothing to split
        return None
    fn, (wk, key, group) = c.fn, c.args
    if len(group) < 2:
        return None
    return [Call(fn, (wk, key, [j]), c.stage, _group_id(j), 1, c.arr) for j in group]


# Renders per call: one scene load serves up to this many cameras of an arrangement, and the
# end of a build is not left to one worker with a long group while the others idle. Renders
# estimated to take longer than SINGLE_RENDER_SECONDS go one per call: a task's round trip
# (0.5 ms local, 11 ms Dask) and a scene load (~0.07 s with Cycles) are small next to them, and a
# build then ends on one render, not on a group of them.
RENDER_CHUNK = 8
SINGLE_RENDER_SECONDS = 0.5


def render_chunk(graph: JobGraph, n: int, workers: int) -> int:
    """How many of an arrangement's ``n`` renders go in one call."""
    if _render_estimate(graph) >= SINGLE_RENDER_SECONDS:
        return 1
    return max(1, min(RENDER_CHUNK, -(-n // workers)))


class _Pipeline:
    """Which calls follow which: an arrangement's view group is queued when it has settled, its
    render groups when its views are known. Holds the bookkeeping of one build's run."""

    def __init__(self, graph: JobGraph, store: Store, summary: BuildSummary, prog, wkey: str, workers: int,
                 until: str, log: Callable[[str], None] | None = None):
        from .tasks import task_arrange, task_renders, task_views

        self.tasks = {"arrange": task_arrange, "view": task_views, "render": task_renders}
        self.log = log
        self.graph, self.store, self.summary, self.prog = graph, store, summary, prog
        self.wkey, self.workers, self.until = wkey, workers, until
        self.arr_jobs = [graph.arrangement_jobs(a) for a in range(graph.n_arrangements)]
        self.views_left: dict[int, int] = {}  # arrangement -> view jobs not yet finished or failed
        self.spans: list[tuple[str, str, int, int, float, float, dict]] = []  # stage, call, jobs, pid, start, seconds, args
        self.cached_render: set[str] = set()
        self.bars = {s: prog.add_task(s, total=0) for s in STAGES}

    def advance(self, stage: str, n: int) -> None:
        self.prog.advance(self.bars[stage], n)

    def first_calls(self) -> list[Call]:
        st, sv = self.summary.stages["arrange"], self.summary.stages["view"]
        st.total, sv.total = len(self.arr_jobs), self.graph.n_views
        self.prog.update(self.bars["arrange"], total=st.total)
        self.prog.update(self.bars["view"], total=sv.total)
        calls: list[Call] = []
        for i, (a, _, _) in enumerate(self.arr_jobs):
            if self.store.has("arrange", a.key):
                st.cached += 1
                self.advance("arrange", 1)
                calls += self.view_calls(i)
            else:
                calls.append(Call(self.tasks["arrange"], (self.wkey, a), "arrange", a.id, 1, i))
        return calls

    def view_calls(self, i: int) -> list[Call]:
        a, views, _ = self.arr_jobs[i]
        todo = [v for v in views if not self.store.has("view", v.key)]
        self.summary.stages["view"].cached += len(views) - len(todo)
        self.advance("view", len(views) - len(todo))
        if not todo:
            return self.render_calls(i)
        self.views_left[i] = len(todo)
        return [Call(self.tasks["view"], (self.wkey, a.key, todo), "view", a.id, len(todo), i)]

    def render_calls(self, i: int) -> list[Call]:
        a, views, renders = self.arr_jobs[i]
        summary, sr = self.summary, self.summary.stages["render"]
        todo, cached = [], 0
        for v, r in zip(views, renders):
            if not self.store.has("view", v.key):  # its view job failed
                continue
            vrec = self.store.load("view", v.key)
            summary.cameras_rejected += vrec["tries"] - (1 if vrec["accepted"] else 0)
            summary.rejected_seconds += vrec["rejected_seconds"]
            if not vrec["accepted"]:
                summary.views_dropped += 1
                continue
            summary.views_accepted += 1
            if self.until == "view":  # (the camera bookkeeping above is still wanted)
                continue
            sr.total += 1
            if self.store.has("render", r.key):
                cached += 1
                self.cached_render.add(r.key)
            else:
                todo.append((v, r))
        sr.cached += cached
        self.prog.update(self.bars["render"], total=sr.total)
        self.advance("render", cached)
        # Split an arrangement's renders between the workers (each loads the scene once):
        # otherwise the last arrangement's group runs alone at the end of the build.
        size = render_chunk(self.graph, len(todo), self.workers)
        chunks = [todo[k:k + size] for k in range(0, len(todo), size)]
        return [Call(self.tasks["render"], (self.wkey, a.key, c), "render", _group_id(c[0]), len(c), i) for c in chunks]

    def _view_resolved(self, i: int, n: int) -> list[Call]:
        self.views_left[i] -= n
        return self.render_calls(i) if self.views_left[i] == 0 else []

    def on_done(self, c: Call, res) -> list[Call]:
        seconds, result, (pid, start), told = res
        notices.record(told)
        args = {}
        if c.stage == "render":
            for r in result:
                for k, v in r.phases.items():
                    args[k] = args.get(k, 0.0) + v
            phases = self.summary.render_phases
            for k, v in args.items():
                phases[k] = round(phases.get(k, 0.0) + v, 4)
        self.spans.append((c.stage, c.ident, c.n, pid, start, seconds, {k: round(v, 4) for k, v in args.items()}))
        if self.log is not None:
            self.log(f"{c.stage} {c.ident}: " + _job_detail(c.stage, result) + f" in {seconds:.2f} s (worker {pid})")
        stage = self.summary.stages[c.stage]
        stage.ran += c.n
        stage.seconds += seconds
        self.advance(c.stage, c.n)
        if c.stage == "arrange":
            return self.view_calls(c.arr)
        return self._view_resolved(c.arr, c.n) if c.stage == "view" else []

    def on_error(self, c: Call, e: BaseException) -> list[Call]:
        if self.log is not None:
            self.log(f"{c.stage} {c.ident}: {c.n} job(s) failed: {type(e).__name__}: {e}")
        self.summary.stages[c.stage].failed += c.n
        self.summary.failures.append({"stage": c.stage, "job": c.ident, "error": f"{type(e).__name__}: {e}",
                                      "tries": c.runs})
        return self._view_resolved(c.arr, c.n) if c.stage == "view" else []

    def record_timing(self, out: Path) -> None:
        summary, spans = self.summary, self.spans
        summary.workers = self.workers
        t_first = min((sp[4] for sp in spans), default=0.0)
        if spans:
            summary.run_seconds = max(sp[4] + sp[5] for sp in spans) - t_first
            busy = sum(sp[5] for sp in spans)
            summary.utilisation = round(busy / (self.workers * summary.run_seconds), 3) if summary.run_seconds else 1.0
        # Always written: a rebuild that ran nothing must not leave the previous build's timeline.
        write_json(out / ".specsynth" / "trace.json", _trace(spans, t_first), indent=None)
        summary.failures.sort(key=lambda f: (STAGES.index(f["stage"]), f["job"]))


def _job_detail(stage: str, result) -> str:
    """What one finished call did, for ``--verbose``."""
    if stage == "arrange":
        if result.cached:
            return "settled earlier (cached)"
        return f"{result.objects} object(s) settled, {result.removed} removed, {result.redropped} re-dropped"
    if stage == "view":
        ok = sum(1 for r in result if r.accepted)
        return f"{ok} of {len(result)} camera(s) accepted after {sum(r.tries for r in result)} tries"
    return f"{len(result)} image(s)"


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
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    refuse_links_out(out)
    summary = BuildSummary(out=str(out), backend=graph.backend)
    with output_lock(out):
        store = Store(out)
        store.clean_tmp()
        ctx = BuildContext(inputs=graph.inputs, spec_dir=graph.spec_path.parent, out=out.resolve(), threads=threads or 0)
        ex = load_executor(executor)(ctx, jobs=jobs, address=address)
        workers = max(1, getattr(ex, "workers", jobs))
        try:
            with _progress(console) as prog:
                # wkey: which worker state a task uses (one Dask worker may serve several builds)
                pipe = _Pipeline(graph, store, summary, prog, str(ctx.out), workers, until, log)
                _run(ex, pipe.first_calls(), pipe.on_done, pipe.on_error, window=2 * workers, retries=retries,
                     split=split_group)
        finally:
            ex.shutdown()
        pipe.record_timing(out)
        if until == "view":
            return summary
        _merge(graph, out, store, pipe, summary)
        summary.wall_seconds = time.perf_counter() - t_build
        write_json(out / ".specsynth" / "summary.json", summary.to_json())
    return summary


def _merge(graph: JobGraph, out: Path, store: Store, pipe: _Pipeline, summary: BuildSummary) -> None:
    """Every finished render into the dataset formats, then the manifest and the output index."""
    t0 = time.perf_counter()
    images, credits = [], []
    for a, views, renders in pipe.arr_jobs:
        arec = {}
        if store.has("arrange", a.key):
            arec = store.load("arrange", a.key)
            summary.objects_removed += arec["removed"]
            summary.objects_redropped += arec["redropped"]
        for r in renders:
            if store.has("render", r.key):
                images.append((ImageRecord.from_json(store.load("render", r.key)), store.path("render", r.key)))
                credits += arec.get("credits", [])
    if (summary.failures or not images) and (out / COMPLETE).is_file():
        summary.kept_previous = True  # a failed or empty rebuild must not replace the last good dataset
        write_json(out / KEPT_FAILURES, summary.failures)
        return
    (out / COMPLETE).unlink(missing_ok=True)  # until the last file is in place
    (out / KEPT_FAILURES).unlink(missing_ok=True)
    from ..outputs import write_outputs
    from ..outputs.attribution import write_attribution
    from ..outputs.dataset import parts
    from .verify import read_index, write_index

    every = [e for part in parts(graph.spec.split, images) for e in part.images]  # a stereo pair's eyes: two images
    summary.images = len(every)
    summary.instances = sum(len(im.instances) for im, _ in every)
    _account_savings(summary, every, pipe.cached_render)
    write_outputs(out, graph.spec, images, dataset_models(graph, every), previous=read_index(out))
    write_attribution(out, credits, graph.spec.name)
    write_manifest(graph, out, pipe.arr_jobs)
    write_json(out / "failures.json", summary.failures)
    write_index(out)  # last: every output file is in place
    if images and not summary.failures:
        write_json(out / COMPLETE, {"images": summary.images})
    summary.stages["merge"] = StageStats(total=1, ran=1, seconds=time.perf_counter() - t0)


def dataset_models(graph: JobGraph, images) -> list:
    """The models the dataset's annotations name: the spec's objects, and the annotated
    distractors that appear (each under the obj_id it was annotated with)."""
    from dataclasses import replace

    from ..assets.resolve import resolve_objects
    from ..spec.models import Objects

    models = resolve_objects(graph.spec.objects, graph.spec_path.parent)
    d, n = graph.spec.arrangements.distractors, len(models)
    extra = sorted({g.obj_id for rec, _ in images for g in rec.instances} - {m.obj_id for m in models})
    if not (d.annotate and extra):
        return models
    found = {a.name: a for a in resolve_objects(Objects(builtin=sorted({d.name_of(i, n) for i in extra})),
                                                graph.spec_path.parent)}
    return models + [replace(found[d.name_of(i, n)], obj_id=i) for i in extra]


def _trace(spans, t0: float) -> dict[str, Any]:
    """The run as Chrome trace events (open in https://ui.perfetto.dev or chrome://tracing): one
    row per worker process, one box per call."""
    pids = {pid: k for k, pid in enumerate(sorted({sp[3] for sp in spans}))}
    events = [{"name": f"{stage} {ident}" + (f" ({n})" if n > 1 else ""), "cat": stage, "ph": "X",
               "ts": round(1e6 * (start - t0)), "dur": round(1e6 * seconds), "pid": 1, "tid": pids[pid],
               **({"args": {"seconds by phase": args}} if args else {})}
              for stage, ident, n, pid, start, seconds, args in spans]
    events += [{"name": "thread_name", "ph": "M", "pid": 1, "tid": k, "args": {"name": f"worker {k} (pid {pid})"}}
               for pid, k in pids.items()]
    return {"traceEvents": events, "displayTimeUnit": "ms"}


def _group_id(item) -> str:
    """The arrangement of a view job or a (view, render) pair, plus the camera when alone."""
    job = item[1] if isinstance(item, tuple) else item
    return job.id.removesuffix("/render")


def _account_savings(summary: BuildSummary, images, cached_render: set[str]) -> None:
    """Seconds the build did not spend: rejected cameras that were never rendered, scenes loaded
    once per arrangement instead of once per view, and cached renders."""
    if not images:
        return
    mean_render = sum(im.render_seconds for im, _ in images) / len(images)
    per_arr: dict[int, list] = {}
    for im, _ in images:
        per_arr.setdefault(im.arr, []).append(im)
    reuse = sum((len(v) - 1) * float(v[0].stats.get("load_seconds", 0.0)) for v in per_arr.values())
    cache = sum(im.render_seconds for im, path in images if path.name in cached_render)
    summary.saved = {
        "visibility_precheck": round(summary.cameras_rejected * mean_render - summary.rejected_seconds, 2),
        "scene_loaded_once_per_arrangement": round(reuse, 2),
        "cache": round(cache, 2),
    }
    summary.glossy_bounces_skipped = sum(1 for im, _ in images if im.stats.get("glossy_skipped"))
    summary.error_control = error_control_summary([im.stats for im, _ in images])


def error_control_summary(stats: list[dict]) -> dict[str, Any]:
    """Samples and estimated error against target over the images rendered to an error target."""
    got = [s for s in stats if "error_target" in s]  # a target of 0 too: an image without noise
    if not got:
        return {}
    samples = np.array([s["samples"] for s in got], float)
    ratio = error_ratio([s["error_estimate"] for s in got], [s["error_target"] for s in got])
    return {"images": len(got),
            "samples": {"median": float(np.median(samples)), "p95": float(np.percentile(samples, 95)),
                        "max": int(samples.max())},
            "error_ratio": {"median": round(float(np.median(ratio)), 4), "p95": round(float(np.percentile(ratio, 95)), 4)},
            "within_10_percent": round(float(np.mean(ratio <= 1.1)), 4)}


def write_manifest(graph: JobGraph, out: Path, arr_jobs) -> None:
    """Job id -> key of every job with a finished result: a failed or never-run job is absent, so
    a diff against a complete build shows it as removed."""
    store = Store(out)
    done = {s: store.keys(s) for s in STAGES}
    jobs: dict[str, dict[str, str]] = {s: {} for s in STAGES}
    for a, views, renders in arr_jobs:
        for j in (a, *views, *renders):
            if j.key in done[j.stage]:
                jobs[j.stage][j.id] = j.key
    manifest = {
        "specsynth": metadata.version("specsynth"),
        "spec": str(graph.spec_path),
        "spec_hash": keys.digest(graph.spec.model_dump(mode="json")),
        "backend": graph.backend,
        "stage_inputs": graph.stage_inputs,
        "stage_digests": graph.stage_digests,
        "jobs": jobs,
    }
    write_json(out / ".specsynth" / "manifest.json", manifest, indent=None)
    lock = {
        "seed": graph.spec.seed,
        "seed_rule": "numpy SeedSequence(entropy=seed, spawn_key=sha256(job id) as uint32 words)",
        "assets": graph.asset_hashes,
        "arrangement_seeds": {a.id: a.seed for a, _, _ in arr_jobs},
        "stage_digests": graph.stage_digests,
    }
    write_json(out / "specsynth.lock", lock)


# ---------------------------------------------------------------------- diff


def manifest_of(graph: JobGraph) -> dict[str, Any]:
    """The manifest a complete build of ``graph`` would write, for diffing specs without building
    (every camera counted as accepted: which are rejected is known only after the view stage)."""
    jobs: dict[str, dict[str, str]] = {s: {} for s in STAGES}
    for j in graph.jobs():
        jobs[j.stage][j.id] = j.key
    return {"stage_inputs": graph.stage_inputs, "jobs": jobs, "backend": graph.backend}


def read_manifest(out: Path) -> dict[str, Any]:
    p = Path(out) / ".specsynth" / "manifest.json"
    if not p.is_file():
        raise FileNotFoundError(f"{out}: not a specsynth output folder (no .specsynth/manifest.json)")
    try:
        return json.loads(p.read_bytes())
    except ValueError as e:
        raise FileNotFoundError(f"{p}: unreadable manifest ({type(e).__name__}); rebuild to rewrite it") from None


def diff(a: dict[str, Any], b: dict[str, Any]) -> dict[str, Any]:
    """Per stage added/removed/modified/unchanged, each modification attributed to its causes."""
    result: dict[str, Any] = {}
    upstream_of = {"view": "arrange", "render": "view"}
    causes_by_stage: dict[str, list[str]] = {}
    for stage in STAGES:
        ia, ib = a["stage_inputs"].get(stage, {}), b["stage_inputs"].get(stage, {})
        changed = sorted(k for k in set(ia) | set(ib) if ia.get(k) != ib.get(k))
        ja, jb = a["jobs"].get(stage, {}), b["jobs"].get(stage, {})
        added = sorted(set(jb) - set(ja))
        removed = sorted(set(ja) - set(jb))
        common = set(ja) & set(jb)
        modified = sorted(j for j in common if ja[j] != jb[j])
        causes = list(changed)
        if modified and stage in upstream_of and result.get(upstream_of[stage], {}).get("modified"):
            causes.append(f"upstream:{upstream_of[stage]}")
        causes_by_stage[stage] = causes
        result[stage] = {
            "added": len(added),
            "removed": len(removed),
            "modified": len(modified),
            "unchanged": len(common) - len(modified),
            "causes": causes if (modified or added or removed) else [],
            "changed_inputs": {k: [ia.get(k), ib.get(k)] for k in changed},
        }
    result["identical"] = all(
        result[s]["added"] == result[s]["removed"] == result[s]["modified"] == 0 for s in STAGES
    )
    return result
