"""Contact sheet of every built-in scene and of random_room for a few seeds (the README's picture).

    .venv/bin/python scripts/scene_sheet.py --out docs/images/scenes.jpg [--backend cycles] [--samples 16]

Each tile is `specsynth scenes preview NAME --no-stages --denoise` (the overview camera), labelled.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from PIL import Image, ImageDraw

from specsynth.scenes import PROCEDURAL, builtin_scenes
from specsynth.views.preview import preview_scene


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="docs/images/scenes.jpg")
    ap.add_argument("--backend", default=None)
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--seeds", type=int, nargs="*", default=[1, 2, 3])
    ap.add_argument("--cols", type=int, default=4)
    a = ap.parse_args()
    tiles = [(n, None) for n in builtin_scenes() if n not in PROCEDURAL] + [("random_room", s) for s in a.seeds]
    w, h = a.width, a.width * 3 // 4
    rows = -(-len(tiles) // a.cols)
    sheet = Image.new("RGB", (a.cols * w, rows * h), (20, 20, 20))
    with tempfile.TemporaryDirectory() as tmp:
        for k, (name, seed) in enumerate(tiles):
            png = Path(tmp) / f"{k}.png"
            preview_scene(name, a.backend, png, width=w, height=h, samples=a.samples, variant=seed, stages=False,
                          denoise=True)
            im = Image.open(png).convert("RGB")
            label = name if seed is None else f"{name} seed {seed}"
            ImageDraw.Draw(im).rectangle((0, 0, 7 * len(label) + 8, 14), fill=(0, 0, 0))
            ImageDraw.Draw(im).text((4, 1), label, fill=(255, 255, 255))
            sheet.paste(im, ((k % a.cols) * w, (k // a.cols) * h))
            print(f"{label}: done", flush=True)
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    sheet.save(a.out, quality=88)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
