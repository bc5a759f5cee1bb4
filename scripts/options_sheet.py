"""Contact sheet of the camera/sensor options and extra outputs, side by side (the README's picture).

    .venv/bin/python scripts/options_sheet.py --out docs/images/options.jpg

One view of the `kitchen` scene built with Cycles plain and with each camera option: every extra
output (RGB, albedo, normals, NOCS, depth), a `sensor:` block (noisy RGB and depth), a distorting
lens (with its visible masks' outlines), depth of field, motion blur, and the right eye of a
stereo pair.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from specsynth.plan.compiler import compile_spec
from specsynth.run.build import build
from specsynth.spec.yamlio import load_spec

SPEC = """\
name: options
seed: 4
intrinsics: {width: 320, height: 240, fx: 286.0, fy: 286.0, cx: 159.5, cy: 119.5}
objects: {builtin: [duck, mug, jenga, teddy]}
scenes: [{name: kitchen}]
arrangements: {count: 1}
cameras: {per_arrangement: 1, distance: [0.5, 0.8]}
backend: {name: cycles, denoise: true}
outputs: {image_format: png, normals: true, nocs: true, albedo: true}
"""
SENSOR = ["sensor={shot_noise: 0.04, read_noise: 0.01, exposure: [0.5, 0.5], white_balance: [4000, 4000], "
          "depth: {axial_noise: [0.002, 0.004], edge_holes: 2, dropout: 0.02}}"]
LENS = ["intrinsics.distortion=[-0.35, 0.12, 0.0, 0.0, 0.0]"]
DOF = ["cameras.depth_of_field={aperture: [30, 30]}", "backend.samples=16"]
MOTION = ["cameras.motion_blur={shutter: 0.05, speed: [0.5, 0.5], rotation: [5, 5]}", "backend.samples=16"]
STEREO = ["cameras.stereo={baseline: 0.1}"]


def _outlined(rgb: np.ndarray, chunk: Path) -> np.ndarray:
    out = rgb[..., :3].copy()
    for f in sorted((chunk / "mask_visib").glob("000000_*.png")):
        m = np.asarray(Image.open(f)) > 0
        out[m ^ np.roll(m, 1, 0) | m ^ np.roll(m, 1, 1)] = (0, 255, 0)
    return out


def _exr(path: Path) -> np.ndarray:
    import OpenEXR

    with OpenEXR.File(str(path)) as f:
        return np.asarray(f.channels()["RGB"].pixels, dtype=np.float32)


def _grey(depth: np.ndarray, hi: float) -> np.ndarray:
    g = np.clip(depth / hi, 0, 1) * 255
    return np.repeat(g[..., None], 3, axis=2).astype(np.uint8)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="docs/images/options.jpg")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        spec = Path(tmp) / "s.yaml"
        spec.write_text(SPEC)
        build(compile_spec(load_spec(spec)), Path(tmp) / "plain", jobs=1)
        build(compile_spec(load_spec(spec, SENSOR)), Path(tmp) / "sensor", jobs=1)
        for name, overrides in (("lens", LENS), ("dof", DOF), ("motion", MOTION), ("stereo", STEREO)):
            build(compile_spec(load_spec(spec, overrides)), Path(tmp) / name, jobs=1)
        c, s, ln, df, mo = (Path(tmp) / d / "bop" / "train_pbr" / "000000" for d in ("plain", "sensor", "lens", "dof", "motion"))
        right = Path(tmp) / "stereo" / "bop" / "train_pbr_right" / "000000"
        n = _exr(c / "normals" / "000000.exr")
        depth = np.asarray(Image.open(c / "depth" / "000000.png"), np.float64)
        tiles = [
            ("rgb", np.asarray(Image.open(c / "rgb" / "000000.png"))),
            ("sensor: noise, +0.5 EV, WB 4000 K", np.asarray(Image.open(s / "rgb" / "000000.png"))),
            ("albedo", np.asarray(Image.open(c / "albedo" / "000000.png"))),
            ("normals", ((n * 0.5 + 0.5) * 255 * (np.linalg.norm(n, axis=-1, keepdims=True) > 0)).astype(np.uint8)),
            ("nocs", (_exr(c / "nocs" / "000000.exr") * 255).astype(np.uint8)),
            ("depth", _grey(depth, depth.max())),
            ("sensor depth", _grey(np.asarray(Image.open(s / "depth_noisy" / "000000.png"), np.float64), depth.max())),
            ("lens k1 -0.35 k2 0.12, masks", _outlined(np.asarray(Image.open(ln / "rgb" / "000000.png")), ln)),
            ("depth of field, 30 mm pupil, 16 spp", np.asarray(Image.open(df / "rgb" / "000000.png"))),
            ("motion blur 0.5 m/s, 5 deg/s, 1/20 s, 16 spp", np.asarray(Image.open(mo / "rgb" / "000000.png"))),
            ("stereo: right eye, 10 cm", np.asarray(Image.open(right / "rgb" / "000000.png"))),
        ]
    w, h = tiles[0][1].shape[1], tiles[0][1].shape[0]
    cols = 4  # 12 tiles: 3 rows
    sheet = Image.new("RGB", (cols * w, -(-len(tiles) // cols) * h), (20, 20, 20))
    for k, (label, img) in enumerate(tiles):
        im = Image.fromarray(np.ascontiguousarray(img[..., :3]))
        ImageDraw.Draw(im).rectangle((0, 0, 6 * len(label) + 8, 13), fill=(0, 0, 0))
        ImageDraw.Draw(im).text((4, 1), label, fill=(255, 255, 255))
        sheet.paste(im, ((k % cols) * w, (k // cols) * h))
    Path(a.out).parent.mkdir(parents=True, exist_ok=True)
    sheet.save(a.out, quality=90)
    print(f"wrote {a.out}")


if __name__ == "__main__":
    main()
