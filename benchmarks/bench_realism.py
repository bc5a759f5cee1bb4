"""How much of a dataset's background looks like a real room: textured tiles and distinct hues.

    .venv/bin/python benchmarks/bench_realism.py out/demo out/demo_bl [...]

For every image of each BOP output folder, the background is every pixel outside all objects'
full masks. Measured over the background, pooled over the images:

- textured tiles: the fraction of 8 x 8 pixel tiles wholly in the background whose luminance
  (0-255, Rec. 709 weights on the sRGB values) has a standard deviation above ``--std`` (4 by
  default: flat paint under smooth light stays below it, wood grain, tiles, bricks, fabric and
  clutter go above);
- distinct hues: the number of 15-degree hue bins (of 24) holding at least 1 % of the background
  pixels that are coloured at all (HSV saturation > 0.15, value > 0.1).

A photo-baseline build (``specs/demo_bl.yaml``) measures real photographs this way, because its
backgrounds are scikit-image's photographs.
"""

from __future__ import annotations

import argparse
import colorsys
from pathlib import Path

import numpy as np
from PIL import Image


def background_masks(chunk: Path, im_id: int, shape) -> np.ndarray:
    bg = np.ones(shape, bool)
    for m in sorted((chunk / "mask").glob(f"{im_id:06d}_*.png")):
        bg &= ~(np.asarray(Image.open(m)) > 0)
    return bg


def measure(out: Path, std_threshold: float) -> dict[str, float]:
    tiles = textured = 0
    hue_counts = np.zeros(24)
    coloured = 0
    images = 0
    for rgb_path in sorted(Path(out).glob("bop/*/*/rgb/*")):
        chunk = rgb_path.parent.parent
        rgb = np.asarray(Image.open(rgb_path).convert("RGB")).astype(np.float64)
        bg = background_masks(chunk, int(rgb_path.stem), rgb.shape[:2])
        lum = rgb @ np.array([0.2126, 0.7152, 0.0722])
        h8, w8 = (rgb.shape[0] // 8) * 8, (rgb.shape[1] // 8) * 8
        t_lum = lum[:h8, :w8].reshape(h8 // 8, 8, w8 // 8, 8).transpose(0, 2, 1, 3).reshape(-1, 64)
        t_bg = bg[:h8, :w8].reshape(h8 // 8, 8, w8 // 8, 8).transpose(0, 2, 1, 3).reshape(-1, 64).all(1)
        tiles += int(t_bg.sum())
        textured += int((t_lum[t_bg].std(1) > std_threshold).sum())
        px = rgb[bg] / 255.0
        mx, mn = px.max(1), px.min(1)
        sat = np.where(mx > 0, (mx - mn) / np.maximum(mx, 1e-9), 0)
        keep = (sat > 0.15) & (mx > 0.1)
        hues = np.array([colorsys.rgb_to_hsv(*p)[0] for p in px[keep][:: max(1, keep.sum() // 20000)]])
        if len(hues):
            hue_counts += np.bincount((hues * 24).astype(int) % 24, minlength=24) * (keep.sum() / len(hues))
        coloured += int(keep.sum())
        images += 1
    distinct = int((hue_counts >= 0.01 * max(coloured, 1)).sum())
    return {"images": images, "textured_tiles": textured / max(tiles, 1), "distinct_hues": distinct}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("outs", nargs="+", type=Path)
    ap.add_argument("--std", type=float, default=4.0)
    args = ap.parse_args()
    print("| build | images | background tiles with texture | distinct hues |\n|---|---|---|---|")
    for out in args.outs:
        r = measure(out, args.std)
        print(f"| {out} | {r['images']} | {100 * r['textured_tiles']:.0f} % | {r['distinct_hues']} |")


if __name__ == "__main__":
    main()
