"""Physics on the built-in scenes, through the real arrange stage: CPU seconds per arrangement of
15 LM-sized built-in objects and the rate of removed / re-dropped objects, per scene.

    .venv/bin/python benchmarks/bench_arrange_scenes.py --n 200 [--scenes room kiva room2] [--objects lmo]

Goal (issue): <= 1 s CPU per arrangement of 15 objects. Objects: duck, mug, teddy, lego, jenga,
torus, the 4 toys and 5 random_urdfs, one instance each, canonical orientation, drops of 5-50 cm
on a stage chosen at random per arrangement (kiva: RU-APC style, 1-5 instances of 3 models in
random orientation, because a bin holds ~0.05 m^2). ``--objects lmo``: the 8 real LM-O models
(scanned meshes; ``make install`` unpacks them), one instance each, canonical, as specs/lmo_*.yaml.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from specsynth.plan.compiler import compile_spec
from specsynth.run.tasks import Steps
from specsynth.run.worker import BuildContext
from specsynth.spec.yamlio import load_spec

OBJECTS = ["duck", "mug", "teddy", "lego", "jenga", "torus", "toys/cube", "toys/cylinder", "toys/prism",
           "toys/shape_sorter", "random_urdfs/000", "random_urdfs/001", "random_urdfs/002", "random_urdfs/003",
           "random_urdfs/004"]


def spec_text(scene: str, n: int, lmo: bool = False) -> str:
    objects = f"  builtin: {OBJECTS}\n  orientation: canonical\n"
    if lmo:
        objects = "  path: dataset:lmo/models\n  orientation: canonical\n"
    elif scene == "kiva":
        objects = f"  builtin: {OBJECTS}\n  orientation: random\n  instances: [1, 5]\n  models_per_arrangement: [3, 3]\n"
    return (f"name: bench_{scene}\nseed: 1\nobjects:\n{objects}scenes:\n  - name: {scene}\n"
            f"arrangements:\n  count: {n}\nbackend:\n  name: photo\n")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=200)
    ap.add_argument("--scenes", nargs="*", default=["room", "kiva", "room2"])
    ap.add_argument("--objects", choices=["builtin", "lmo"], default="builtin")
    args = ap.parse_args()
    print("| scene | arrangements | objects dropped | CPU s / arrangement (mean, median, p90) | removed | re-dropped |")
    print("|---|---|---|---|---|---|")
    for scene in args.scenes:
        with tempfile.TemporaryDirectory() as d:
            f = Path(d) / "s.yaml"
            f.write_text(spec_text(scene, args.n, lmo=args.objects == "lmo"))
            graph = compile_spec(load_spec(f))
            steps = Steps(BuildContext(inputs=graph.inputs, spec_dir=Path(d), out=Path(d) / "out"))
            steps.world.assets()  # asset conversion is not physics
            for a in range(min(2, args.n)):  # scene load and collision shapes are per-process costs
                steps.world.scene(graph.spec.scenes[0])
            cpu, dropped, removed, redropped, slow = [], 0, 0, 0, []
            for arr in range(args.n):
                job = graph.arrange_job(arr)
                t0 = time.process_time()
                steps.arrange.run(job)
                cpu.append(time.process_time() - t0)
                rec = steps.store.load("arrange", job.key)
                dropped += rec["dropped"]
                removed += rec["removed"]
                redropped += rec["redropped"]
                slow.append((cpu[-1], arr, rec["stage"], rec["sim_seconds"], rec["redropped"], rec["settled"]))
            steps.close()
            cpu_sorted = sorted(cpu)
            p90 = cpu_sorted[int(0.9 * (len(cpu) - 1))]
            print(f"| {scene} | {args.n} | {dropped} | {statistics.mean(cpu):.2f}, {statistics.median(cpu):.2f}, {p90:.2f} "
                  f"| {removed} ({100 * removed / max(1, dropped):.1f} %) | {redropped} ({100 * redropped / max(1, dropped):.1f} %) |",
                  flush=True)
            for t, arr, stage, sim, red, settled in sorted(slow, reverse=True)[:3]:
                print(f"  slowest: arr {arr} {t:.1f} CPU s, stage {stage}, {sim:.2f} simulated s, {red} re-dropped, "
                      f"{'settled' if settled else 'not settled'}")


if __name__ == "__main__":
    main()
