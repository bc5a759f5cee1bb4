"""Executor plugins (entry-point group ``specsynth.executors``): how jobs reach workers.

Protocol: ``Executor(ctx, jobs=N, address=None)``, ``submit(fn, *args) -> concurrent.futures.Future``,
``shutdown()``. ``fn`` is a module-level function of ``specsynth.tasks`` that runs on a worker
whose state was set up by ``specsynth.tasks.init_worker(ctx)``.
"""
