"""Markdown tables of `specsynth compare` results, for docs/realism.md.

Side by side, each statistic's distance (in real spreads) per column and the medians:

    python scripts/compare_table.py "0.1=cmp0/compare.json" "now=cmp1/compare.json"

The realism goals against a base result (each appearance distance at most half of the base's;
edge and texture density within 25 % of the real images' medians):

    python scripts/compare_table.py --goals cmp0/compare.json cmp1/compare.json
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

DENSITIES = ("edge_density", "texture_density")


def side_by_side(columns: list[tuple[str, dict]]) -> list[str]:
    last = columns[-1][1]["statistics"]
    lines = ["| statistic | " + " | ".join(name for name, _ in columns) + " | real median | synthetic median (last column) |",
             "|---" * (len(columns) + 3) + "|"]
    for stat, entry in last.items():
        cells = [f"{r['statistics'][stat]['distance']:.2f}" if stat in r["statistics"] else "" for _, r in columns]
        real, synth = entry["real"]["median"], entry["synthetic"]["median"]
        lines.append(f"| `{stat}` | " + " | ".join(cells) + f" | {real:.3g} | {synth:.3g} |")
    lines.append("| coverage | " + " | ".join(f"{r['coverage']['value'] * 100:.0f} %" for _, r in columns) + " | | |")
    return lines


def goals(base: dict, now: dict) -> list[str]:
    lines = ["| goal | base | goal value | now | met |", "|---|---|---|---|---|"]
    for stat, entry in now["statistics"].items():
        if entry["group"] != "appearance" or stat not in base["statistics"]:
            continue
        b, n = base["statistics"][stat]["distance"], entry["distance"]
        lines.append(f"| `{stat}` distance ≤ half the base's | {b:.2f} | ≤ {b / 2:.2f} | {n:.2f} | "
                     f"{'yes' if n <= b / 2 else 'no'} |")
    for stat in DENSITIES:
        real, synth = (now["statistics"][stat][side]["median"] for side in ("real", "synthetic"))
        b = base["statistics"][stat]["synthetic"]["median"]
        off = synth / real - 1
        lines.append(f"| `{stat}` median within 25 % of the real {real:.3f} | {b:.3f} | "
                     f"{0.75 * real:.3f}–{1.25 * real:.3f} | {synth:.3f} ({off:+.0%}) | {'yes' if abs(off) <= 0.25 else 'no'} |")
    return lines


def main(argv: list[str]) -> None:
    if argv[:1] == ["--goals"]:
        base, now = (json.loads(Path(p).read_text()) for p in argv[1:3])
        print("\n".join(goals(base, now)))
        return
    columns = [(name, json.loads(Path(path).read_text())) for name, path in (a.split("=", 1) for a in argv)]
    print("\n".join(side_by_side(columns)))


if __name__ == "__main__":
    main(sys.argv[1:])
