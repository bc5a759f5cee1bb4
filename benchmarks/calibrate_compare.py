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
from specsynth.compare.collect import collect
from specsynth.compare.comparison import STATISTICS, _column, compare
from specsynth.compare.gtinfo import complete
from specsynth.compare.split import open_split


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
    ims = real.images
    parts = {"interleaved": (ims[0::2], ims[1::2]), "halves": (ims[: len(ims) // 2], ims[len(ims) // 2:])}
    measured = {k: (collect(replace(real, images=a)), collect(replace(real, images=b))) for k, (a, b) in parts.items()}
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
