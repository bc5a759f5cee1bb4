"""``specsynth compare`` of a large synthetic split against the real LM-O split: time and memory.

    .venv/bin/python benchmarks/bench_compare.py out/demo --images 1000 10000 [--jobs 2]

For each size, a BOP split of that many images is made by repeating the images of a built
dataset (``SYNTH``'s ``bop/<split>``) as hard links, 1000 per scene folder as a build writes them,
with their annotations (``scene_gt``, ``scene_camera``, ``scene_gt_info``, visible masks) under new
image ids; then ``specsynth compare SPLIT dataset:lmo/test --json --own-masks`` runs as its own
process (the synthetic split's own masks: measuring it alike, with the annotated objects alone as
occluders as the real split's masks are, adds about 0.1 s per synthetic image once). Reported:
wall seconds, and the peak resident memory of the compare process and of its largest worker
(``getrusage`` of the children; the pool's workers are its children). Goal (issue #33): 10,000
synthetic images against the 200 real ones in <= 60 s on 2 cores, memory flat in the number of
images. The real split's masks are computed once and cached before the first timed run.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CHUNK = 1000


def _source(synth: Path) -> tuple[Path, list[tuple[Path, int]]]:
    """The built split's folder and its (scene folder, image id) pairs."""
    splits = [p for p in (synth / "bop").iterdir() if p.is_dir() and p.name != "models"]
    split = sorted(splits)[0]
    pairs = [(scene, int(k)) for scene in sorted(p for p in split.iterdir() if p.is_dir())
             for k in json.loads((scene / "scene_gt.json").read_text())]
    return split, pairs


def make_split(synth: Path, n: int, dest: Path) -> Path:
    """A BOP dataset at ``dest`` whose split holds ``n`` images repeating ``synth``'s."""
    split, pairs = _source(synth)
    out = dest / "bop" / split.name
    cache: dict[Path, tuple[dict, dict, dict]] = {}
    for chunk_start in range(0, n, CHUNK):
        scene_out = out / f"{chunk_start // CHUNK:06d}"
        for sub in ("rgb", "mask_visib"):
            (scene_out / sub).mkdir(parents=True)
        gt, cam, info = {}, {}, {}
        for im_id in range(chunk_start, min(n, chunk_start + CHUNK)):
            scene, src_id = pairs[im_id % len(pairs)]
            if scene not in cache:
                cache[scene] = tuple(json.loads((scene / f).read_text())
                                     for f in ("scene_gt.json", "scene_camera.json", "scene_gt_info.json"))
            sgt, scam, sinfo = cache[scene]
            key = str(im_id)
            gt[key], cam[key], info[key] = sgt[str(src_id)], scam[str(src_id)], sinfo[str(src_id)]
            rgb = next((scene / "rgb").glob(f"{src_id:06d}.*"))
            os.link(rgb, scene_out / "rgb" / f"{im_id:06d}{rgb.suffix}")
            for k in range(len(sgt[str(src_id)])):
                os.link(scene / "mask_visib" / f"{src_id:06d}_{k:06d}.png",
                        scene_out / "mask_visib" / f"{im_id:06d}_{k:06d}.png")
        for name, d in (("scene_gt.json", gt), ("scene_camera.json", cam), ("scene_gt_info.json", info)):
            (scene_out / name).write_text(json.dumps(d))
    for f in ("camera.json",):
        (dest / "bop" / f).write_bytes((synth / "bop" / f).read_bytes())
    os.symlink((synth / "bop" / "models").resolve(), dest / "bop" / "models")
    return out


def measure(split: Path, jobs: int) -> tuple[float, float, float]:
    code = ("import json, resource, sys, time\n"
            "from specsynth.cli import main\n"
            f"t = time.perf_counter(); rc = main(['compare', {str(split)!r}, 'dataset:lmo/test', '--json', '--jobs', '{jobs}', '--own-masks'])\n"
            "w = time.perf_counter() - t\n"
            "print(json.dumps([rc, w, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss,"
            " resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss]), file=sys.stderr)\n")
    t0 = time.perf_counter()
    res = subprocess.run([sys.executable, "-c", code], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    wall = time.perf_counter() - t0
    rc, _, self_kb, child_kb = json.loads(res.stderr.strip().splitlines()[-1])
    if rc != 0:
        raise SystemExit(f"compare failed ({rc}) on {split}")
    return wall, self_kb / 1024, child_kb / 1024


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("synth", type=Path, help="a build's --out folder")
    ap.add_argument("--images", type=int, nargs="+", default=[1000, 10000])
    ap.add_argument("--jobs", type=int, default=2)
    args = ap.parse_args()
    subprocess.run([sys.executable, "-m", "specsynth.cli", "compare", "dataset:lmo/test", "dataset:lmo/test", "--json"],
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)  # real masks cached
    print("| synthetic images | wall s (whole process) | peak RSS MiB: compare process | largest worker |")
    print("|---|---|---|---|")
    for n in args.images:
        with tempfile.TemporaryDirectory(dir=args.synth.parent) as d:
            split = make_split(args.synth, n, Path(d))
            wall, main_mb, worker_mb = measure(split, args.jobs)
            print(f"| {n:,} | {wall:.1f} | {main_mb:.0f} | {worker_mb:.0f} |", flush=True)


if __name__ == "__main__":
    main()
