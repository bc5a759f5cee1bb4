"""Dask executor: the same jobs on an existing Dask cluster (``--executor dask://HOST:PORT``).

Workers write results straight into the shared content-addressed store under the output folder
(which must be on a filesystem every worker sees); only small summaries travel back. Each worker
process builds its warm state once, through a WorkerPlugin. Without an address, a LocalCluster
of ``--jobs`` single-threaded worker processes is started (useful for tests and one machine).
"""

from __future__ import annotations

import hashlib

from .. import tasks


def _plugin_class():
    from distributed.diagnostics.plugin import WorkerPlugin

    class WarmWorker(WorkerPlugin):
        def __init__(self, ctx: tasks.BuildContext):
            self.ctx = ctx
            # One plugin per output folder: builds sharing a cluster do not replace each other's.
            self.name = f"specsynth-warm-{hashlib.sha256(str(ctx.out).encode()).hexdigest()[:12]}"

        def setup(self, worker):
            # Dask sets OMP_NUM_THREADS=1 in workers; renderers get an explicit count instead.
            tasks.init_worker(self.ctx)

        def teardown(self, worker):
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
            self._cluster = LocalCluster(n_workers=max(1, jobs), threads_per_worker=1, processes=True,
                                         dashboard_address=None, silence_logs=40)
            self.client = Client(self._cluster)
        self._plugin = _plugin_class()(ctx)
        self.client.register_plugin(self._plugin)
        self.workers = max(1, len(self.client.scheduler_info().get("workers", {})) or jobs)

    def submit(self, fn, *args):
        # pure=False: a retry must run again, not return a cached failure.
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
