"""Throughput of one build with 1 and 2 local workers and a 2-worker Dask LocalCluster, and the
per-job overhead of each executor (a no-op job's round trip).

    .venv/bin/python benchmarks/bench_executors.py [--arrangements 24] [--backend photo]

The spec is the demo's cameras with the photo backend at 320x240 (physics, visibility, annotation
and rendering all run in the workers). Every build runs in a fresh process, timed from its start
(process and worker start-up included), at N and 2N arrangements: the end-to-end rate is what one
build of that size gets; the marginal rate (extra images / extra seconds between the two sizes)
is the steady state a long build runs at, with the once-per-build costs (start-up, imports, the
merge's fixed part) cancelled out. The machine's own ceiling is measured too: the same CPU-bound
work in one process, then in two processes at once. Goal (issue): >= 1.8x one worker with two.
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


def _spin(n: int) -> float:
    import numpy as np

    t0 = time.perf_counter()
    a = np.random.default_rng(0).random((300, 300))
    acc = 0
    for i in range(n):  # interpreter-bound and numpy-bound (single-threaded: no BLAS) work
        acc += i % 7
        if i % 2000 == 0:
            a = np.tanh(a * 1.01 + 0.1)
    return time.perf_counter() - t0


def machine_ceiling(n: int = 3_000_000) -> float:
    """Speed-up of two independent CPU-bound processes over one on this machine."""
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    with ctx.Pool(1) as p:
        alone = p.apply(_spin, (n,))
    with ctx.Pool(2) as p:
        both = [r.get() for r in [p.apply_async(_spin, (n,)) for _ in range(2)]]
    return 2 * alone / max(both)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--arrangements", type=int, default=24, help="N: builds of N and 2N arrangements")
    ap.add_argument("--backend", default="photo", help="photo (physics/annotation-bound) or cycles (render-bound)")
    args = ap.parse_args()
    common = [f"backend={{name: {args.backend}}}", "intrinsics={width: 320, height: 240, fx: 286.2, fy: 286.8, cx: 162.4, cy: 120.8}"]
    graph = compile_spec(load_spec(ROOT / "specs/demo.yaml", common))
    rows = []
    with tempfile.TemporaryDirectory() as d:
        ctx = BuildContext(spec=graph.spec, spec_dir=graph.spec_path.parent, out=Path(d) / "ctx")
        spec = Path(d) / "spec.yaml"
        spec.write_text((ROOT / "specs/demo.yaml").read_text())
        for label, executor, jobs, threads, copies in (
            ("local, 1 worker, 1 thread", "local", 1, 1, 1),
            ("local, 1 worker, 2 threads", "local", 1, 2, 1),
            ("local, 2 workers x 1 thread", "local", 2, 1, 1),
            ("dask LocalCluster, 2 workers x 1 thread", "dask", 2, 1, 1),
            # No scheduler at all: the workload's own ceiling on this machine.
            ("two independent 1-worker builds at once", "local", 1, 1, 2),
        ):
            if args.backend != "photo" and "2 threads" in label:
                continue
            runs = []
            for n in (args.arrangements, 2 * args.arrangements):
                outs = [Path(d) / f"{label.replace(' ', '_').replace(',', '')}_{n}_{c}" for c in range(copies)]
                overrides = [*common, f"arrangements.count={n}"]
                t0 = time.perf_counter()  # a fresh process each: thread counts are read once per process
                procs = [subprocess.Popen([sys.executable, "-m", "specsynth.cli", "build", str(spec), "--out", str(out), "--quiet",
                                           "--executor", executor, "--jobs", str(jobs), "--threads", str(threads),
                                           *[a for o in overrides for a in ("--set", o)]],
                                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) for out in outs]
                logs = [p.communicate()[0] for p in procs]
                runs.append((time.perf_counter() - t0, sum(len(list(out.glob("bop/*/*/rgb/*"))) for out in outs)))
                assert all(p.returncode == 0 for p in procs), logs
            (w1, i1), (w2, i2) = runs
            rows.append((label, w1, i1, w2, i2, 60 * (i2 - i1) / (w2 - w1), overhead(executor, jobs, ctx) if copies == 1 else None))
    ceiling = machine_ceiling()
    base, base_m = rows[0][4] / rows[0][3], rows[0][5]
    print(f"{args.backend} backend at 320x240, builds of {args.arrangements} and {2 * args.arrangements} arrangements "
          f"({rows[0][2]} and {rows[0][4]} images), {os.cpu_count()} cores; two independent CPU-bound processes "
          f"on this machine: {ceiling:.2f}x one")
    print("| executor | wall s (N / 2N) | images / min, 2N end to end | speed-up, end to end | images / min, marginal | "
          "speed-up, marginal | overhead per job (no-op round trip) |")
    print("|---|---|---|---|---|---|---|")
    for label, w1, i1, w2, i2, marginal, ov in rows:
        print(f"| {label} | {w1:.1f} / {w2:.1f} | {60 * i2 / w2:.0f} | {i2 / w2 / base:.2f}x | {marginal:.0f} | "
              f"{marginal / base_m:.2f}x | {'—' if ov is None else f'{1000 * ov:.2f} ms'} |")


if __name__ == "__main__":
    main()
