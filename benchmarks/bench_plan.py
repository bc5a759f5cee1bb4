"""Time and peak memory of `specsynth plan` for a spec with a million images (issue: < 30 s, < 2 GB).

    .venv/bin/python benchmarks/bench_plan.py
"""

from __future__ import annotations

import resource
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from conftest import write_bop_models  # noqa: E402

from specsynth.plan.compiler import compile_spec  # noqa: E402
from specsynth.run.build import plan  # noqa: E402
from specsynth.spec.yamlio import load_spec  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

with tempfile.TemporaryDirectory() as d:
    models = write_bop_models(Path(d) / "models", 15)
    t0 = time.perf_counter()
    graph = compile_spec(load_spec(ROOT / "specs/lmo_pbr_h.yaml", [f"objects.path={models}", "arrangements.count=5000"]))
    p = plan(graph, Path(d) / "out")
    dt = time.perf_counter() - t0
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"images: {p['stages']['view']['jobs']:,}  plan seconds: {dt:.1f}  peak RSS: {rss:.0f} MiB")
