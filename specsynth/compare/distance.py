"""How far a synthetic sample is from a real one: pure functions of two samples of numbers.

The distance of one statistic is the 1-Wasserstein distance between the two samples (the area
between their distribution functions, in the statistic's unit) divided by the real sample's
spread (its interquartile range / 1.349, the standard deviation of a normal with that IQR; the
standard deviation when the IQR is 0; 1 when both are 0). 0 means the same distribution; 1 means
the synthetic values sit, on average, one real spread away. Shifting every synthetic value by s
moves it by |s| / spread exactly.

Coverage: the share of real instances that have a synthetic instance within ``COVERAGE_RADIUS``
real spreads in each of (distance, elevation, visible fraction) at once (a box neighbourhood).
The thresholds are calibrated on real photographs (``docs/compare.md``).
"""

from __future__ import annotations

import numpy as np

# Verdict thresholds on the normalised distance, calibrated on two disjoint halves of the real
# LM-O test split (docs/compare.md).
MATCHES = 0.4
CLOSE = 1.5
COVERAGE_RADIUS = 0.5  # real spreads, per axis
COVERAGE_AXES = ("distance", "elevation", "visib_fract")


def finite(a) -> np.ndarray:
    a = np.asarray(a, np.float64).ravel()
    return a[np.isfinite(a)]


def spread(real) -> float:
    """IQR / 1.349, else the standard deviation, else 1."""
    r = finite(real)
    if len(r) < 2:
        return 1.0
    q1, q3 = np.percentile(r, (25, 75))
    s = (q3 - q1) / 1.349
    if s > 0:
        return float(s)
    sd = float(r.std())
    return sd if sd > 0 else 1.0


def wasserstein1(a, b) -> float:
    """The 1-Wasserstein distance between two samples (their empirical distributions)."""
    a, b = np.sort(finite(a)), np.sort(finite(b))
    if not len(a) or not len(b):
        return float("nan")
    allv = np.sort(np.concatenate([a, b]))
    d = np.diff(allv)
    fa = np.searchsorted(a, allv[:-1], side="right") / len(a)
    fb = np.searchsorted(b, allv[:-1], side="right") / len(b)
    return float(np.sum(np.abs(fa - fb) * d))


def normalised_distance(synth, real) -> float:
    return wasserstein1(synth, real) / spread(real)


def verdict(d: float) -> str:
    if not np.isfinite(d):
        return "no data"
    if d <= MATCHES:
        return "matches"
    if d <= CLOSE:
        return "close"
    return "differs"


def summary(a) -> dict[str, float]:
    """n, median, 5th and 95th percentile, mean, std of a sample (NaN when empty)."""
    a = finite(a)
    if not len(a):
        return {"n": 0, "median": float("nan"), "p5": float("nan"), "p95": float("nan"), "mean": float("nan"),
                "std": float("nan")}
    p5, med, p95 = np.percentile(a, (5, 50, 95))
    return {"n": int(len(a)), "median": float(med), "p5": float(p5), "p95": float(p95), "mean": float(a.mean()),
            "std": float(a.std())}


def coverage(real_pts: np.ndarray, synth_pts: np.ndarray, scales, radius: float = COVERAGE_RADIUS) -> float:
    """Share of real points (rows) with a synthetic point within ``radius * scales`` on every axis."""
    from scipy.spatial import cKDTree

    real_pts = np.asarray(real_pts, np.float64)
    synth_pts = np.asarray(synth_pts, np.float64)
    real_pts = real_pts[np.isfinite(real_pts).all(1)]
    synth_pts = synth_pts[np.isfinite(synth_pts).all(1)]
    if not len(real_pts):
        return float("nan")
    if not len(synth_pts):
        return 0.0
    s = np.asarray(scales, np.float64)
    d, _ = cKDTree(synth_pts / s).query(real_pts / s, k=1, p=np.inf)
    return float(np.mean(d <= radius * (1 + 1e-12)))
