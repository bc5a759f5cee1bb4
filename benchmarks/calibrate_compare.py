"""Calibrate `specsynth compare`'s verdicts on real photographs: the real LM-O split against itself.

    .venv/bin/python benchmarks/calibrate_compare.py [--real dataset:lmo/test]

Splits the real images two ways, interleaved (even / odd images: the same scene, alternate
frames) and in halves (first / second: the camera moving round the desk), and prints every
statistic's normalised distance between the two parts, then the coverage of one part by the
other at several radii. The real set's own medians come first: docs/compare.md quotes them.
"""

from __future__ import annotations

import argparse
from dataclasses import replace

import numpy as np

from specsynth.compare import distance as dist
from specsynth.compare.collect import Collected, collect
from specsynth.compare.comparison import STATISTICS, _column, compare
from specsynth.compare.gtinfo import complete
from specsynth.compare.split import open_split


SPLITS = {"interleaved": lambda i, n: i % 2 == 0, "halves": lambda i, n: i < n // 2}  # True: an image of the first part


def _part(c: Collected, first, side: bool) -> Collected:
    """One part of ``c``: the images ``first`` puts on ``side``, with their instances and objects."""
    keep = first(np.arange(c.n_images), c.n_images) == side
    return replace(c, images={k: v[keep] for k, v in c.images.items()},
                   instances={k: v[keep[c.instances["image"]]] for k, v in c.instances.items()},
                   objects={k: v[keep[c.objects["image"]]] for k, v in c.objects.items()}, n_images=int(keep.sum()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--real", default="dataset:lmo/test")
    args = ap.parse_args()
    real = complete(open_split(args.real))
    whole = collect(real)
    print("| statistic | median | 5-95 % |\n|---|---|---|")
    for name in STATISTICS:
        s = dist.summary(_column(whole, name))
        print(f"| `{name}` | {s['median']:.3g} | {s['p5']:.3g} - {s['p95']:.3g} |")
    measured = {k: (_part(whole, first, True), _part(whole, first, False)) for k, first in SPLITS.items()}
    print("\n| statistic | interleaved | halves |\n|---|---|---|")
    rows = {k: compare(a, b)["statistics"] for k, (a, b) in measured.items()}
    for name in STATISTICS:
        print(f"| `{name}` | {rows['interleaved'][name]['distance']:.2f} | {rows['halves'][name]['distance']:.2f} |")
    for k in rows:
        d = [e["distance"] for e in rows[k].values()]
        print(f"{k}: median {np.median(d):.2f}, max {np.max(d):.2f}")
    print("\n| radius | interleaved (both ways) | halves (both ways) |\n|---|---|---|")
    axes = dist.COVERAGE_AXES
    for r in (0.25, 0.5, 0.75, 1.0):
        cells = []
        for a, b in measured.values():
            pa, pb = (np.stack([c.instances[x] for x in axes], 1) for c in (a, b))
            sc = [dist.spread(whole.instances[x]) for x in axes]
            cells.append(f"{100 * dist.coverage(pa, pb, sc, r):.0f} %, {100 * dist.coverage(pb, pa, sc, r):.0f} %")
        print(f"| {r} | {cells[0]} | {cells[1]} |")


if __name__ == "__main__":
    main()
