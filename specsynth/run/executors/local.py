"""The default executor: a local pool of spawned processes, one warm backend per worker.

``--jobs 1`` runs jobs in the calling process (same code path, no start-up cost). Results do not
depend on the number of workers: every job's output is a function of its inputs and seed only.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import threading
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager

from .. import tasks


@contextmanager
def deaf_children():
    """SIGINT blocked in this thread while the pool starts workers (it does so in ``submit``):
    they inherit the mask through exec, so a Ctrl-C to the terminal's process group cannot
    interrupt one in its imports and print its traceback. The build's own process still gets
    the signal (another of its threads takes it) and stops the pool; a worker sets SIGINT to be
    ignored and unblocks it once started (:func:`.tasks.init_pool_worker`)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


class LocalExecutor:
    def __init__(self, ctx: tasks.BuildContext, *, jobs: int = 1, address: str | None = None):
        self.workers = max(1, int(jobs))
        # The machine's cores split between the workers (one worker: all of them).
        self._ctx = ctx.with_threads(tasks.available_cores() // self.workers) if self.workers > 1 else ctx
        self._pool = None
        if self.workers == 1:
            tasks.init_worker(ctx)
        else:
            self._pool = self._new_pool()

    def _new_pool(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(
            max_workers=self.workers,
            mp_context=mp.get_context("spawn"),
            initializer=tasks.init_pool_worker,
            initargs=(self._ctx, os.getpid()),
        )

    def submit(self, fn, *args) -> Future:
        if self._pool is not None:
            with deaf_children():
                try:
                    return self._pool.submit(fn, *args)
                except BrokenProcessPool:
                    # A worker died (e.g. a renderer segfault): replace the pool; the build's retry
                    # logic re-submits the jobs that have no finished result.
                    self._pool.shutdown(wait=False, cancel_futures=True)
                    self._pool = self._new_pool()
                    return self._pool.submit(fn, *args)
        fut: Future = Future()
        try:
            fut.set_result(fn(*args))
        except BaseException as e:  # surfaced through the future, as a pool would
            fut.set_exception(e)
        return fut

    def shutdown(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
        else:
            tasks.close_worker(str(self._ctx.out))

