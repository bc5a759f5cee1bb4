"""The arrange step: draw a stage, objects and distractors from the job's seed, drop them with
physics, store the arrangement record (with the credits of everything it shows)."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..assets.resolve import ObjectAsset, catalogue_objects
from ..model.records import ArrangementRecord, PlacedObject
from ..plan import seeds
from ..plan.compiler import Job
from ..plan.inputs import ArrangeInputs
from ..scenes import procedural_name
from ..spec.models import SceneRef
from .worker import Worker


def run_arrange(w: Worker, inp: ArrangeInputs, job: Job) -> dict[str, Any]:
    """Settle one arrangement (cached when its record exists) -> a summary for the build."""
    from ..physics import arrange

    if w.store.has("arrange", job.key):
        return {"id": job.id, "cached": True}
    index, rng = seeds.scene_draw(inp.seed, job.id, [s.weight for s in inp.scenes])
    ref = inp.scenes[index]
    variant = seeds.job_seed(inp.seed, f"{job.id}/scene") if procedural_name(ref) else None
    scene = w.scene(ref, variant)
    names = list(scene.stages) if ref.stages else sorted(scene.stages)  # the scene holds the ones asked for
    stage = scene.stages[names[draw_stage([scene.stages[n].weight for n in names], rng)]]

    models = w.assets()
    if inp.objects.models_per_arrangement is not None:
        lo, hi = inp.objects.models_per_arrangement
        k = min(int(rng.integers(lo, hi + 1)), len(models))
        chosen = sorted(rng.choice(len(models), size=k, replace=False))
        models = [models[i] for i in chosen]
    lo, hi = inp.objects.instances
    drop: list[ObjectAsset] = []
    for m in models:
        drop += [m] * int(rng.integers(lo, hi + 1))

    distractors = w.distractor_assets(draw_distractors(inp.arrangements.distractors, rng))
    result = arrange(scene, stage, drop + distractors, inp.arrangements, inp.objects.orientation, rng)
    targets = [(i, pose) for i, pose in result.placed if i < len(drop)]
    placed = [
        PlacedObject(obj_id=drop[i].obj_id, inst=n, name=drop[i].name, pose=np.asarray(pose).tolist())
        for n, (i, pose) in enumerate(targets)
    ]
    others = [
        PlacedObject(obj_id=0, inst=n, name=distractors[i - len(drop)].name, pose=np.asarray(pose).tolist())
        for n, (i, pose) in enumerate((i, pose) for i, pose in result.placed if i >= len(drop))
    ]
    if inp.arrangements.distractors.annotate:  # objects like the others, after them in gt order
        n_obj = len(w.assets())
        placed += [PlacedObject(obj_id=inp.arrangements.distractors.obj_id(o.name, n_obj), inst=len(placed) + k,
                                name=o.name, pose=o.pose) for k, o in enumerate(others)]
        others = []
    rec = ArrangementRecord(
        arr=job.arr, scene=ref.ref if variant is None else f"{ref.ref}#{variant}", stage=stage.name,
        objects=placed, dropped=len(drop), removed=result.removed, redropped=result.redropped,
        settled=result.settled, sim_seconds=result.sim_seconds, seed=job.seed,
        credits=list(scene.credits) + [a.credit for a in models if a.credit]
        + [a.credit for a in {d.name: d for d in distractors}.values() if a.credit],
        distractors=others,
    )
    rec.credits += swapped_credits(w, rec, ref)
    w.store.put("arrange", job.key, rec.to_json())
    return {"id": job.id, "removed": rec.removed, "redropped": rec.redropped, "objects": len(placed)}


def draw_stage(weights: list[float], rng) -> int:
    """A stage's index, by weight; uniform (one integer draw, as before weights) when all are equal."""
    if len(set(weights)) <= 1:
        return int(rng.integers(len(weights)))
    p = np.asarray(weights, np.float64)
    return int(rng.choice(len(p), p=p / p.sum()))


def swapped_credits(w: Worker, rec: ArrangementRecord, ref: SceneRef) -> list[dict]:
    """Credits of the library textures that randomisation puts into this arrangement's scene
    (exactly what its renders will show: the same function of the same seed)."""
    if not ref.randomize.materials:
        return []
    from ..assets.library import textures
    from ..assets.library.cache import cache_dir

    by_path = {str(t.path): t for t in textures.available(cache_dir())}
    used = sorted({m.material.texture for m in w.render_scene(rec).meshes if m.material.texture in by_path})
    return [by_path[t].credit for t in used]


def draw_distractors(d, rng: np.random.Generator) -> list[str]:
    """The built-in objects dropped as distractors in one arrangement: each uniform over the named
    ones and the members of the wildcards (pybullet_data's 1000 random shapes, the library's small
    items)."""
    lo, hi = d.count
    n = int(rng.integers(lo, hi + 1)) if hi > 0 else 0
    pool = [o for o in d.objects if not o.endswith("/*")]
    wild = "random_urdfs/*" in d.objects
    catalogue = catalogue_objects() if "catalogue/*" in d.objects else []
    out = []
    for _ in range(n):
        k = int(rng.integers(len(pool) + (1000 if wild else 0) + len(catalogue)))
        if k < len(pool):
            out.append(pool[k])
        elif wild and k < len(pool) + 1000:
            out.append(f"random_urdfs/{k - len(pool):03d}")
        else:
            out.append(catalogue[k - len(pool) - (1000 if wild else 0)])
    return out
