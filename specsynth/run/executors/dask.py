"""Dask executor: the same jobs on an existing Dask cluster (``--executor dask://HOST:PORT``).

Workers write results straight into the shared content-addressed store under the output folder
(which must be on a filesystem every worker sees); only small summaries travel back. Each worker
process builds its warm state once, through a WorkerPlugin. Without an address, a LocalCluster
of ``--jobs`` single-threaded worker processes is started (useful for tests and one machine).
"""

from __future__ import annotations

import hashlib
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

from .. import tasks

CONFIG_DIR = Path(__file__).with_name("dask_config")  # Dask settings for workers (DASK_CONFIG)
JOB_EXECUTOR = "specsynth"  # the name of each worker's job thread among its Dask executors


def _plugin_class():
    from distributed.diagnostics.plugin import WorkerPlugin

    class WarmWorker(WorkerPlugin):
        def __init__(self, ctx: tasks.BuildContext):
            self.ctx = ctx
            # One plugin per output folder: builds sharing a cluster do not replace each other's.
            self.name = f"specsynth-warm-{hashlib.sha256(str(ctx.out).encode()).hexdigest()[:12]}"

        def setup(self, worker):
            # Every specsynth job of this worker process runs on one thread of its own (the
            # executor protocol: process-wide renderer, thread-bound OpenGL contexts), whatever
            # --nthreads the worker has; builds sharing the worker share that thread.
            if JOB_EXECUTOR not in worker.executors:
                worker.executors[JOB_EXECUTOR] = ThreadPoolExecutor(1, thread_name_prefix="specsynth-job")
            # Dask sets OMP_NUM_THREADS=1 in workers; renderers get an explicit count instead: the
            # worker's --nthreads (the cores it was given), unless the build passed --threads.
            tasks.init_worker(self.ctx.with_threads(worker.state.nthreads))

        def teardown(self, worker):
            # On the job thread: an OpenGL context is released by the thread that holds it.
            try:
                worker.executors[JOB_EXECUTOR].submit(tasks.close_worker, str(self.ctx.out)).result()
            except (KeyError, RuntimeError):  # the worker is closing and its job thread is gone
                tasks.close_worker(str(self.ctx.out))

    return WarmWorker


class DaskExecutor:
    def __init__(self, ctx: tasks.BuildContext, *, jobs: int = 1, address: str | None = None):
        try:
            from distributed import Client, LocalCluster
        except ImportError as e:  # pragma: no cover - depends on the environment
            raise ImportError("the dask executor needs: pip install 'specsynth[dask]'") from e
        self._cluster = None
        if address:
            self.client = Client(address if "://" in address else f"tcp://{address}")
        else:
            # Single-threaded Dask workers, the machine's cores split between them for rendering.
            ctx = ctx.with_threads(tasks.available_cores() // max(1, jobs))
            import dask
            import yaml

            # Logs below CRITICAL stay quiet: a job that fails is reported by the build itself, once,
            # where distributed's workers had logged every failed attempt with its traceback.
            with dask.config.set(_dotted(yaml.safe_load((CONFIG_DIR / "specsynth.yaml").read_text()))):
                self._cluster = LocalCluster(n_workers=max(1, jobs), threads_per_worker=1, processes=True,
                                             dashboard_address=None, silence_logs=50)
            self.client = Client(self._cluster)
        self._plugin = _plugin_class()(ctx)
        self.client.register_plugin(self._plugin)
        self.workers = max(1, len(self.client.scheduler_info().get("workers", {})) or jobs)

    def submit(self, fn, *args):
        import dask

        # pure=False: a retry must run again, not return a cached failure.
        with dask.annotate(executor=JOB_EXECUTOR):
            return self.client.submit(fn, *args, pure=False)

    def shutdown(self) -> None:
        if self._cluster is None:  # a shared cluster: leave its workers, drop this build's state
            try:
                self.client.unregister_worker_plugin(self._plugin.name)
            except Exception:  # older distributed, or already gone: the state is small
                pass
        self.client.close()
        if self._cluster is not None:
            self._cluster.close()


def _dotted(tree: dict, prefix: str = "") -> dict:
    """Nested settings as dotted keys: ``dask.config.set`` replaces whole subtrees given nested."""
    out = {}
    for k, v in tree.items():
        if isinstance(v, dict):
            out.update(_dotted(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out
