"""Scheduling a build's calls: which jobs go to a worker together (``Call``, ``split_group``,
``render_chunk``) and the loop that keeps the executor busy (``run_calls``), with retries and
crash isolation. It knows stages and priorities, not what a step does with its jobs."""

from __future__ import annotations

import heapq
import itertools
import queue
from collections import deque
from dataclasses import dataclass
from typing import Any, Callable

from ..plan.compiler import STAGES, JobGraph
from ..plugins import PluginNotFound, backend_plugin

# Rough seconds per job on a 2-core machine (docs/performance.md), for `plan` estimates only.
EST_SECONDS = {"arrange": 0.5, "view": 0.08}


def _options(graph: JobGraph):
    """The spec's backend options with its level's calibration (the spec's own when the plugin is missing)."""
    options = graph.spec.backend
    try:
        return backend_plugin(options.name).options_for(options, graph.spec.quality)
    except PluginNotFound:
        return options


def render_estimate(graph: JobGraph) -> float:
    """Estimated seconds per render, from the backend plugin's own cost model: a frame of the
    image's pixels and its samples (the backends' rule, an explicit or calibrated `samples`, else
    max(AA, diffuse rays, specular rays)), times the pixels a supersampled render has per pixel."""
    try:
        a, b = backend_plugin(graph.spec.backend.name).cost
    except PluginNotFound:
        a, b = 1.0, 0.1
    options = _options(graph)
    return (a + b * (options.samples or graph.spec.quality.resolved().samples)) * options.supersample**2


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


def run_calls(ex, calls: list[Call], on_done: Callable[[Call, Any], list[Call]],
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
    return [Call(fn, (wk, key, [j]), c.stage, group_id(j), 1, c.arr) for j in group]


# Renders per call. A worker keeps the scene it loaded, so an arrangement whose renders are split
# between workers is loaded by each of them: with a furnished room that is ~2 s per worker (the
# demo's Cycles builds: 15.1 of 64.9 render worker-s went to 8 loads of 4 rooms), more than a
# `low` render. So an arrangement's renders go to one worker together (up to RENDER_CHUNK of them)
# while other arrangements are still to come and keep the other workers busy. The build's last
# ``workers - 1`` arrangements are split, so its end is not left to one worker with a long group
# while the others idle: into groups that share the workers when renders are cheap, one per call
# when a render is estimated to take SINGLE_RENDER_SECONDS or more.
RENDER_CHUNK = 8
SINGLE_RENDER_SECONDS = 0.5


def render_chunk(graph: JobGraph, n: int, workers: int, still_to_come: int = 0) -> int:
    """How many of an arrangement's ``n`` renders go in one call, when ``still_to_come``
    arrangements of the build have not queued their renders yet."""
    if still_to_come >= workers - 1:
        return max(1, min(RENDER_CHUNK, n))
    if render_estimate(graph) >= SINGLE_RENDER_SECONDS:
        return 1
    return max(1, min(RENDER_CHUNK, -(-n // workers)))


def group_id(item) -> str:
    """The arrangement of a view job or a (view, render) pair, plus the camera when alone."""
    job = item[1] if isinstance(item, tuple) else item
    return job.id.removesuffix("/render")
