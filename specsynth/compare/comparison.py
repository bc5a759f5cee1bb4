"""The comparison of two collected splits: every statistic's summaries, distance and verdict."""

from __future__ import annotations

import numpy as np

from . import distance as dist
from .collect import Collected


# name -> (group, where it is measured, unit, what it is)
STATISTICS: dict[str, tuple[str, str, str, str]] = {
    "distance": ("geometry", "instances", "m", "camera distance to the object"),
    "elevation": ("geometry", "instances", "deg", "camera elevation above the objects' plane"),
    "inplane": ("geometry", "images", "deg", "in-plane rotation of the image"),
    "aim_offset": ("geometry", "images", "", "offset of the object nearest the centre (1 = on the image's ellipse)"),
    "size": ("geometry", "instances", "px", "object size (sqrt of its amodal box area)"),
    "truncation": ("geometry", "instances", "", "share of the object's box outside the image"),
    "visib_fract": ("geometry", "instances", "", "visible fraction"),
    "instances": ("geometry", "images", "", "instances per image (visible >= 10 %)"),
    "brightness": ("appearance", "images", "", "mean luma"),
    "contrast": ("appearance", "images", "", "luma range, 5th to 95th percentile"),
    "colourfulness": ("appearance", "images", "", "colourfulness (Hasler-Suesstrunk)"),
    "saturation": ("appearance", "images", "", "mean HSV saturation"),
    "sharpness": ("appearance", "images", "", "edge sharpness (0.5 = a one-pixel step)"),
    "halo": ("appearance", "images", "", "sharpening halos: overshoot at the strongest edges"),
    "noise": ("appearance", "images", "levels", "noise std (8-bit levels)"),
    "edge_density": ("appearance", "images", "", "clutter: share of edge pixels"),
    "texture_density": ("appearance", "images", "", "clutter: share of textured tiles"),
    "vignetting": ("appearance", "images", "", "dark corners: the corners' bright level over the centre's"),
    "obj_brightness": ("objects", "objects", "", "object: mean luma inside its visible mask"),
    "obj_lightness": ("objects", "objects", "L*", "object: lightness of its mean colour"),
    "obj_a": ("objects", "objects", "a*", "object: green-red of its mean colour"),
    "obj_b": ("objects", "objects", "b*", "object: blue-yellow of its mean colour"),
}
PER_OBJECT = ("distance", "visib_fract", "size", "obj_brightness", "obj_lightness", "obj_a", "obj_b")


def _column(c: Collected, name: str, obj_id: int | None = None) -> np.ndarray:
    table = getattr(c, STATISTICS[name][1])
    values = table[name]
    if obj_id is not None:
        values = values[table["obj_id"] == obj_id]
    return values


def _fmt(v: float, unit: str) -> str:
    if not np.isfinite(v):
        return "-"
    text = f"{v:.3g}" if abs(v) < 100 else f"{v:.0f}"
    return f"{text} {unit}".strip()


def _line(name: str, real: dict, synth: dict, d: float) -> str:
    unit, what = STATISTICS[name][2], STATISTICS[name][3]
    verdict = dist.verdict(d)
    if verdict == "no data":
        return f"{what}: no data on one side"
    rel = "higher" if synth["median"] > real["median"] else "lower"
    body = (f"{what}: synthetic median {_fmt(synth['median'], unit)} vs real {_fmt(real['median'], unit)} "
            f"(5-95 %: {_fmt(synth['p5'], unit)}-{_fmt(synth['p95'], unit)} vs {_fmt(real['p5'], unit)}-"
            f"{_fmt(real['p95'], unit)})")
    if verdict == "matches":
        return f"{body}: matches ({d:.2f})"
    return f"{body}: {verdict} ({d:.2f} real spreads; synthetic {rel})"


def _entry(name: str, s: np.ndarray, r: np.ndarray) -> dict:
    real, synth = dist.summary(r), dist.summary(s)
    d = dist.normalised_distance(s, r) if real["n"] and synth["n"] else float("nan")
    group, _, unit, what = STATISTICS[name]
    return {"group": group, "unit": unit, "what": what, "real": real, "synthetic": synth, "distance": d,
            "spread": dist.spread(r), "verdict": dist.verdict(d), "line": _line(name, real, synth, d)}


def compare(synth: Collected, real: Collected) -> dict:
    """Every statistic overall and per object, coverage, and the histograms' data."""
    stats = {name: _entry(name, _column(synth, name), _column(real, name)) for name in STATISTICS}
    axes = dist.COVERAGE_AXES
    pts = [np.stack([c.instances[a] for a in axes], 1) for c in (real, synth)]
    cov = dist.coverage(pts[0], pts[1], [dist.spread(real.instances[a]) for a in axes])
    per_object = {}
    for obj_id in sorted(set(real.instances["obj_id"].tolist()) & set(synth.instances["obj_id"].tolist())):
        per_object[str(obj_id)] = {name: _entry(name, _column(synth, name, obj_id), _column(real, name, obj_id))
                                   for name in PER_OBJECT}
    return {
        "images": {"real": real.n_images, "synthetic": synth.n_images},
        "up": {"real": real.up, "synthetic": synth.up},
        "statistics": stats,
        "coverage": {"value": cov, "axes": list(axes), "radius": dist.COVERAGE_RADIUS,
                     "line": f"coverage: {100 * cov:.0f} % of real instances have a synthetic one within "
                             f"{dist.COVERAGE_RADIUS} real spreads in {', '.join(axes)}"},
        "per_object": per_object,
        "group_distance": {g: _mean_distance(stats, g) for g in ("geometry", "appearance", "objects")},
    }


def _mean_distance(stats: dict, group: str) -> float:
    d = [e["distance"] for e in stats.values() if e["group"] == group and np.isfinite(e["distance"])]
    return float(np.mean(d)) if d else float("nan")
