"""The manifest of a build (job id -> key of every finished job, the stage inputs, the lock file)
and ``specsynth diff``'s comparison of two manifests."""

from __future__ import annotations

import json
from importlib import metadata
from pathlib import Path
from typing import Any

from ..plan import keys
from ..plan.compiler import STAGES, JobGraph
from .store import Store, write_json


def write_manifest(graph: JobGraph, out: Path, arr_jobs, into: Path | None = None) -> None:
    """The manifest (``.specsynth/manifest.json``) and the lock file of a build into ``out``, or
    into ``into`` when the dataset is written aside (the merge's staging folder)."""
    into = Path(out) if into is None else Path(into)
    manifest = {
        "specsynth": metadata.version("specsynth"),
        "spec": str(graph.spec_path),
        "spec_hash": keys.digest(graph.spec.model_dump(mode="json")),
        "backend": graph.backend,
        "stage_inputs": graph.stage_inputs,
        "stage_digests": graph.stage_digests,
        "jobs": finished_jobs(Store(out), arr_jobs),
    }
    write_json(into / ".specsynth" / "manifest.json", manifest, indent=None)
    lock = {
        "seed": graph.spec.seed,
        "seed_rule": "numpy SeedSequence(entropy=seed, spawn_key=sha256(job id) as uint32 words)",
        "assets": graph.asset_hashes,
        "arrangement_seeds": {a.id: a.seed for a, _, _ in arr_jobs},
        "stage_digests": graph.stage_digests,
    }
    write_json(into / "specsynth.lock", lock)


def finished_jobs(store: Store, arr_jobs) -> dict[str, dict[str, str]]:
    """Job id -> key of every job with a finished result, by stage: a failed or never-run job is
    absent, so a diff against a complete build shows it as removed."""
    done = {s: store.keys(s) for s in STAGES}
    jobs: dict[str, dict[str, str]] = {s: {} for s in STAGES}
    for a, views, renders in arr_jobs:
        for j in (a, *views, *renders):
            if j.key in done[j.stage]:
                jobs[j.stage][j.id] = j.key
    return jobs


def manifest_of(graph: JobGraph) -> dict[str, Any]:
    """The manifest a complete build of ``graph`` would write, for diffing specs without building
    (every camera counted as accepted: which are rejected is known only after the view stage)."""
    jobs: dict[str, dict[str, str]] = {s: {} for s in STAGES}
    for j in graph.jobs():
        jobs[j.stage][j.id] = j.key
    return {"stage_inputs": graph.stage_inputs, "jobs": jobs, "backend": graph.backend}


def read_manifest(out: Path) -> dict[str, Any]:
    p = Path(out) / ".specsynth" / "manifest.json"
    if not p.is_file():
        raise FileNotFoundError(f"{out}: not a specsynth output folder (no .specsynth/manifest.json)")
    try:
        manifest = json.loads(p.read_bytes())
    except (ValueError, RecursionError) as e:
        raise FileNotFoundError(f"{p}: unreadable manifest ({type(e).__name__}); rebuild to rewrite it") from None
    if not _manifest_shaped(manifest):
        raise FileNotFoundError(f"{p}: not a manifest specsynth wrote (stage_inputs and jobs: per stage, names to "
                                "digests); rebuild to rewrite it")
    return manifest


def _manifest_shaped(m) -> bool:
    """What ``diff`` reads of a manifest: per stage, names to strings, in both of its tables."""
    if not isinstance(m, dict):
        return False
    for table in ("stage_inputs", "jobs"):
        t = m.get(table)
        if not isinstance(t, dict) or not all(
                isinstance(v, dict) and all(isinstance(x, str) for x in v.values()) for v in t.values()):
            return False
    return True


def diff(a: dict[str, Any], b: dict[str, Any]) -> dict[str, Any]:
    """Per stage added/removed/modified/unchanged, each modification attributed to its causes."""
    result: dict[str, Any] = {}
    upstream_of = {"view": "arrange", "render": "view"}
    causes_by_stage: dict[str, list[str]] = {}
    for stage in STAGES:
        ia, ib = a["stage_inputs"].get(stage, {}), b["stage_inputs"].get(stage, {})
        changed = sorted(k for k in set(ia) | set(ib) if ia.get(k) != ib.get(k))
        ja, jb = a["jobs"].get(stage, {}), b["jobs"].get(stage, {})
        added = sorted(set(jb) - set(ja))
        removed = sorted(set(ja) - set(jb))
        common = set(ja) & set(jb)
        modified = sorted(j for j in common if ja[j] != jb[j])
        causes = list(changed)
        if modified and stage in upstream_of and result.get(upstream_of[stage], {}).get("modified"):
            causes.append(f"upstream:{upstream_of[stage]}")
        causes_by_stage[stage] = causes
        result[stage] = {
            "added": len(added),
            "removed": len(removed),
            "modified": len(modified),
            "unchanged": len(common) - len(modified),
            "causes": causes if (modified or added or removed) else [],
            "changed_inputs": {k: [ia.get(k), ib.get(k)] for k in changed},
        }
    result["identical"] = all(
        result[s]["added"] == result[s]["removed"] == result[s]["modified"] == 0 for s in STAGES
    )
    return result
