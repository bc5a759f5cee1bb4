"""The build's scheduler: pipelined stages, priority, completion order, retries and splits."""

from __future__ import annotations

import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor

from specsynth.run.schedule import Call, run_calls


class Inline:
    """The executor protocol run in the calling thread (what ``--jobs 1`` does)."""

    workers = 1

    def submit(self, fn, *args) -> Future:
        f: Future = Future()
        try:
            f.set_result(fn(*args))
        except Exception as e:
            f.set_exception(e)
        return f


def _pipeline(ex, n_arr: int, log: list, work=lambda stage, arr: None, window: int = 2):
    def job(stage, arr):
        work(stage, arr)
        log.append((stage, arr))
        return stage

    def on_done(c: Call, res):
        nxt = {"arrange": "view", "view": "render"}.get(c.stage)
        return [Call(job, (nxt, c.arr), nxt, f"{nxt}{c.arr}", 1, c.arr)] if nxt else []

    calls = [Call(job, ("arrange", i), "arrange", f"a{i}", 1, i) for i in range(n_arr)]
    run_calls(ex, calls, on_done, lambda c, e: [], window=window, retries=0)


def test_arrangements_settle_first_then_each_flows_to_its_renders():
    log: list = []
    _pipeline(Inline(), 4, log)
    assert sorted(log) == sorted((s, i) for s in ("arrange", "view", "render") for i in range(4))
    # physics (the long, unpredictable job) never ends the build; then an arrangement's render
    # goes before the next arrangement's view
    assert log[:4] == [("arrange", i) for i in range(4)]
    # window 2: arr 0 and 1's views are in flight together; then arr 0's render jumps the queue
    assert log[4:7] == [("view", 0), ("view", 1), ("render", 0)]
    assert all(log.index(("render", i)) < log.index(("view", i + 2)) for i in range(2))


def test_results_are_taken_as_they_finish_not_in_submission_order():
    """A long arrange of arrangement 0 must not hold back arrangement 1's later stages."""
    log: list = []
    gate = threading.Event()

    def work(stage, arr):
        if (stage, arr) == ("arrange", 0):
            gate.wait(10)

    def release_when_1_rendered(stage, arr):
        work(stage, arr)
        if (stage, arr) == ("render", 1):
            gate.set()

    with ThreadPoolExecutor(2) as ex:
        t0 = time.perf_counter()
        _pipeline(ex, 2, log, release_when_1_rendered, window=4)
    assert time.perf_counter() - t0 < 10, "arrangement 1 waited behind arrangement 0"
    assert log.index(("render", 1)) < log.index(("arrange", 0))


def test_retry_then_split_then_report():
    tries: dict = {}
    failed, done = [], []

    def group(ids):
        for i in ids:
            tries[i] = tries.get(i, 0) + 1
            if i == "bad":
                raise ValueError("bad job")
        return ids

    c = Call(group, (["a", "bad", "b"],), "view", "g", 3, 0)

    def split(c):
        (ids,) = c.args
        return None if len(ids) < 2 else [Call(group, ([i],), c.stage, i, 1, c.arr) for i in ids]

    run_calls(Inline(), [c], lambda c, r: done.append(r[1]) or [], lambda c, e: failed.append((c.ident, str(e))) or [],
         window=2, retries=1, split=split)
    assert failed == [("bad", "bad job")]
    assert sorted(map(tuple, done)) == [("a",), ("b",)]
    assert tries["bad"] == 2 + 2  # the group twice (one retry), then alone twice


def test_build_splits_view_and_render_groups_but_not_arrangements():
    """An arrangement call (args: worker key, job) that keeps failing is reported, not unpacked
    as a group (that raised inside the scheduler and stopped the whole build)."""
    from types import SimpleNamespace as Job

    from specsynth.run.schedule import split_group

    arrange = Call(print, ("w", Job(id="arr=000000")), "arrange", "arr=000000", 1, 0)
    assert split_group(arrange) is None
    a, b = Job(id="arr=000000/cam=000"), Job(id="arr=000000/cam=001")
    parts = split_group(Call(print, ("w", "key", [a, b]), "view", "arr=000000", 2, 0))
    assert [(c.args, c.n, c.ident) for c in parts] == [(("w", "key", [a]), 1, a.id), (("w", "key", [b]), 1, b.id)]
    assert split_group(Call(print, ("w", "key", [a]), "view", a.id, 1, 0)) is None


def test_an_arrangements_renders_stay_on_one_worker_until_the_builds_last_ones(monkeypatch):
    """A worker keeps the scene it loaded: an arrangement's renders go to one worker together
    while other arrangements are still to come; the build's last ``workers - 1`` are split, one
    render per call when renders are dear, in groups sharing the workers when they are cheap."""
    from specsynth.run import schedule

    graph = object()
    for estimate in (2.0, 0.1):
        monkeypatch.setattr(schedule, "render_estimate", lambda g, s=estimate: s)
        for workers in (1, 2, 4):
            for to_come in range(6):
                split = 1 if estimate >= schedule.SINGLE_RENDER_SECONDS else -(-6 // workers)
                expected = 6 if to_come >= workers - 1 else split
                assert schedule.render_chunk(graph, 6, workers, to_come) == expected
    assert schedule.render_chunk(graph, 20, 2, 5) == schedule.RENDER_CHUNK


def test_a_build_loads_each_arrangement_on_fewer_workers(monkeypatch):
    """Two threads as workers, each keeping the scene it last loaded (as a build's worker keeps
    its RenderCall): four arrangements of four dear renders load 4 or 5 scenes, not up to 8."""
    from specsynth.run import schedule

    monkeypatch.setattr(schedule, "render_estimate", lambda g: 2.0)
    loads, kept = [], threading.local()

    def render(arr, n):
        if getattr(kept, "arr", None) != arr:
            kept.arr = arr
            loads.append(arr)
        time.sleep(0.002 * n)

    queued: set[int] = set()

    def on_done(c: Call, res):
        if c.stage != "arrange":
            return []
        queued.add(c.arr)
        size = schedule.render_chunk(None, 4, 2, 4 - len(queued))
        return [Call(render, (c.arr, size), "render", f"r{c.arr}/{k}", size, c.arr) for k in range(0, 4, size)]

    calls = [Call(lambda: None, (), "arrange", f"a{i}", 1, i) for i in range(4)]
    with ThreadPoolExecutor(2) as ex:
        run_calls(ex, calls, on_done, lambda c, e: [], window=2, retries=0)
    assert sorted(set(loads)) == [0, 1, 2, 3]
    assert len(loads) <= 5  # arrangements 0-2 once each; the last one on one or both workers
