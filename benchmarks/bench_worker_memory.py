"""Resident memory of one build worker over many renders (issue #19: flat within +10 % over 500).

    .venv/bin/python benchmarks/bench_worker_memory.py --renders 500 [--backend cycles] [--scene room]

Builds a small spec (160 x 120, `low`, 4 cameras per arrangement, the given scene) with one worker
process, and samples the resident memory (VmRSS) of the build's whole process tree every second,
with the number of render records in the store at that moment. Prints RSS after every tenth of
the renders and the growth from the first tenth to the end.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

SPEC = """\
name: memory
seed: 3
intrinsics: {{width: 160, height: 120, fx: 143.1, fy: 143.4, cx: 81.3, cy: 60.5}}
objects: {{builtin: [duck, mug, teddy, lego]}}
scenes: [{{name: {scene}}}]
arrangements: {{count: {arrangements}}}
cameras: {{per_arrangement: 4}}
quality: {{level: low}}
backend: {{name: {backend}, denoise: true}}
outputs: {{image_format: jpg}}
"""


def tree_rss_mb(pid: int) -> float:
    """VmRSS of a process and all its descendants, MB."""
    total, todo = 0.0, [pid]
    while todo:
        p = todo.pop()
        try:
            for line in Path(f"/proc/{p}/status").read_text().splitlines():
                if line.startswith("VmRSS:"):
                    total += float(line.split()[1]) / 1024
            for child in Path(f"/proc/{p}/task").iterdir():
                kids = (child / "children").read_text().split()
                todo += [int(k) for k in kids]
        except (FileNotFoundError, ProcessLookupError):
            continue
    return total


def renders_done(out: Path) -> int:
    root = out / ".specsynth" / "store" / "render"
    return sum(1 for _ in root.glob("*/*/record.json")) if root.is_dir() else 0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--renders", type=int, default=500)
    ap.add_argument("--backend", default="cycles")
    ap.add_argument("--scene", default="room")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        spec = Path(tmp) / "memory.yaml"
        spec.write_text(SPEC.format(scene=a.scene, arrangements=-(-a.renders // 4), backend=a.backend))
        out = Path(tmp) / "out"
        cli = Path(sys.executable).parent / "specsynth"
        proc = subprocess.Popen([str(cli), "build", str(spec), "--out", str(out), "--jobs", "1", "--quiet"],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        samples, t0 = [], time.time()
        while proc.poll() is None:
            samples.append((renders_done(out), tree_rss_mb(proc.pid)))
            time.sleep(1.0)
        wall = time.time() - t0
    done = max(n for n, _ in samples)
    print(f"{done} renders ({a.backend}, {a.scene}, 160x120 low) in {wall:.0f} s, one worker\n")
    print("| renders done | RSS of the build, MB |\n|---|---|")
    marks = [round(done * k / 10) for k in range(1, 11)]
    rows = []
    for m in marks:
        at = [rss for n, rss in samples if n >= m]
        if at:
            rows.append((m, at[0]))
            print(f"| {m} | {at[0]:.0f} |")
    if len(rows) >= 2:
        first, last = rows[0][1], rows[-1][1]
        print(f"\ngrowth from {rows[0][0]} to {rows[-1][0]} renders: {100 * (last - first) / first:+.1f} %")


if __name__ == "__main__":
    main()
