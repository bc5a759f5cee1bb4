"""Running a compiled graph: build orchestration, worker tasks, executors, the content-addressed store, bench."""
