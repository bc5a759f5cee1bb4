"""The arrange step: draw a stage, objects and distractors from the job's seed, drop them with
physics, store the arrangement record (with the credits of everything it shows)."""

from __future__ import annotations

import colorsys

import numpy as np

from ..assets.resolve import ObjectAsset, catalogue_objects
from ..model.colour import srgb_to_linear
from ..model.records import ArrangementRecord, PlacedObject
from ..plan import seeds
from ..plan.compiler import Job
from ..plan.inputs import ArrangeInputs
from ..scenes import procedural_name
from ..spec.models import SceneRef
from .reports import Arranged
from .store import Store, stored
from .worker import World


class ArrangeStep:
    """Settles arrangements with its own inputs, into ``store``, over a ``world`` built from the
    same inputs (its resolved objects and loaded scenes are the views' and renders' too)."""

    def __init__(self, inputs: ArrangeInputs, world: World, store: Store):
        if world.inputs != inputs:
            raise ValueError("the arrange step's world must be built from its own inputs")
        self.inputs, self.world, self.store = inputs, world, store

    def run(self, job: Job) -> Arranged:
        """Settle one arrangement (cached when its record exists)."""
        if self.store.has("arrange", job.key):
            return Arranged(job.id, job.key, cached=True)
        rec = self.settle(job)
        self.store.put("arrange", job.key, rec.to_json())
        return Arranged(job.id, job.key, objects=len(rec.objects), removed=rec.removed, redropped=rec.redropped,
                        record=stored(rec.to_json()), models=tuple(self.world.assets()),
                        distractors=self.annotated_distractors(rec))

    def settle(self, job: Job) -> ArrangementRecord:
        """The arrangement of ``job``: its scene and stage, the objects and distractors drawn from
        its seed, dropped and settled."""
        from ..physics import arrange

        inp, world = self.inputs, self.world
        index, rng = seeds.scene_draw(inp.seed, job.id, [s.weight for s in inp.scenes])
        ref = inp.scenes[index]
        variant = seeds.job_seed(inp.seed, f"{job.id}/scene") if procedural_name(ref) else None
        scene = world.scene(ref, variant)
        names = list(scene.stages) if ref.stages else sorted(scene.stages)  # the scene holds the ones asked for
        stage = scene.stages[names[draw_stage([scene.stages[n].weight for n in names], rng)]]
        models = self.draw_models(rng)
        lo, hi = inp.objects.instances
        drop: list[ObjectAsset] = []
        for m in models:
            drop += [m] * int(rng.integers(lo, hi + 1))
        distractors = world.distractor_assets(draw_distractors(inp.arrangements.distractors, rng,
                                                               world.distractor_folder_models()))
        # Standing, as things stand on a desk: a distractor with no free spot is left out, not stacked.
        unstacked = len(distractors) if inp.arrangements.placement == "stand" else 0
        result = arrange(scene, stage, drop + distractors, inp.arrangements, inp.objects.orientation, rng,
                         unstacked=unstacked)
        placed, others = self.placed(result.placed, drop, distractors,
                                     seeds.job_rng(inp.seed, f"{job.id}/paint"))
        kept = {distractors[i - len(drop)].name for i, _ in result.placed if i >= len(drop)}  # credited: shown
        rec = ArrangementRecord(
            arr=job.arr, scene=ref.ref if variant is None else f"{ref.ref}#{variant}", stage=stage.name,
            objects=placed, dropped=len(drop), removed=result.removed, redropped=result.redropped,
            settled=result.settled, sim_seconds=result.sim_seconds, seed=job.seed,
            credits=list(scene.credits) + [a.credit for a in models if a.credit]
            + [a.credit for a in {d.name: d for d in distractors}.values() if a.credit and a.name in kept],
            distractors=others,
        )
        rec.credits += swapped_credits(world, rec, ref)
        return rec

    def draw_models(self, rng: np.random.Generator) -> list[ObjectAsset]:
        """The models an arrangement drops: all of them, or ``models_per_arrangement`` drawn."""
        models = self.world.assets()
        if self.inputs.objects.models_per_arrangement is not None:
            lo, hi = self.inputs.objects.models_per_arrangement
            k = min(int(rng.integers(lo, hi + 1)), len(models))
            chosen = sorted(rng.choice(len(models), size=k, replace=False))
            models = [models[i] for i in chosen]
        return models

    def placed(self, kept, drop: list[ObjectAsset], distractors: list[ObjectAsset], paint_rng: np.random.Generator
               ) -> tuple[list[PlacedObject], list[PlacedObject]]:
        """(the annotated objects in gt order, the distractors left as scene geometry) of what
        physics kept (``kept``: (index into drop + distractors, pose)); distractors painted by
        ``paint_rng``."""
        targets = [(i, pose) for i, pose in kept if i < len(drop)]
        placed = [PlacedObject(obj_id=drop[i].obj_id, inst=n, name=drop[i].name, pose=np.asarray(pose).tolist())
                  for n, (i, pose) in enumerate(targets)]
        d = self.inputs.arrangements.distractors
        others = [PlacedObject(obj_id=0, inst=n, name=distractors[i - len(drop)].name, pose=np.asarray(pose).tolist(),
                               color=paint_color(d.paint, paint_rng, d.paint_saturation))
                  for n, (i, pose) in enumerate((i, pose) for i, pose in kept if i >= len(drop))]
        if not d.annotate:
            return placed, others
        n_obj = len(self.world.assets())  # annotated: objects like the others, after them in gt order
        placed += [PlacedObject(obj_id=d.obj_id(o.name, n_obj), inst=len(placed) + k, name=o.name, pose=o.pose,
                                color=o.color)
                   for k, o in enumerate(others)]
        return placed, []

    def annotated_distractors(self, rec: ArrangementRecord) -> tuple[ObjectAsset, ...]:
        """The models of the distractors ``rec`` annotates, each under its obj_id."""
        spec_ids = {a.obj_id for a in self.world.assets()}
        by_id = self.world.assets_by_id(rec)
        return tuple(by_id[i] for i in sorted(by_id) if i not in spec_ids)


# Toys and office plastics are dyed in a few strong hues, not in any (HSV hue, share). Calibrated on
# the real LM-O test photographs: of their strongly coloured pixels (CIE LCh chroma > 30, 96
# images at quarter size) 38 % are yellow, 26 % red to orange, 16 % blue and 7 % pink, with
# little green and almost no cyan or violet; a uniform hue painted as many violet and cyan things
# as yellow ones (docs/realism.md).
PLASTIC_HUES = ((0.0, 0.22), (0.07, 0.12), (0.14, 0.3), (0.33, 0.1), (0.6, 0.2), (0.93, 0.06))
PLASTIC_HUE_JITTER = 0.025
PLASTIC_VALUE = (0.6, 1.0)  # dyed plastics are bright; a dark one is the exception, not a third


def paint_color(share: float, rng: np.random.Generator, saturation: tuple[float, float]) -> list[float] | None:
    """A plastic colour (linear RGB) for one distractor with probability ``share``, else None (its
    own colours); ``saturation`` is the HSV range of the encoded (sRGB) colour. Nothing is drawn at
    0, so a spec without paint draws as before."""
    if share <= 0.0 or rng.random() >= share:
        return None
    hues, weights = zip(*PLASTIC_HUES)
    h = hues[int(rng.choice(len(hues), p=np.asarray(weights) / sum(weights)))]
    h = (h + rng.uniform(-PLASTIC_HUE_JITTER, PLASTIC_HUE_JITTER)) % 1.0
    s, v = rng.uniform(*saturation), rng.uniform(*PLASTIC_VALUE)
    encoded = np.asarray(colorsys.hsv_to_rgb(h, s, v))
    return srgb_to_linear(encoded).tolist()


def draw_stage(weights: list[float], rng) -> int:
    """A stage's index, by weight; uniform (one integer draw, as before weights) when all are equal."""
    if len(set(weights)) <= 1:
        return int(rng.integers(len(weights)))
    p = np.asarray(weights, np.float64)
    return int(rng.choice(len(p), p=p / p.sum()))


def swapped_credits(world: World, rec: ArrangementRecord, ref: SceneRef) -> list[dict]:
    """Credits of the library textures that randomisation puts into this arrangement's scene
    (exactly what its renders will show: the same function of the same seed)."""
    if not ref.randomize.materials:
        return []
    from ..assets.library import textures
    from ..assets.library.cache import cache_dir

    by_path = {str(t.path): t for t in textures.available(cache_dir())}
    used = sorted({m.material.texture for m in world.render_scene(rec).meshes if m.material.texture in by_path})
    return [by_path[t].credit for t in used]


def draw_distractors(d, rng: np.random.Generator, folder_models: list[str] = ()) -> list[str]:
    """The objects dropped as distractors in one arrangement: each uniform over the named ones, the
    members of the wildcards (pybullet_data's 1000 random shapes, the library's small items) and
    ``folder_models``, the models of the BOP folders in ``d.paths``."""
    lo, hi = d.count
    n = int(rng.integers(lo, hi + 1)) if hi > 0 else 0
    pool = [o for o in d.objects if not o.endswith("/*")]
    pool += [f"random_urdfs/{k:03d}" for k in range(1000)] if "random_urdfs/*" in d.objects else []
    pool += catalogue_objects() if "catalogue/*" in d.objects else []
    pool += list(folder_models)
    return [pool[int(rng.integers(len(pool)))] for _ in range(n)]
