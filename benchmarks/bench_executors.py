"""Throughput of one build with 1 and 2 local workers and a 2-worker Dask LocalCluster, and the
per-job overhead of each executor (a no-op job's round trip).

    .venv/bin/python benchmarks/bench_executors.py [--arrangements 12]

The spec is the demo's cameras with the photo backend at 320x240 (physics, visibility, annotation
and rendering all run in the workers). Every build runs in a fresh process, timed from its start
(process and worker start-up included). Goal (issue): >= 1.8x one worker with two.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from specsynth.backend_api import load_executor
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
    ap.add_argument("--backend", default="photo", help="photo (physics/annotation-bound) or cycles (render-bound)")
    args = ap.parse_args()
    overrides = [f"arrangements.count={args.arrangements}", f"backend={{name: {args.backend}}}",
                 "intrinsics={width: 320, height: 240, fx: 286.2, fy: 286.8, cx: 162.4, cy: 120.8}"]
    graph = compile_spec(load_spec(ROOT / "specs/demo.yaml", overrides))
    rows = []
    with tempfile.TemporaryDirectory() as d:
        ctx = BuildContext(spec=graph.spec, spec_dir=graph.spec_path.parent, out=Path(d) / "ctx")
        spec = Path(d) / "spec.yaml"
        spec.write_text((ROOT / "specs/demo.yaml").read_text())
        for label, executor, jobs, threads in (
            ("local, 1 worker, 1 thread", "local", 1, 1),
            ("local, 1 worker, 2 threads", "local", 1, 2),
            ("local, 2 workers x 1 thread", "local", 2, 1),
            ("dask LocalCluster, 2 workers x 1 thread", "dask", 2, 1),
        ):
            if args.backend != "photo" and "2 threads" in label:
                continue
            out = Path(d) / label.replace(" ", "_").replace(",", "")
            t0 = time.perf_counter()  # a fresh process each: thread counts are read once per process
            r = subprocess.run([sys.executable, "-m", "specsynth.cli", "build", str(spec), "--out", str(out), "--quiet",
                                "--executor", executor, "--jobs", str(jobs), "--threads", str(threads),
                                *[a for o in overrides for a in ("--set", o)]], capture_output=True, text=True)
            wall = time.perf_counter() - t0
            assert r.returncode == 0, r.stdout + r.stderr
            images = len(list(out.glob("bop/*/*/rgb/*")))
            rows.append((label, wall, images, overhead(executor, jobs, ctx)))
    base = rows[0][1]
    print(f"{graph.n_arrangements} arrangements, {rows[0][2]} images, {args.backend} backend at 320x240, {os.cpu_count()} cores")
    print("| executor | wall s | images / min | speed-up | overhead per job (no-op round trip) |")
    print("|---|---|---|---|---|")
    for label, wall, images, ov in rows:
        print(f"| {label} | {wall:.1f} | {60 * images / wall:.1f} | {base / wall:.2f}x | {1000 * ov:.2f} ms |")


if __name__ == "__main__":
    main()
