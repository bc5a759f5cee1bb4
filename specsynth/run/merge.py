"""The merge: every finished render into the dataset formats the spec switches on, with the
attribution, the manifest and the record of the files written, in a staging folder swapped in at
the end (``staging``)."""

from __future__ import annotations

import os
import time
from dataclasses import replace
from pathlib import Path

from ..assets.resolve import ObjectAsset, resolve_objects
from ..model.records import ImageRecord
from ..output_api import ImageEntry
from ..plan.compiler import JobGraph
from .manifest import write_manifest
from .pipeline import Pipeline
from .staging import COMPLETE, KEPT_FAILURES, Staging
from .store import write_json
from .summary import BuildSummary, StageStats, error_control_summary


def merge(graph: JobGraph, out: Path, pipe: Pipeline, summary: BuildSummary) -> None:
    """Every finished render into the dataset formats, with the attribution, the manifest and the
    record of the files, written aside and swapped in (``staging``): a merge that fails or is
    killed leaves the last dataset as it was, and the next build completes it."""
    t0 = time.perf_counter()
    phases = Phases()
    images, credits = collect(pipe, summary)
    phases.done("collect")
    if (summary.failures or not images) and (out / COMPLETE).is_file():
        summary.kept_previous = True  # a failed or empty rebuild must not replace the last good dataset
        write_json(out / KEPT_FAILURES, summary.failures)
        return
    staging = Staging(out)
    new = staging.begin()
    phases.done("stage")
    write_dataset(graph, out, new, pipe, summary, images, credits, phases)
    staging.commit()
    phases.done("swap")
    summary.merge_phases = phases.seconds
    summary.stages["merge"] = StageStats(total=1, ran=1, seconds=time.perf_counter() - t0)


def write_dataset(graph: JobGraph, out: Path, new: Path, pipe: Pipeline, summary: BuildSummary,
                  images: list[ImageEntry], credits: list[dict], phases: Phases) -> None:
    """The dataset of ``images`` into ``new`` (the staging folder that becomes ``out``): every
    writer's files, the attribution, the lock file and manifest, the failures, the record of the
    files, and the completion mark when nothing failed."""
    from ..outputs import write_outputs
    from ..outputs.attribution import write_attribution
    from ..outputs.dataset import parts
    from .verify import INDEX, index_of, read_index

    every = [e for part in parts(graph.spec.split, images) for e in part.images]  # a stereo pair's eyes: two images
    summary.images = len(every)
    summary.instances = sum(len(im.instances) for im, _ in every)
    _account_savings(summary, every, pipe.cached_render)
    models = dataset_models(graph, every, pipe)
    phases.done("models")
    previous = read_index(out)
    write_outputs(new, graph.spec, images, models, previous=previous, final=out)
    write_attribution(new, credits, graph.spec.name)
    write_manifest(graph, out, pipe.arr_jobs, into=new)
    write_json(new / "failures.json", summary.failures)
    phases.done("write")
    write_json(new / INDEX, index_of(new, previous), indent=None)
    if images and not summary.failures:
        write_json(new / COMPLETE, {"images": summary.images})
    phases.done("index")


class Phases:
    """Seconds between marks: where a merge's time went (``BuildSummary.merge_phases``)."""

    def __init__(self):
        self.seconds: dict[str, float] = {}
        self._t = time.perf_counter()

    def done(self, name: str) -> None:
        t = time.perf_counter()
        self.seconds[name] = round(self.seconds.get(name, 0.0) + t - self._t, 4)
        self._t = t


def collect(pipe: Pipeline, summary: BuildSummary) -> tuple[list[ImageEntry], list[dict]]:
    """Every finished render with its store folder, and the credits of the arrangements they
    show; the records the workers reported are used as they are, the rest read from the store."""
    images, credits = [], []
    for a, views, renders in pipe.arr_jobs:
        arec = pipe.record("arrange", a.key) or {}
        summary.objects_removed += arec.get("removed", 0)
        summary.objects_redropped += arec.get("redropped", 0)
        for r in renders:
            rec = pipe.record("render", r.key)
            if rec is not None:
                images.append((ImageRecord.from_json(rec), pipe.store.path("render", r.key)))
                credits += arec.get("credits", [])
    return images, credits


def dataset_models(graph: JobGraph, images: list[ImageEntry], pipe: Pipeline | None = None) -> list[ObjectAsset]:
    """The models the dataset's annotations name: the spec's objects in their own look (not the
    renders' ``objects.materials``), and the annotated distractors that appear (each under the
    obj_id it was annotated with). The workers' when they reported them all and their files are
    on this machine, else resolved here."""
    reported = _reported_models(graph, images, pipe) if pipe is not None else None
    if reported is not None:
        return reported
    from ..spec.models import Objects

    # Each model's own look, as the arrange jobs report them: materials are the renders' dressing.
    models = resolve_objects(graph.inputs.arrange.objects.with_materials({}), graph.spec_path.parent)
    d, n = graph.spec.arrangements.distractors, len(models)
    extra = _extra_ids(images, models)
    if not (d.annotate and extra):
        return models
    found = {a.name: a for a in resolve_objects(Objects(builtin=sorted({d.name_of(i, n) for i in extra})),
                                                graph.spec_path.parent)}
    return models + [replace(found[d.name_of(i, n)], obj_id=i) for i in extra]


def _extra_ids(images: list[ImageEntry], models) -> list[int]:
    """obj_ids the images annotate that are not the spec's objects (annotated distractors)."""
    return sorted({g.obj_id for rec, _ in images for g in rec.instances} - {m.obj_id for m in models})


def _reported_models(graph: JobGraph, images: list[ImageEntry], pipe: Pipeline) -> list[ObjectAsset] | None:
    """``dataset_models`` from what this build's arrange jobs reported; None when a model is
    missing (every arrangement was cached, or one showing an annotated distractor) or a worker's
    files are not here (a cluster's workers with caches of their own)."""
    models = list(pipe.models)
    if not models:
        return None
    extra = _extra_ids(images, models) if graph.spec.arrangements.distractors.annotate else []
    if any(i not in pipe.distractor_models for i in extra):
        return None
    models += [pipe.distractor_models[i] for i in extra]
    files = [m.mesh_path for m in models] + [m.material.texture for m in models if m.material.texture]
    return models if all(os.path.isfile(f) for f in files) else None


def _account_savings(summary: BuildSummary, images, cached_render: set[str]) -> None:
    """Seconds the build did not spend: rejected cameras that were never rendered, scenes loaded
    once per arrangement instead of once per view, and cached renders."""
    if not images:
        return
    mean_render = sum(im.render_seconds for im, _ in images) / len(images)
    per_arr: dict[int, list] = {}
    for im, _ in images:
        per_arr.setdefault(im.arr, []).append(im)
    reuse = sum((len(v) - 1) * float(v[0].stats.get("load_seconds", 0.0)) for v in per_arr.values())
    cache = sum(im.render_seconds for im, path in images if path.name in cached_render)
    summary.saved = {
        "visibility_precheck": round(summary.cameras_rejected * mean_render - summary.rejected_seconds, 2),
        "scene_loaded_once_per_arrangement": round(reuse, 2),
        "cache": round(cache, 2),
    }
    summary.glossy_bounces_skipped = sum(1 for im, _ in images if im.stats.get("glossy_skipped"))
    summary.error_control = error_control_summary([im.stats for im, _ in images])
