"""One build's run: which calls follow which (an arrangement's views when it has settled, its
renders when its views are known), the bookkeeping of what ran, and the timeline."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

from .. import notices
from ..assets.resolve import ObjectAsset
from ..plan.compiler import STAGES, JobGraph
from .reports import Arranged, Rendered
from .schedule import Call, group_id, render_chunk
from .store import Store, write_json
from .summary import BuildSummary


class Pipeline:
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
        self.renders_queued: set[int] = set()  # arrangements whose render calls are made
        self.spans: list[tuple[str, str, int, int, float, float, dict]] = []  # stage, call, jobs, pid, start, seconds, args
        self.cached_render: set[str] = set()
        # What the workers reported: each job's record as stored, by (stage, key), and the models
        # they resolved (the spec's objects; annotated distractors by obj_id), for the merge.
        self.records: dict[tuple[str, str], dict[str, Any]] = {}
        self.models: tuple[ObjectAsset, ...] = ()
        self.distractor_models: dict[int, ObjectAsset] = {}
        self.bars = {s: prog.add_task(s, total=0) for s in STAGES}

    def record(self, stage: str, key: str) -> dict[str, Any] | None:
        """A finished job's record: as its worker reported it, else the store's (a job cached
        before this build, or one a retry found done); None for a job without one."""
        found = self.records.get((stage, key))
        if found is None and self.store.has(stage, key):
            found = self.store.load(stage, key)
        return found

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
            vrec = self.record("view", v.key)
            if vrec is None:  # its view job failed
                continue
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
        self.renders_queued.add(i)
        size = render_chunk(self.graph, len(todo), self.workers, len(self.arr_jobs) - len(self.renders_queued))
        chunks = [todo[k:k + size] for k in range(0, len(todo), size)]
        return [Call(self.tasks["render"], (self.wkey, a.key, c), "render", group_id(c[0]), len(c), i) for c in chunks]

    def _view_resolved(self, i: int, n: int) -> list[Call]:
        self.views_left[i] -= n
        return self.render_calls(i) if self.views_left[i] == 0 else []

    def on_done(self, c: Call, res) -> list[Call]:
        seconds, result, (pid, start), told = res
        notices.record(told)
        self.keep(c.stage, result if isinstance(result, list) else [result])
        args = self.render_phases(result) if c.stage == "render" else {}
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

    def keep(self, stage: str, reports: list) -> None:
        for r in reports:
            if r.record is not None:
                self.records[(stage, r.key)] = r.record
            if isinstance(r, Arranged) and r.models:
                self.models = r.models
                self.distractor_models.update((a.obj_id, a) for a in r.distractors)

    def render_phases(self, result: list[Rendered]) -> dict[str, float]:
        """One render call's worker-seconds by phase, added to the build's."""
        args: dict[str, float] = {}
        for r in result:
            for k, v in r.phases.items():
                args[k] = args.get(k, 0.0) + v
        phases = self.summary.render_phases
        for k, v in args.items():
            phases[k] = round(phases.get(k, 0.0) + v, 4)
        return args

    def on_error(self, c: Call, e: BaseException) -> list[Call]:
        if self.log is not None:
            self.log(f"{c.stage} {c.ident}: {c.n} job(s) failed: {type(e).__name__}: {e}")
        self.summary.stages[c.stage].failed += c.n
        self.summary.failures.append({"stage": c.stage, "job": c.ident, "error": f"{type(e).__name__}: {e}",
                                      "tries": c.runs})
        if c.stage == "arrange":
            self.renders_queued.add(c.arr)  # no renders will come: not one to wait for (render_chunk)
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
