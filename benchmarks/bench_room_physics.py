"""Physics on furnished rooms: the arrange step of `specs/demo.yaml` (random_room, its objects and
distractors) over N arrangements, timing `physics.arrange` alone (the room is assembled first,
untimed) and counting the scene triangles given to Bullet.

    .venv/bin/python benchmarks/bench_room_physics.py [--arrangements 20] [--all-colliders]

`--all-colliders` gives Bullet every collider triangle of the room, as before the colliders were
cut to the stage's neighbourhood (`physics.collider_region`), for comparison. Triangles are
counted as `_World.add_collider` receives them.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from specsynth import physics
from specsynth.assets import meshio
from specsynth.plan import seeds
from specsynth.plan.compiler import compile_spec
from specsynth.plan.inputs import BuildInputs
from specsynth.run.tasks import Steps
from specsynth.run.worker import BuildContext
from specsynth.spec.yamlio import load_spec

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--arrangements", type=int, default=20)
    ap.add_argument("--all-colliders", action="store_true")
    args = ap.parse_args()
    graph = compile_spec(load_spec(ROOT / "specs/demo.yaml", [f"arrangements.count={args.arrangements}"]))
    spec = graph.spec
    seconds: list[float] = []
    outcomes: list[physics.ArrangeResult] = []
    faces = [0, 0]  # given to Bullet, in the rooms' colliders
    real_arrange, real_add = physics.arrange, physics._World.add_collider

    def timed_arrange(*a, **k):
        t0 = time.perf_counter()
        try:
            result = real_arrange(*a, **k)
            outcomes.append(result)
            return result
        finally:
            seconds.append(time.perf_counter() - t0)

    def counted_add(world, v, f):
        faces[0] += len(f)
        return real_add(world, v, f)

    physics.arrange, physics._World.add_collider = timed_arrange, counted_add
    if args.all_colliders:
        physics.box_meets_region = lambda box, region: True
        physics.faces_in_region = lambda v, f, region: f
    with tempfile.TemporaryDirectory() as out:
        steps = Steps(BuildContext(inputs=BuildInputs.of(spec), spec_dir=graph.spec_path.parent, out=Path(out)))
        results = []
        for arr in range(graph.n_arrangements):
            job, _, _ = graph.arrangement_jobs(arr)
            room = steps.world.scene(spec.scenes[0], seeds.job_seed(spec.seed, f"{job.id}/scene"))  # assembled, untimed
            faces[1] += sum(len(meshio.read_mesh(m.mesh_path).faces) for m in room.collider_meshes())
            results.append(steps.arrange.run(job))
        steps.close()
    print(f"{len(seconds)} arrangements of specs/demo.yaml, {'all' if args.all_colliders else 'near-stage'} colliders")
    print(f"physics.arrange s: median {statistics.median(seconds):.3f}, p90 {np.percentile(seconds, 90):.3f}, "
          f"max {max(seconds):.3f}, total {sum(seconds):.2f}")
    sim = [r.sim_seconds for r in outcomes]
    print(f"settled {sum(r.settled for r in outcomes)} of {len(outcomes)}; simulated s: median "
          f"{statistics.median(sim):.2f}, max {max(sim):.2f}, total {sum(sim):.1f}")
    print(f"collider triangles given to Bullet: {faces[0]:,} of {faces[1]:,} ({100 * faces[0] / max(faces[1], 1):.0f} %)")
    print(f"objects kept {sum(r.objects for r in results)}, removed {sum(r.removed for r in results)}, "
          f"re-dropped {sum(r.redropped for r in results)}")


if __name__ == "__main__":
    main()
