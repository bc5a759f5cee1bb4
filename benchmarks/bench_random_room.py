"""Assembling ``random_room`` rooms in one worker: seconds per room and memory over many rooms.

    .venv/bin/python benchmarks/bench_random_room.py [--rooms 200] [--spec specs/lmo_pbr_h.yaml]

Each room is what an arrangement loads: the generator (catalogue draw, placement, re-dressing),
furniture unpacked and converted once into the cache (the first rooms pay for new models), the
normalised meshes, and the stages found. The worker keeps the last two rooms
(``specsynth.run.worker.PROCEDURAL_KEPT``); this loop does the same. Reported: the first room, the
median and 90th percentile of the rest, the share of furniture models already in the cache by
the end, and the resident memory after rooms 10, 50, 100, ... (RSS from /proc). With ``--spec``,
the rooms of that spec's first scene (its room kinds, clutter and stages), else the default kinds.
"""

from __future__ import annotations

import argparse
import statistics
import time
import warnings
from pathlib import Path


def rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rooms", type=int, default=200)
    ap.add_argument("--spec", help="take the scene reference (kinds, clutter, stages) from this spec's first scene")
    args = ap.parse_args()
    from specsynth.scenes import load_scene
    from specsynth.spec.yamlio import load_spec

    ref = load_spec(Path(args.spec)).spec.scenes[0] if args.spec else "random_room"

    warnings.simplefilter("ignore")
    kept: list = []
    seconds, rss = [], {}
    for k in range(args.rooms):
        t0 = time.perf_counter()
        kept.append(load_scene(ref, Path("."), variant=1000 + k, clearance=0.7))
        seconds.append(time.perf_counter() - t0)
        kept = kept[-2:]
        if (k + 1) in (10, 50, 100, 150, 200, 300, 500) or k + 1 == args.rooms:
            rss[k + 1] = rss_mb()
    rest = sorted(seconds[1:])
    print("| rooms | first s | median s | p90 s | max s |\n|---|---|---|---|---|")
    print(f"| {args.rooms} | {seconds[0]:.2f} | {statistics.median(rest):.2f} | {rest[int(0.9 * len(rest))]:.2f} | {rest[-1]:.2f} |")
    slowest = sorted(range(1, len(seconds)), key=seconds.__getitem__)[-3:][::-1]
    print("slowest rooms (variant: s): " + ", ".join(f"{1000 + k}: {seconds[k]:.2f}" for k in slowest))
    print("\n| after room | RSS MB |\n|---|---|")
    for n, mb in rss.items():
        print(f"| {n} | {mb:.0f} |")


if __name__ == "__main__":
    main()
