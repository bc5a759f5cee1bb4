"""A sheet of real and synthetic images side by side: N of each, evenly spaced through each split,
at one scale (real rows first).

    python scripts/realism_sheet.py dataset:lmo/test out/lmo --n 16 --out docs/images/realism_lmo.jpg
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from specsynth.compare.split import open_split


def picks(ref: str, n: int) -> list[Path]:
    split = open_split(ref)
    chosen = set(np.linspace(0, split.n_images - 1, min(n, split.n_images)).round().astype(int).tolist())
    return [im.rgb for k, im in enumerate(split.iter_images()) if k in chosen]


def sheet(rows: list[tuple[str, list[Path]]], cols: int, width: int) -> Image.Image:
    height = width * 3 // 4
    label = 22
    tiles = [(name, files[i:i + cols]) for name, files in rows for i in range(0, len(files), cols)]
    out = Image.new("RGB", (cols * width, len(tiles) * (height + label)), (255, 255, 255))
    d = ImageDraw.Draw(out)
    shown = set()
    for r, (name, files) in enumerate(tiles):
        y = r * (height + label)
        if name not in shown:
            d.text((4, y + 4), name, fill=(0, 0, 0))
            shown.add(name)
        for c, f in enumerate(files):
            with Image.open(f) as im:
                out.paste(im.convert("RGB").resize((width, height), Image.BILINEAR), (c * width, y + label))
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("real")
    ap.add_argument("synth")
    ap.add_argument("--n", type=int, default=16)
    ap.add_argument("--cols", type=int, default=8)
    ap.add_argument("--width", type=int, default=240)
    ap.add_argument("--out", required=True)
    ap.add_argument("--labels", nargs=2, metavar=("REAL", "SYNTH"), help="row titles (default: the two arguments)")
    args = ap.parse_args()
    names = args.labels or (f"real: {args.real}", f"synthetic: {args.synth}")
    rows = [(names[0], picks(args.real, args.n)), (names[1], picks(args.synth, args.n))]
    sheet(rows, args.cols, args.width).save(args.out, quality=88)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
