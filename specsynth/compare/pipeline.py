"""``specsynth compare``'s steps: open both splits (every check before any work), complete what
they lack, measure both, compare."""

from __future__ import annotations

from pathlib import Path

from .collect import Collected, collect
from .comparison import compare
from .gtinfo import annotated_occluders_only, complete
from .split import Split, open_split


def open_both(synth_ref: str, real_ref: str, models: str | None = None) -> tuple[Split, Split]:
    """Both splits read and checked; a split that will need masks computed has its models checked too."""
    from .split import check_models

    splits = []
    for ref in (synth_ref, real_ref):
        s = open_split(ref)
        if not (s.has_gt_info and s.has_masks):
            check_models(s, Path(models) if models else s.models)
        splits.append(s)
    return splits[0], splits[1]


def measure(split: Split, models: str | None = None, jobs: int = 0, log=None,
            annotated_occluders: bool = False) -> Collected:
    return collect(complete(split, Path(models) if models else None, log=log,
                            annotated_occluders=annotated_occluders), jobs=jobs)


def run_compare(synth_ref: str, real_ref: str, models: str | None = None, jobs: int = 0, log=None,
                own_masks: bool = False):
    """-> (the comparison, the synthetic side's numbers, the real side's). When the real split's
    visibility can only be computed with its annotated objects as the occluders (no masks, no depth),
    the synthetic side's is computed the same way: both sides are measured alike, and a distractor
    in front of an object counts on neither. ``own_masks``: the synthetic side keeps its own."""
    synth, real = open_both(synth_ref, real_ref, models)
    alike = not own_masks and annotated_occluders_only(real)
    if alike and not (synth.models or models):
        alike = False  # nothing to render the synthetic objects from: its own masks are measured
    s = measure(synth, models if not synth.models else None, jobs, log, annotated_occluders=alike)
    r = measure(real, models, jobs, log)
    c = compare(s, r)
    c["occluders"] = ("the annotated objects alone, on both sides (the real split has no masks or depth)" if alike
                      else "as each split's own masks or depth have them")
    return c, s, r
