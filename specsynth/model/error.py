"""Image error without a reference: estimated from independent renders of the same view.

The measure is ``specsynth bench``'s relative MSE on linear radiance, ``mean((x - ref)² / (ref² + ε))``
over pixels and channels. Two renders ``a`` and ``b`` of one view with independent seeds are
unbiased estimates of the same image with the same per-pixel variance σ²; ``E[(a - b)²] = 2σ²``.
Hence, with the converged image replaced by the best estimate at hand as the normaliser:

- the error of their mean ``(a + b) / 2`` is ``mean((a - b)² / 4 / (norm² + ε))`` (its variance σ²/2);
- the error of one render of ``N`` samples, from two raw renders of ``n`` samples each, is
  ``mean((a - b)² / 2 · (n / N)^α / (norm² + ε))``, where the variance of one render falls as
  ``samples^-α``: α = 1 for independent samples; a renderer's stratified or quasi-random sampler
  converges faster (measured on the demo's views: α 1.1-1.2 for Mitsuba between 16 and 225
  samples, docs/quality.md), so an image under an error target measures its own α from pairs of
  at least two sample counts (``convergence_rate``) before it may stop.

Denoised renders are not unbiased: the first estimate then measures the denoised images' variance
and not the detail the denoiser smooths away (docs/quality.md says by how much, measured).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .ir import RenderResult

EPS = 1e-2  # the relative MSE's offset in the denominator: dark pixels do not dominate it

# Bump when the code here changes what an error-targeted image is: part of the render key of
# builds under quality.control: error (plan.compiler), so their cached renders are made again.
# 2: the sample counts the backend takes, the record of the image kept, stereo eyes as one.
# 3: the target from the sampler's convergence rate measured on the image (not 1 / samples).
# 4: with a backend's denoise and guides, the halves of every sample spent denoised together.
# 5: the convergence rate and the target from the largest sample counts measured (RATE_RANGE).
# 6: steps planned at a rate of 1 while the rate rests on close counts (few_counts), not withheld.
# 7: the default budget twice the paper preset's samples (BUDGET_FACTOR), spent past the preset's
#    samples only by an image not at its target within them (ErrorTarget.next_pair).
# 8: a denoised image's estimate and target normalised by the smaller of it and a 3 x 3 mean of
#    the raw image (denoised_normaliser), not by the denoised image alone.
# (A backend that continues a render's samples, Capabilities.continues_samples, takes another
# way, which the render key names beside the revision.)
REVISION = 8
# An image's budget without quality.max_samples, in the paper preset's samples. One render of N
# samples can have less error than the mean of independent renders of N in all (a stratified
# sampler converges faster than 1 / samples within a render): with the budget at the preset's
# samples, 3 of a 48-image demo (Mitsuba, 320 x 240) ended at 1.15-1.30x their targets. Past
# the preset's samples only an image not at its target within them goes on (soft_samples).
BUDGET_FACTOR = 2
# The fastest fall of one render's variance with its samples that a target assumes: measured
# rates above it are noise or a few-sample start (a stratified sampler is at most ~N^-1.5 on
# smooth pixels and near 1 on the many-bounce paths that make most of a room's noise).
MAX_RATE = 1.5


def rel_mse(x: np.ndarray, ref: np.ndarray) -> float:
    """Relative MSE of ``x`` against a reference image (linear radiance)."""
    x, ref = np.asarray(x, np.float64), np.asarray(ref, np.float64)
    return float(np.mean((x - ref) ** 2 / (ref**2 + EPS)))


def split_rel_mse(a: np.ndarray, b: np.ndarray, norm: np.ndarray | None = None) -> float:
    """Estimated relative MSE of ``(a + b) / 2``, from two independent renders of one view."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    norm = (a + b) / 2 if norm is None else np.asarray(norm, np.float64)
    return float(np.mean((a - b) ** 2 / 4 / (norm**2 + EPS)))


def extrapolated_rel_mse(a: np.ndarray, b: np.ndarray, samples: int, to_samples: int,
                         norm: np.ndarray | None = None) -> float:
    """Estimated relative MSE of one render of ``to_samples`` samples per pixel, from two raw
    (not denoised) independent renders of ``samples`` each, for a sampler whose variance falls as
    1 / samples (an error target scales at the rate it measures: ``_paper_map``)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    norm = (a + b) / 2 if norm is None else np.asarray(norm, np.float64)
    return float(np.mean((a - b) ** 2 / 2 / (norm**2 + EPS))) * samples / to_samples


# The counts that set the rate: those within RATE_RANGE of the largest measured, reaching down to
# the nearest count at least RATE_SPAN below it. A sampler's first samples can fall faster than
# its later ones (Mitsuba's stratified one on a demo view at 96 x 72: samples x variance 2.83 at 4
# samples, 2.01 at 16, 1.82 at 64, 1.85 at 225, so the rate is 1.25 from 4 to 16 and 1.0 above),
# and the target extrapolates from the largest counts: a rate fitted over every count set the
# preset's error 0.72-0.91x its truth. Counts closer than RATE_SPAN, extrapolated over more than
# RATE_RANGE, set a target too low to plan with (``_Progress.plan``): counts 4 and 9 measured 1.29
# there, put the target at 0.47x the truth, and the next step took the image from 26 to 188 samples.
RATE_RANGE = 8
RATE_SPAN = 4


def rate_counts(counts) -> list[int]:
    """The sample counts, of those measured, that set the convergence rate (all of them while
    they span less than ``RATE_SPAN``)."""
    counts = sorted(set(counts))
    below = [n for n in counts if n * RATE_SPAN <= counts[-1]]
    if not below:
        return counts
    floor = min(below[-1], counts[-1] / RATE_RANGE)
    return [n for n in counts if n >= floor]


def convergence_rate(variances: dict[int, float], floor: float = 1.0) -> float | None:
    """α in ``variance ∝ samples^-α`` from one render's mean variance at each sample count: the
    least-squares slope of log variance on log samples over ``rate_counts``, within [``floor``
    (the sampler's own, ``ErrorTarget.min_rate``), MAX_RATE]; None with fewer than two counts."""
    counts = rate_counts(n for n, v in variances.items() if v > 0)
    if len(counts) < 2:
        return None
    x = np.log(np.asarray(counts, np.float64))
    y = np.log(np.asarray([variances[n] for n in counts], np.float64))
    slope = float(np.sum((x - x.mean()) * (y - y.mean())) / np.sum((x - x.mean()) ** 2))
    return min(MAX_RATE, max(floor, -slope))


def denoised_rel_mse_map(d_a: np.ndarray, d_b: np.ndarray, a: np.ndarray, b: np.ndarray,
                         norm: np.ndarray | None = None) -> np.ndarray:
    """Per pixel, an unbiased estimate of the relative squared error of ``(d_a + d_b) / 2``, where
    ``d_a``, ``d_b`` are two independent raw renders ``a``, ``b`` each denoised on its own: the
    denoiser's bias included, and nothing assumed about the denoiser. ``d_a`` is independent of
    ``b``, so ``E[(d_a - b)²]`` is d_a's error plus b's variance ``E[(a - b)²] / 2``; the mean of the
    two halves has half their variance ``E[(d_a - d_b)²] / 2`` less error than one half."""
    d_a, d_b, a, b = (np.asarray(x, np.float64) for x in (d_a, d_b, a, b))
    norm = (d_a + d_b) / 2 if norm is None else np.asarray(norm, np.float64)
    half = ((d_a - b) ** 2 + (d_b - a) ** 2) / 2 - (a - b) ** 2 / 2
    return (half - (d_a - d_b) ** 2 / 4) / (norm**2 + EPS)


def denoised_normaliser(den_image: np.ndarray, raw_image: np.ndarray) -> np.ndarray:
    """The stand-in for the converged image in a denoised image's relative error: per pixel, the
    smaller of the denoised image and a 3 x 3 mean of the raw one. Where the denoiser leaves
    blotches or specks brighter than the truth, the denoised image alone inflates the denominator
    and the error reads low (measured on demo views against references: 15-23 % under the true
    error); the raw mean alone is so noisy that the error reads 2-3x over, and its 3 x 3 mean
    alone 25-31 % under, where it blurs edges. Their smaller one read -9 % to +4 % of the truth
    (docs/quality.md)."""
    from scipy.ndimage import uniform_filter

    raw = np.asarray(raw_image, np.float64)
    local_mean = uniform_filter(raw, size=(3, 3) + (1,) * (raw.ndim - 2), mode="nearest")  # edges repeated
    return np.minimum(np.asarray(den_image, np.float64), local_mean)


def mean_and_error(per_pixel: np.ndarray, blocks: int = 8) -> tuple[float, float]:
    """The image mean of a per-pixel estimate and its standard error, from the spread of the means
    of ``blocks`` x ``blocks`` tiles (a denoised image's pixels are correlated; its tiles hardly)."""
    h, w = per_pixel.shape[:2]
    rows, cols = np.array_split(np.arange(h), blocks), np.array_split(np.arange(w), blocks)
    tiles = np.array([per_pixel[r[0]:r[-1] + 1, c[0]:c[-1] + 1].mean() for r in rows for c in cols if len(r) and len(c)])
    return float(per_pixel.mean()), float(tiles.std(ddof=1) / np.sqrt(len(tiles)))


def denoised_rel_mse(d_a, d_b, a, b, norm=None) -> float:
    """The image's estimated relative MSE (see ``denoised_rel_mse_map``)."""
    return float(denoised_rel_mse_map(d_a, d_b, a, b, norm).mean())


@dataclass(frozen=True)
class ErrorTarget:
    """One image rendered until its estimated error reaches the paper preset's."""

    paper_samples: int  # samples per pixel of the paper preset whose error is the target
    start_samples: int  # samples per render of the first pair
    max_samples: int  # the image's total budget: never more than this many samples per pixel
    # An image stops when its estimate plus this many standard errors of it is at the target:
    # 1.645, one-sided 95 %: the error of about 19 in 20 images is at most the target.
    confidence: float = 1.645
    # The samples per pixel a render takes when asked for n (at least n, rising with n): a sampler
    # that rounds a count up (Mitsuba's stratified, to a square) would otherwise carry the last
    # pair past the budget. None: every count as asked (BackendPlugin.sample_counts).
    counts: Callable[[int], int] | None = None
    # The renderer continues a render's sample sequence (Capabilities.continues_samples): each half
    # is then one render of all its samples, extended by every step (``render(n, half, offset)``),
    # and keeps the faster-than-1/N convergence of a quasi-random sampler that independent renders
    # averaged together lose. False: each step renders two new independent images (``render(n, i)``).
    continues: bool = False
    # Steps keep within this many samples per pixel while a pair fits there, then within the
    # budget (``next_pair``): the default budget's first stage, the paper preset's samples. None:
    # the budget alone.
    soft_samples: int | None = None
    # The slowest fall of one render's variance with its samples that the target assumes
    # (BackendPlugin.sampler_rate): a measured rate below it is held at it, and it stands for the
    # rate until one is measured.
    min_rate: float = 1.0

    def __post_init__(self) -> None:
        if min(self.paper_samples, self.start_samples) < 1 or self.max_samples < 2 * self.taken(self.start_samples):
            raise ValueError(f"an error target needs at least 1 sample per render and a budget of two: {self}")
        if not 1.0 <= self.min_rate <= MAX_RATE:
            raise ValueError(f"an error target's min_rate must be within [1, {MAX_RATE}], got {self.min_rate}")

    def taken(self, n: int) -> int:
        """The samples per pixel a render asked for ``n`` takes."""
        return taken(self.counts, n)

    def per_render(self, n: int, left: int) -> int:
        return per_render(self.counts, n, left)

    def next_pair(self, n: int, spent: int) -> int:
        """Samples per render of the next pair, asked for about ``n`` with ``spent`` so far: within
        ``soft_samples`` while a pair fits there, then within the budget; 0: spent. (With the soft
        stage at the paper preset's samples, an image at its target within them takes the steps it
        took under a budget of them: with the budget of twice as many alone as the bound, steps
        grew and a 48-image demo took 35 % more samples for errors further under their targets,
        median 0.66 of them against 0.79.)"""
        if self.soft_samples is not None:
            first = self.per_render(n, min(self.soft_samples, self.max_samples) - spent)
            if first >= 1:
                return first
        return self.per_render(n, self.max_samples - spent)


def taken(counts: Callable[[int], int] | None, n: int) -> int:
    """The samples per pixel a render asked for ``n`` takes (``ErrorTarget.counts``)."""
    return n if counts is None else int(counts(n))


def per_render(counts: Callable[[int], int] | None, n: int, left: int) -> int:
    """Samples per render of a pair asked for about ``n`` with ``left`` samples per pixel of the
    budget: the count the renderer takes for ``n``, else the largest it takes that fits (the
    counts rise with the request: bisection); 0 when no pair fits."""
    cap = left // 2
    if cap < 1 or taken(counts, 1) > cap:
        return 0
    if taken(counts, n) <= cap:
        return taken(counts, n)
    lo, hi = 1, min(n, cap)  # taken(lo) fits
    while lo < hi:
        mid = (lo + hi + 1) // 2
        lo, hi = (mid, hi) if taken(counts, mid) <= cap else (lo, mid - 1)
    return taken(counts, lo)


@dataclass
class TargetedResult:
    # The image kept: the mean of every render's raw samples, or its two halves each denoised by
    # the core and averaged, or the last pair as the backend denoised it, averaged; its stats hold
    # what the backend reported alike for every render it is made of.
    result: RenderResult
    samples: int  # samples per pixel spent, over all renders
    renders: int
    error: float  # estimated relative MSE of the result
    target: float  # estimated relative MSE of the paper preset at this view
    # (the denoised image's samples, its upper bound) per pair rendered for the denoised way, or
    # per step when the core denoises the halves of every sample spent (then: all samples so far)
    history: list[tuple[int, float]] = field(default_factory=list)
    error_se: float = 0.0  # the estimate's standard error
    image_samples: int = 0  # samples per pixel in the result: all spent, or the last pair's (denoised by the backend)
    denoised: bool = False  # the result is denoised (its halves by the core, or the last pair by the backend)
    # α in "one render's variance ∝ samples^-α", measured on this image; None: not measured (the
    # budget ended first, or no noise), the target then assumed α = 1
    rate: float | None = None

    def stats(self) -> dict:
        return {"samples": self.samples, "renders": self.renders, "image_samples": self.image_samples,
                "denoised": self.denoised, "error_estimate": self.error, "error_se": self.error_se,
                "error_target": self.target, "error_ratio": float(error_ratio(self.error, self.target)),
                **({} if self.rate is None else {"error_rate": self.rate})}


def error_ratio(estimate, target) -> np.ndarray:
    """Estimated error over target, per image, as the record, ``summary.json`` and ``specsynth
    stats`` report it: 0 where the target is 0 (an image without noise: its first pair reaches it)."""
    est, tgt = np.asarray(estimate, np.float64), np.asarray(target, np.float64)
    return np.divide(est, tgt, out=np.zeros(np.broadcast(est, tgt).shape), where=tgt > 0)


MAX_GROWTH = 8  # a step renders at most this many times the samples spent so far


def samples_needed(history: list[tuple[int, float]], target: float) -> int:
    """Total samples at which the estimate reaches ``target``: error ∝ samples^-α, with α from the
    last two steps (a denoiser's error falls slower than 1 / samples), 1 on the first."""
    (n1, e1) = history[-1]
    alpha = 1.0
    if len(history) > 1:
        (n0, e0) = history[-2]
        if e0 > e1 > 0 and n1 > n0:
            alpha = min(1.0, max(0.25, math.log(e0 / e1) / math.log(n1 / n0)))
    if e1 <= target or target <= 0:
        return n1
    return min(MAX_GROWTH * n1, math.ceil(n1 * (e1 / target) ** (1 / alpha)))


def sample_step(n: int) -> int:
    """``n`` rounded up to 2^k or 3 * 2^k (at most 1.5 times ``n``): renderers that compile a kernel
    per sample count (Mitsuba's JIT variants) then meet two counts an octave, compiled once for
    every image of a build."""
    n = max(1, n)
    k = 1 << (n.bit_length() - 1)  # the power of two at or below n
    return next(c for c in (k, 3 * k // 2, 2 * k) if c >= n and (c == k or c % 3 == 0 or c == 2 * k))


Denoise = Callable[[np.ndarray, np.ndarray], np.ndarray]  # (linear, guides) -> denoised linear


class _Raw:
    """Raw renders accumulated into two independent sample-weighted halves (even and odd renders),
    with their denoiser guides (RenderResult.guides) where every render has them."""

    def __init__(self) -> None:
        self.sums, self.counts = [0.0, 0.0], [0, 0]
        self.guides: list = [0.0, 0.0]

    def add(self, g: int, linear: np.ndarray, samples: int, guides: np.ndarray | None = None) -> None:
        self.sums[g] = self.sums[g] + np.asarray(linear, np.float64) * samples
        self.counts[g] += samples
        self.guides[g] = None if guides is None or self.guides[g] is None else self.guides[g] + guides * samples

    def halves(self) -> tuple[np.ndarray, np.ndarray]:
        return self.sums[0] / self.counts[0], self.sums[1] / self.counts[1]

    def has_guides(self) -> bool:
        """Every render of both halves came with guides."""
        return all(isinstance(g, np.ndarray) for g in self.guides)

    def guide_halves(self) -> tuple[np.ndarray, np.ndarray] | None:
        if not self.has_guides():
            return None
        return tuple((self.guides[g] / self.counts[g]).astype(np.float32) for g in (0, 1))


@dataclass(frozen=True)
class _Candidate:
    """One way to the image: the raw renders' mean, or the last pair denoised and averaged."""

    image: np.ndarray
    error: float  # its estimated relative MSE
    se: float  # the estimate's standard error
    # The estimate plus ``confidence`` standard errors of (estimate - target): the target's own
    # noise counted too, and nothing twice where both come from the same renders.
    upper: float
    samples: int  # samples per pixel in the image
    denoised: bool


def _candidate(image: np.ndarray, error_map: np.ndarray, paper_map: np.ndarray, confidence: float, samples: int,
               denoised: bool) -> _Candidate:
    error, se = mean_and_error(error_map)
    return _Candidate(image, error, se, error + confidence * mean_and_error(error_map - paper_map)[1], samples, denoised)


def _denoised_halves(raw: _Raw, pair: list[RenderResult] | None, took: list[int], denoise: Denoise | None):
    """(two independent denoised images, the raw images they were denoised from, their samples
    together) or None: the accumulated halves denoised by ``denoise`` with their accumulated guides
    (every sample spent is in the image), else the last pair as the backend denoised it."""
    guides = raw.guide_halves() if denoise is not None else None
    if guides is not None:
        a, b = raw.halves()
        d_a, d_b = (denoise(h.astype(np.float32), g) for h, g in ((a, guides[0]), (b, guides[1])))
        return d_a, d_b, a, b, sum(raw.counts)
    # (A render that skipped its denoiser, RenderBackend.denoise, is its noisy image: not this way.)
    if pair is not None and pair[0].noisy is not None and not np.array_equal(pair[0].linear, pair[0].noisy):
        return pair[0].linear, pair[1].linear, pair[0].noisy, pair[1].noisy, sum(took)
    return None


def _candidates(raw: _Raw, pair: list[RenderResult] | None, took: list[int], pairs: list[tuple[int, np.ndarray]],
                paper_samples: int, confidence: float, denoise: Denoise | None = None, continued: bool = False,
                min_rate: float = 1.0) -> tuple[float, float | None, list[_Candidate], float]:
    """(the paper preset's estimated error at this view, the convergence rate it took or None when
    not yet measured, [the raw candidate, the denoised one when the backend denoises], the error
    to plan the next step for: the estimate, or at the sampler's least rate (``min_rate``) while
    the rate is not measured or rests on close counts far from the paper's, ``few_counts``). One
    normaliser for all of them: the raw mean, or where something is denoised
    ``denoised_normaliser`` (the raw mean of a few samples alone is so noisy that
    ``1 / (norm² + ε)`` of it inflates the target, measured 2-3x at 2 samples per render on a
    noisy image, and the stop comes early). ``pairs``: every pair's samples per
    render and the square of its two raw renders' difference (``continued``: the halves' at each
    step, ``_paper_map``; ``min_rate``: ``ErrorTarget.min_rate``)."""
    a, b = raw.halves()
    raw_image = (a + b) / 2
    den = _denoised_halves(raw, pair, took, denoise)
    den_image = None if den is None else (np.asarray(den[0], np.float64) + den[1]) / 2
    norm = raw_image if den_image is None else denoised_normaliser(den_image, raw_image)
    norm2 = norm**2 + EPS
    raw_map = ((a - b) ** 2 / 4 / norm2).mean(axis=-1)
    paper_map, rate = _paper_map(pairs, norm2, paper_samples, continued, min_rate=min_rate)
    # Continued halves: the raw estimate and the target are the same two renders' difference, so
    # their ratio has no noise; the margin is the estimate's own (truth against it), not theirs.
    out = [_candidate(raw_image, raw_map, np.zeros_like(raw_map) if continued else paper_map, confidence,
                      sum(raw.counts), False)]
    if den is not None:
        den_map = denoised_rel_mse_map(*den[:4], norm=norm).mean(axis=-1)
        out.append(_candidate(den_image, den_map, paper_map, confidence, den[4], True))
    paper = float(paper_map.mean())
    counts = [n for n, _ in pairs]
    if rate is not None and not few_counts(counts, paper_samples, continued):
        return paper, rate, out, paper
    plan = float(_paper_map(pairs, norm2, paper_samples, alpha=min_rate)[0].mean())
    return paper, rate, out, max(paper, plan)


def few_counts(counts: list[int], paper_samples: int, continued: bool = False) -> bool:
    """The rate rests on counts closer than ``RATE_SPAN`` and is extrapolated more than
    ``RATE_RANGE``: a fast start of the sampler can make it high, and the target low. It is
    safe to stop on (the image then has less error than asked), not to plan with."""
    top = rate_counts(counts)
    return (not continued and len(top) > 1 and top[-1] < RATE_SPAN * top[0]
            and top[-1] * RATE_RANGE < paper_samples)


def _paper_map(pairs: list[tuple[int, np.ndarray]], norm2: np.ndarray, paper_samples: int,
               continued: bool = False, alpha: float | None = None, min_rate: float = 1.0
               ) -> tuple[np.ndarray, float | None]:
    """Per pixel, the paper preset's estimated error: the variance of one render of every pair
    whose count sets the rate (``rate_counts``), scaled from its samples to the paper's at that
    rate (at least ``min_rate``, which stands for it until it is measured; ``alpha``, when given,
    instead), averaged with weights by samples; and the rate. ``continued``: the pairs are the
    same two renders at each step, so the last is the least extrapolated, and the rate is the
    one over the last two counts (a quasi-random sequence's first samples converge faster than
    its later ones: measured on Cycles, 1.50 from 2 to 8 samples where 16 to 225 fall at 1.2)."""
    if continued:
        pairs = pairs[-2:]
    maps = [(n, (sq / 2 / norm2).mean(axis=-1)) for n, sq in pairs]
    by_count: dict[int, list[float]] = {}
    for n, m in maps:
        by_count.setdefault(n, []).append(float(m.mean()))
    rate = convergence_rate({n: float(np.mean(v)) for n, v in by_count.items()}, floor=min_rate)
    alpha = alpha if alpha is not None else min_rate if rate is None else rate
    if continued:
        maps = maps[-1:]
    elif rate is not None:  # the pairs whose counts set the rate: the others converge otherwise
        top = set(rate_counts(by_count))
        maps = [(n, m) for n, m in maps if n in top]
    total = sum(n for n, _ in maps)
    return sum(n * m * (n / paper_samples) ** alpha for n, m in maps) / total, rate


def _render_pair(render: Callable[..., RenderResult], n: int, first: int, raw: _Raw,
                 phases: dict[str, float], continues: bool = False) -> tuple[list[RenderResult], list[int]]:
    """The ``first``-th and the next render of ``n`` samples (or, when the renderer ``continues``,
    each half's next ``n`` samples of its own sequence), their raw samples added to ``raw``'s two
    halves and their time to ``phases`` -> (the pair, the samples each took; one count)."""
    pair, took = [], []
    for g in (0, 1):
        res = render(n, g, raw.counts[g]) if continues else render(n, first + g)
        took.append(int(res.stats.get("samples", res.stats.get("spp", n))))
        if took[-1] > n:  # the budget is planned with the counts the renderer says it takes
            raise RuntimeError(f"a render asked for {n} samples per pixel took {took[-1]}: the backend's plugin must "
                               "say how it rounds sample counts (BackendPlugin.sample_counts)")
        raw.add(g, res.noisy if res.noisy is not None else res.linear, took[-1], res.guides)
        for k, v in (res.stats.get("phases") or {}).items():  # the image's time is every render's
            phases[k] = phases.get(k, 0.0) + v
        pair.append(res)
    return pair, took


def _next_step(images: list[_Progress], n: int, target: ErrorTarget) -> tuple[int, bool]:
    """(samples per render of the next pairs, whether they are new pairs for the denoised way): the
    cheaper way on for the image furthest from its target. The raw mean of all renders is a mean
    of independent renders, whose error falls as 1 / samples spent (or two renders continued,
    falling at the measured rate): the raw way needs what the image furthest from its target
    needs at that fall; new, larger denoised pairs (whose samples
    are all new) are chosen only at half the cost of the raw way, their fall being predicted.
    When the core denoises the halves, both ways are made of every sample spent and the next pair
    tops them up towards the nearer. While an image's convergence rate is not measured the next
    pairs take at least twice the last pair's samples: a second count. Steps are planned for
    ``_Progress.plan``. 0 samples: the budget is spent."""
    spent = max(image.spent for image in images)
    raw_need = max(1, max(image.raw_need() for image in images) - spent)
    histories, papers = [image.history for image in images], [image.plan for image in images]
    den_need = max(2 * math.ceil(samples_needed(h, p) / 2) for h, p in zip(histories, papers)) if all(histories) else None
    if den_need is not None and all(image.accumulated() for image in images):
        # Both ways are made of every sample spent: the next pair tops up to the nearer one.
        # (Capped at doubling the samples spent, two demo views took 175 samples per image for a
        # relMSE of 2.70e-3, against 168 for 2.41e-3, in more and smaller steps.)
        n_next = max(1, math.ceil(min(raw_need, max(1, den_need - spent)) / 2))
        den_step = True
    else:
        den_step = den_need is not None and 2 * den_need < raw_need  # a prediction, against a sure way
        n_next = max(n + 1, den_need // 2) if den_step else max(1, math.ceil(raw_need / 2))
    if any(image.unmeasured() for image in images):
        n_next = max(n_next, 2 * n)
    if target.continues:  # a step more costs a render's overhead, no samples: each half grows ~4x at most (before rounding)
        n_next = min(n_next, max(2 * n, 3 * spent // 2))
    return target.next_pair(sample_step(n_next), spent), den_step


class _Progress:
    """One image of a group on its way to its target: its raw halves, what its renders reported,
    and the last step's candidates."""

    def __init__(self, render: Callable[..., RenderResult], continues: bool = False) -> None:
        self.render, self.raw, self.history, self.phases, self.reported = render, _Raw(), [], {}, []
        self.spent, self.paper, self.rate, self.candidates = 0, 0.0, None, []
        self.plan = 0.0  # the target the next step is planned for (``_candidates``)
        self.continues = continues  # each half is one render continued (ErrorTarget.continues)
        # (samples per render, the raw renders' squared difference); continued: (each half's samples, the halves')
        self.pairs: list[tuple[int, np.ndarray]] = []
        self.denoise: Denoise | None = None  # set when the core denoises the halves (``evaluate``)
        self._pair: tuple[list[RenderResult], list[int]] | None = None

    def render_pair(self, n: int, first: int) -> None:
        pair, took = _render_pair(self.render, n, first, self.raw, self.phases, self.continues)
        self.spent += sum(took)
        self.reported += [res.stats for res in pair]
        if self.continues:  # the halves are two independent renders of all their samples
            a, b = self.raw.halves()
            self.pairs.append((min(self.raw.counts), ((a - b) ** 2).astype(np.float32)))
        else:
            a, b = (np.asarray(res.noisy if res.noisy is not None else res.linear, np.float64) for res in pair)
            self.pairs.append((took[0], ((a - b) ** 2).astype(np.float32)))
        self._pair = pair, took

    def evaluate(self, target: ErrorTarget, den_step: bool, denoise: Denoise | None) -> None:
        """The candidates after the last pair; ``denoise``: the core denoises the halves (every
        image of the group has its guides), else None."""
        if self.denoise is not None and denoise is None:  # guides stopped coming: another way, another history
            self.history = []
        self.denoise = denoise
        pair, took = self._pair
        # A continued pair is a range of samples in the middle of each half's sequence, not an image
        # of its own (measured on Cycles: samples 2-18 denoised had 1.4x the error of a 16-sample
        # render): no last-pair way.
        pair = None if self.continues else pair
        self.paper, self.rate, self.candidates, self.plan = _candidates(
            self.raw, pair, took, self.pairs, target.paper_samples, target.confidence, denoise, self.continues,
            min_rate=target.min_rate)
        # The denoised way's history: its pairs alone, or every step when it denoises all samples spent.
        if len(self.candidates) > 1 and (den_step or self.accumulated()):
            self.history.append((self.candidates[1].samples, self.candidates[1].upper))

    def accumulated(self) -> bool:
        """Its denoised candidate is made of every sample spent (the halves denoised by the core)."""
        return self.denoise is not None

    def unmeasured(self) -> bool:
        """Its target still assumes a rate: fewer than two sample counts rendered, and noise."""
        return self.rate is None and self.paper > 0

    def raw_need(self) -> int:
        """The samples at which the raw mean's bound reaches the target: its error falls as
        1 / samples over independent renders, at the measured rate over continued halves."""
        upper = self.candidates[0].upper
        if upper <= self.plan or self.plan <= 0:
            return self.spent
        alpha = self.rate if self.continues and self.rate is not None else 1.0
        return math.ceil(self.spent * (upper / self.plan) ** (1 / alpha))

    def over(self, kind: int) -> float:
        """The candidate's upper bound over the target (an image without noise, target 0, is at it
        with a bound of 0)."""
        upper = self.candidates[kind].upper
        return upper / self.paper if self.paper > 0 else (0.0 if upper <= 0 else math.inf)

    def result(self, kind: int, renders: int, encode: Callable[[np.ndarray], np.ndarray]) -> TargetedResult:
        best = self.candidates[kind]
        linear = best.image.astype(np.float32)
        # The kept image's record: what the backend reported alike for every render it is made of
        # (a setting), not the last render's count, seed or time (Mitsuba's spp of the last pair
        # stood beside the samples of all of them); the time is every render's.
        made_of = self.reported[-2:] if best.denoised and not self.accumulated() else self.reported
        res = RenderResult(rgb=encode(linear), linear=linear, stats={**shared_stats(made_of), "phases": self.phases})
        return TargetedResult(res, self.spent, renders, best.error, self.paper, self.history, best.se, best.samples,
                              best.denoised, self.rate)


def render_to_target(render: Callable[..., RenderResult], target: ErrorTarget,
                     encode: Callable[[np.ndarray], np.ndarray], denoise: Denoise | None = None) -> TargetedResult:
    """Render pairs of independent images (``render(samples, i)``: the i-th render's seed is the
    caller's) until the estimated error of the image reaches the paper preset's estimated error
    at this view (with ``target.confidence`` standard errors to spare), or the budget is spent.

    Every render's raw samples (before a denoiser) are accumulated: their mean is an unbiased
    image of all the samples spent, which reaches the target at the paper's samples. Renders
    denoised by the backend cannot be accumulated: a step renders a new pair with the samples
    the last pair's estimate asks for, and that pair's mean is the other candidate; its error
    estimate needs nothing of the denoiser but that it treats the two renders alike and
    independently. The image is the candidate with the lower bound; the next step is the
    cheaper way to the target (``_next_step``).

    With ``denoise`` and renders that carry their denoiser's guides, the denoised candidate is
    instead the two accumulated halves, each denoised with its accumulated guides: no sample is
    spent on a pair that is then dropped, and each step tops up the halves.

    When ``target.continues``, ``render(samples, half, offset)`` renders the samples ``offset`` to
    ``offset + samples`` of half 0's or half 1's own sequence: each half is then one render of
    all its samples, and the pairs that measure the noise are the halves themselves."""
    return render_group_to_target([render], target, encode, denoise)[0]


def render_group_to_target(renders: list[Callable[..., RenderResult]], target: ErrorTarget,
                           encode: Callable[[np.ndarray], np.ndarray], denoise: Denoise | None = None
                           ) -> list[TargetedResult]:
    """Several images of one view (a stereo rig's eyes) rendered to their targets as one
    (``render_to_target`` for one image): each step renders a pair of every image with the same
    samples and render indices, the next step is the one the image furthest from its target
    needs, and all stop together when every image is at its target or the budget is spent. Each
    keeps the same kind of candidate (raw mean or denoised pair: the one whose image furthest
    from its target is nearest), so the images of a pair carry the same samples and treatment
    and only their own content's error tells them apart."""
    images = [_Progress(render, target.continues) for render in renders]
    n, count, den_step = target.per_render(target.start_samples, target.max_samples), 0, True
    while True:
        for image in images:
            image.render_pair(n, count)
        # One way for the whole group: the core denoises the halves only when every image has guides.
        halves = denoise if denoise is not None and all(image.raw.has_guides() for image in images) else None
        for image in images:
            image.evaluate(target, den_step, halves)
        count += 2
        kinds = range(min(len(image.candidates) for image in images))
        kind = min(kinds, key=lambda k: max(image.over(k) for image in images))  # the raw mean on a tie
        if all(image.candidates[kind].upper <= image.paper and not image.unmeasured() for image in images):
            break
        n, den_step = _next_step(images, n, target)
        if n < 1:
            break
    return [image.result(kind, count, encode) for image in images]


def shared_stats(reported: list[dict]) -> dict:
    """The entries every one of ``reported`` has with one value (the phases aside)."""
    first, rest = reported[0], reported[1:]
    return {k: v for k, v in first.items() if k != "phases" and all(k in r and _same(r[k], v) for r in rest)}


def _same(a, b) -> bool:
    try:
        return bool(a == b)
    except (TypeError, ValueError):  # arrays and the like: not a setting
        return False
