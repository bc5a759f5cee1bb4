"""Throughput of one build with 1 and 2 local workers and a 2-worker Dask LocalCluster, and the
per-job overhead of each executor (a no-op job's round trip).

    .venv/bin/python benchmarks/bench_executors.py [--arrangements 12]

The spec is the demo's cameras with the photo backend at 320x240 (physics, visibility, annotation
and rendering all run in the workers). Goal (issue): >= 1.8x one worker with two.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

from specsynth.backend_api import load_executor
from specsynth.build import build
from specsynth.compiler import compile_spec
from specsynth.tasks import BuildContext
from specsynth.yamlio import load_spec

ROOT = Path(__file__).resolve().parents[1]


def overhead(name: str, jobs: int, ctx: BuildContext, n: int = 200) -> float:
    ex = load_executor(name)(ctx, jobs=jobs)
    try:
        [f.result() for f in [ex.submit(os.getpid) for _ in range(10)]]  # warm
        t0 = time.perf_counter()
        for _ in range(n):
            ex.submit(os.getpid).result()
        return (time.perf_counter() - t0) / n
    finally:
        ex.shutdown()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--arrangements", type=int, default=12)
    args = ap.parse_args()
    overrides = [f"arrangements.count={args.arrangements}", "backend={name: photo}",
                 "intrinsics={width: 320, height: 240, fx: 286.2, fy: 286.8, cx: 162.4, cy: 120.8}"]
    graph = compile_spec(load_spec(ROOT / "specs/demo.yaml", overrides))
    rows = []
    with tempfile.TemporaryDirectory() as d:
        ctx = BuildContext(spec=graph.spec, spec_dir=graph.spec_path.parent, out=Path(d) / "ctx")
        for label, executor, jobs in (("local, 1 worker", "local", 1), ("local, 2 workers", "local", 2),
                                      ("dask LocalCluster, 2 workers", "dask", 2)):
            t0 = time.perf_counter()
            s = build(graph, Path(d) / label.replace(" ", "_").replace(",", ""), executor=executor, jobs=jobs)
            wall = time.perf_counter() - t0
            assert not s.failures, s.failures
            rows.append((label, wall, s.images, overhead(executor, jobs, ctx)))
    base = rows[0][1]
    print(f"{graph.n_arrangements} arrangements, {rows[0][2]} images, photo backend at 320x240, {os.cpu_count()} cores")
    print("| executor | wall s | images / min | speed-up | overhead per job (no-op round trip) |")
    print("|---|---|---|---|---|")
    for label, wall, images, ov in rows:
        print(f"| {label} | {wall:.1f} | {60 * images / wall:.1f} | {base / wall:.2f}x | {1000 * ov:.2f} ms |")


if __name__ == "__main__":
    main()
