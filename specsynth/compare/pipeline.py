"""``specsynth compare``'s steps: open both splits (every check before any work), complete what
they lack, measure both, compare."""

from __future__ import annotations

from pathlib import Path

from .collect import Collected, collect
from .comparison import compare
from .gtinfo import complete
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


def measure(split: Split, models: str | None = None, jobs: int = 0, log=None) -> Collected:
    return collect(complete(split, Path(models) if models else None, log=log), jobs=jobs)


def run_compare(synth_ref: str, real_ref: str, models: str | None = None, jobs: int = 0, log=None):
    """-> (the comparison, the synthetic side's numbers, the real side's)."""
    synth, real = open_both(synth_ref, real_ref, models)
    s = measure(synth, models, jobs, log)
    r = measure(real, models, jobs, log)
    return compare(s, r), s, r
