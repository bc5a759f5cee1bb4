"""Executor plugins (entry-point group ``specsynth.executors``): how jobs reach workers.

Protocol: ``Executor(ctx, jobs=N, address=None)``, ``submit(fn, *args) -> concurrent.futures.Future``,
``shutdown()``. ``fn`` is a module-level function of ``specsynth.run.tasks`` that runs on a worker
whose state was set up by ``specsynth.run.tasks.init_worker(ctx)``. A worker process must run its jobs
one at a time and always on the same thread: a renderer's scene (bpy's) is process-wide, and
OpenGL contexts (annotation, the photo backend) belong to the thread that made them current.
"""
