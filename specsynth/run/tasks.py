"""What a worker process runs: the task functions executors call, and the process's set-up.

Work arrives grouped per arrangement so the expensive state (assets, pyrender scene, the
renderer's scene) is built once per arrangement and only the camera moves. A process keeps one
``Steps`` per build, made when it starts (``init_worker``): the three steps (``arrange.ArrangeStep``,
``views.ViewStep``, ``render.RenderStep``), each built on its first job from its own stage's inputs,
over the state they share (``worker.py``). Renderers are found by name through entry points, never
imported here.
"""

from __future__ import annotations

import os
import time
from functools import cached_property

from threadpoolctl import threadpool_limits

from .. import notices
from ..plan.compiler import Job
from ..spec.models import Intrinsics
from .arrange import ArrangeStep
from .render import RenderStep
from .reports import Arranged, Rendered, Viewed
from .store import Store
from .views import ViewStep
from .worker import BuildContext, Held, World


class Steps:
    """One build's steps in this process, each built on its first job from its own stage's inputs,
    over what they share: the store, the world the arrangement inputs rebuild, and the annotator
    of each image size (a view group and the renders of its arrangement load it once)."""

    def __init__(self, ctx: BuildContext):
        self.ctx = ctx
        self.store = Store(ctx.out)
        self.world = World(ctx.inputs.arrange, ctx.spec_dir)
        self._annotators: dict[tuple[int, int], Held] = {}
        # One BLAS thread: our products are 4x4 poses and Nx3 vertex arrays, too small to gain from
        # threads, and an idle OpenBLAS thread spins in sched_yield after every call. Measured on a
        # photo build: 28 CPU-s in 19 s of wall with numpy's default 2 threads, 17.5 in 17.5 with 1;
        # with two workers that spinning is taken from the other worker. Undone by ``close``.
        self._blas = threadpool_limits(limits=1, user_api="blas")

    def annotator(self, intrinsics: Intrinsics) -> Held:
        size = (intrinsics.width, intrinsics.height)
        if size not in self._annotators:
            from ..annotate.engine import Annotator

            self._annotators[size] = Held(lambda: Annotator(*size))
        return self._annotators[size]

    @cached_property
    def arrange(self) -> ArrangeStep:
        return ArrangeStep(self.ctx.inputs.arrange, self.world, self.store)

    @cached_property
    def views(self) -> ViewStep:
        inputs = self.ctx.inputs.view
        return ViewStep(inputs, self.world, self.annotator(inputs.intrinsics), self.store)

    @cached_property
    def render(self) -> RenderStep:
        inputs = self.ctx.inputs.render
        return RenderStep(inputs, self.world, self.annotator(inputs.intrinsics), self.store,
                          spec_dir=self.ctx.spec_dir, threads=self.ctx.threads)

    def close(self) -> None:
        if "render" in self.__dict__:  # built: its backend and albedo raster hold GL or a renderer
            self.render.close()
        for held in self._annotators.values():
            held.close()
        self._blas.restore_original_limits()


# Steps per output folder, created by the pool initializer (or a Dask WorkerPlugin): the warm
# renderer must outlive a job, and one Dask worker process may serve several builds at once.
_workers: dict[str, Steps] = {}


def die_with_parent(parent: int) -> None:
    """Ask Linux to kill this process when ``parent``, the build that started it, dies
    (PR_SET_PDEATHSIG): a build killed with SIGKILL otherwise leaves its pool workers rendering
    for minutes."""
    import ctypes
    import signal

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL, 0, 0, 0)  # PR_SET_PDEATHSIG = 1
    except (OSError, AttributeError):
        return  # not Linux: workers then exit when their task pipe closes
    if os.getppid() != parent:  # the build died while this worker started: nobody will signal it
        os._exit(1)


# What a worker process was told while it started (before any job): sent back with its first job.
_startup_notices: list[notices.Notice] = []


def init_pool_worker(ctx: BuildContext, parent: int) -> None:
    """Initializer of the local pool's worker processes. Ctrl-C is the build's to handle: it stops
    the pool; a worker interrupted mid-job would only print a traceback."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})  # blocked by the parent while it spawned us
    die_with_parent(parent)
    with notices.Collector() as c:
        init_worker(ctx)
    _startup_notices.extend(c.notices)


def init_worker(ctx: BuildContext) -> None:
    # Renderers must not oversubscribe the cores the pool already splits between workers: OpenMP
    # (Blender, OIDN) and Mesa's llvmpipe (annotation engine, photo backend) read these before
    # their first context is created in this process.
    if ctx.threads:
        os.environ["OMP_NUM_THREADS"] = str(ctx.threads)
        os.environ["LP_NUM_THREADS"] = str(ctx.threads)
    os.environ["OPENBLAS_NUM_THREADS"] = "1"  # BLAS libraries loaded later (see Steps._blas)
    old = _workers.get(str(ctx.out))
    if old is not None:
        old.close()
    _workers[str(ctx.out)] = Steps(ctx)


def available_cores() -> int:
    """Cores this process may run on: a container or a batch system may give fewer than cpu_count."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # pragma: no cover - non-Linux
        return os.cpu_count() or 1


def current_worker(out: str) -> Steps:
    try:
        return _workers[str(out)]
    except KeyError:
        raise RuntimeError(f"worker not initialised for {out}") from None


def close_worker(out: str) -> None:
    w = _workers.pop(str(out), None)
    if w is not None:
        w.close()


def timed(fn, *args):
    """Run a task; (worker seconds, result, (worker pid, start as epoch seconds), notices), so a
    build can say where worker time went, draw its timeline, and report once what the libraries
    and asset readers warned about (``specsynth.notices``) instead of each worker printing it."""
    start, t0 = time.time(), time.perf_counter()
    with notices.Collector() as c:
        res = fn(*args)
    told = [*_startup_notices, *c.notices]
    _startup_notices.clear()
    return time.perf_counter() - t0, res, (os.getpid(), start), told


# Each step was built from its own stage's inputs (``specsynth.plan.inputs``), never the whole spec.
def task_arrange(out: str, job: Job) -> Arranged:
    return current_worker(out).arrange.run(job)


def task_views(out: str, arrange_key: str, jobs: list[Job]) -> list[Viewed]:
    return current_worker(out).views.run(arrange_key, jobs)


def task_renders(out: str, arrange_key: str, pairs: list[tuple[Job, Job]]) -> list[Rendered]:
    return current_worker(out).render.run(arrange_key, pairs)
