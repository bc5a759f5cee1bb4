"""Appearance statistics of one image: pure functions of its 8-bit sRGB pixels.

Every statistic is computed the same way on both sides of a comparison, on the stored 8-bit
image (what a detector is trained and tested on). *Luma* is Rec. 709's weighted sum of the sRGB
values, ``Y' = 0.2126 R' + 0.7152 G' + 0.0722 B'`` in [0, 1]. Statistics of content (brightness,
contrast, colour, clutter) are taken at half size (2 x 2 means), so that pixel noise cannot count
as detail; sharpness and noise at full size, where they live. Definitions, and the numbers they
give on the real LM-O photographs, are in ``docs/compare.md``.
"""

from __future__ import annotations

import numpy as np

IMAGE_STATS = ("brightness", "contrast", "colourfulness", "saturation", "sharpness", "halo", "noise",
               "edge_density", "texture_density", "vignetting")

EDGE_GRADIENT = 0.08  # luma per pixel (half size): a visible edge
TEXTURE_STD = 4.0 / 255.0  # luma std inside a tile (half size, 8 x 8 = 16 x 16 full-size pixels)
TILE = 8
SHARP_TOP = 0.02  # the strongest 2 % of full-size gradients are the edges sharpness is read at
SHARP_MIN_STEP = 0.1  # ... where the luma range around them is at least this
SHARP_WINDOW = 2  # half-width of that window (5 x 5 pixels)
HALO_TOP = 0.002  # the strongest 0.2 % of full-size gradients are the edges halos are read at
HALO_WINDOW = 5  # half-width of the window round each (11 x 11): its outer two rings give the levels
HALO_MIN_STEP = 0.2  # ... where those levels differ by at least this much luma
CORNERS = 0.8  # vignetting: the corners are the pixels this far out, in the half-diagonal ...
CENTRE = 0.5  # ... and the centre those within this
BRIGHT = 90  # ... each's bright level: this percentile of its luma
CLIPPED = 250.0 / 255.0  # a centre this bright has clipped (in 2 of 96 of the demo's images, none of the real)
_WEIGHTS = np.array([0.2126, 0.7152, 0.0722], np.float32)


def luma(rgb8: np.ndarray) -> np.ndarray:
    """Y' in [0, 1], float32, HxW."""
    return (np.asarray(rgb8, np.float32) @ _WEIGHTS) / np.float32(255.0)


def half(a: np.ndarray) -> np.ndarray:
    """2 x 2 means (odd last row / column dropped)."""
    h, w = (a.shape[0] // 2) * 2, (a.shape[1] // 2) * 2
    a = a[:h, :w]
    return (a[0::2, 0::2] + a[1::2, 0::2] + a[0::2, 1::2] + a[1::2, 1::2]) * np.float32(0.25)


def half_rgb8(rgb8: np.ndarray) -> np.ndarray:
    """2 x 2 means of an 8-bit image (PIL's box reduction, rounded to 8 bits), HxWx3 uint8."""
    from PIL import Image

    return np.asarray(Image.fromarray(np.ascontiguousarray(rgb8, np.uint8)).reduce(2))


def colourfulness(rgb: np.ndarray) -> float:
    """Hasler and Suesstrunk (2003): sqrt(var rg + var yb) + 0.3 sqrt(mean rg^2 + mean yb^2), on
    sRGB values in [0, 1] (x 255 gives their published scale)."""
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    rg = r - g
    yb = 0.5 * (r + g) - b
    return float(np.sqrt(rg.var() + yb.var()) + 0.3 * np.sqrt(rg.mean() ** 2 + yb.mean() ** 2))


def saturation(rgb: np.ndarray) -> float:
    """Mean HSV saturation (max - min) / max of the pixels with value > 0.05."""
    r, g, b = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    mx, mn = np.maximum(np.maximum(r, g), b), np.minimum(np.minimum(r, g), b)
    lit = mx > 0.05
    n = int(np.count_nonzero(lit))
    if not n:
        return 0.0
    sat = np.divide(mx - mn, mx, out=np.zeros_like(mx), where=lit)
    return float(sat.sum(dtype=np.float64) / n)


def gradient_squared(y: np.ndarray) -> np.ndarray:
    """Squared central differences (one-sided at the border), (luma per pixel)^2: ``np.gradient``'s."""
    gx = np.empty_like(y)
    gy = np.empty_like(y)
    gx[:, 1:-1] = (y[:, 2:] - y[:, :-2]) * np.float32(0.5)
    gx[:, 0], gx[:, -1] = y[:, 1] - y[:, 0], y[:, -1] - y[:, -2]
    gy[1:-1] = (y[2:] - y[:-2]) * np.float32(0.5)
    gy[0], gy[-1] = y[1] - y[0], y[-1] - y[-2]
    gx *= gx
    gy *= gy
    gx += gy
    return gx


def gradient_magnitude(y: np.ndarray) -> np.ndarray:
    """Central differences (one-sided at the border), luma per pixel."""
    return np.sqrt(gradient_squared(y))


def percentiles(a: np.ndarray, qs) -> list[float]:
    """``np.percentile(a, qs)`` (its linear method) from one partial sort around the ranks needed."""
    flat = np.asarray(a).ravel()
    n = len(flat)
    pos = [q / 100.0 * (n - 1) for q in qs]
    ranks = sorted({r for p in pos for r in (int(np.floor(p)), min(n - 1, int(np.floor(p)) + 1))})
    part = np.partition(flat, ranks)
    out = []
    for p in pos:
        lo = int(np.floor(p))
        hi = min(n - 1, lo + 1)
        out.append(float(part[lo] + (p - lo) * (part[hi] - part[lo])))
    return out


def _top_k(a: np.ndarray, k: int) -> np.ndarray:
    """Indices of the ``k`` largest values of ``a`` (as ``argpartition`` picks them), searched among
    the values above a threshold that a 1/16 sample puts at twice ``k``'s rank: every one of the
    ``k`` largest is above it whenever at least ``k`` values are, else the whole array is searched."""
    sample = a[::16]
    m = min(len(sample) - 1, 2 * k // 16)
    if m > 0:
        threshold = np.partition(sample, len(sample) - 1 - m)[len(sample) - 1 - m]
        candidates = np.flatnonzero(a >= threshold)
        if len(candidates) >= k:
            return candidates[np.argpartition(a[candidates], len(candidates) - k)[len(candidates) - k:]]
    return np.argpartition(a, len(a) - k)[len(a) - k:]


def sharpness(y: np.ndarray, g2: np.ndarray | None = None) -> float:
    """Edge sharpness: at the strongest edges, the gradient over the luma step across them.

    At the top ``SHARP_TOP`` of full-size gradient magnitudes whose 5 x 5 neighbourhood spans a
    luma range of at least ``SHARP_MIN_STEP``: the median of |gradient| / range. A one-pixel step
    gives 0.5; an edge blurred by a Gaussian of sigma = 1, 1.5, 2, 3 pixels 0.34, 0.30, 0.28, 0.26
    (0.25 in the limit of blurs much wider than the window). Independent of how many edges the
    image has (clutter). NaN without such edges."""
    g2 = gradient_squared(np.asarray(y, np.float32)) if g2 is None else g2  # ranked without the square root: same order
    r = SHARP_WINDOW
    inner = g2[r:-r, r:-r]
    if inner.size == 0:
        return float("nan")
    rows, cols = np.unravel_index(_top_k(inner.ravel(), max(1, int(SHARP_TOP * inner.size))), inner.shape)
    win = np.lib.stride_tricks.sliding_window_view(y, (2 * r + 1, 2 * r + 1))[rows, cols]
    step = win.max(axis=(1, 2)) - win.min(axis=(1, 2))
    keep = step >= SHARP_MIN_STEP
    if not keep.any():
        return float("nan")
    return float(np.median(np.sqrt(inner[rows, cols][keep]) / step[keep]))


def halo(y: np.ndarray, g2: np.ndarray | None = None) -> float:
    """Sharpening halos: how far the luma next to the strongest edges overshoots the levels on
    either side, as a share of the step between them.

    At the top ``HALO_TOP`` of full-size gradient magnitudes, in the 11 x 11 window round each: the
    levels are the 10th and 90th percentiles of its outer two rings (Chebyshev distance 4-5), the
    overshoot is how far the inner 7 x 7's maximum rises above the upper level plus how far its
    minimum falls below the lower; the median over edges whose levels differ by at least
    ``HALO_MIN_STEP``, of overshoot / step. A clean or blurred step gives 0; an unsharp mask of
    amount a (a Gaussian of 1 pixel) 0.44-0.50 a for a up to 1 (tested; 0.41 a at 2): its fringes
    overshoot by 0.601 a, and where the edge crosses the rings they hold part of them, more as a
    grows; once a fringe clips at black or white the reading falls. The real LM-O photographs:
    0.15. NaN without such edges."""
    y = np.asarray(y, np.float32)
    r = HALO_WINDOW
    inner = (gradient_squared(y) if g2 is None else g2)[r:-r, r:-r]
    if inner.size == 0:
        return float("nan")
    rows, cols = np.unravel_index(_top_k(inner.ravel(), max(1, int(HALO_TOP * inner.size))), inner.shape)
    win = np.lib.stride_tricks.sliding_window_view(y, (2 * r + 1, 2 * r + 1))[rows, cols]
    ring = np.maximum(*np.abs(np.mgrid[-r:r + 1, -r:r + 1])) >= r - 1
    lo, hi = np.percentile(win[:, ring], (10, 90), axis=1)
    core = win[:, 2:-2, 2:-2].reshape(len(win), -1)
    over = np.maximum(core.max(axis=1) - hi, 0.0) + np.maximum(lo - core.min(axis=1), 0.0)
    keep = hi - lo >= HALO_MIN_STEP
    return float(np.median(over[keep] / (hi - lo)[keep])) if keep.any() else float("nan")


def noise_level(y: np.ndarray, g_half: np.ndarray | None = None) -> float:
    """Noise std in 8-bit levels: Immerkaer's (1996) operator N = [1 -2 1]^T [1 -2 1] (blind to
    planes and ramps) averaged over the flattest half of the image, sigma = sqrt(pi / 2) / 6 *
    mean |N * Y'|. Flatness is the half-size gradient (``g_half``, computed from ``y`` when not
    given): averaging 2 x 2 pixels keeps noise from choosing the pixels it is measured on."""
    y = np.asarray(y, np.float32)
    if min(y.shape) < 6:
        return float("nan")
    if g_half is None:
        g_half = gradient_magnitude(half(y))
    h, w = 2 * g_half.shape[0], 2 * g_half.shape[1]
    rows = y[:h, :w]
    d = rows[:, :-2] - 2 * rows[:, 1:-1] + rows[:, 2:]  # [1 -2 1] along x
    n = d[:-2] - 2 * d[1:-1] + d[2:]  # then along y: N at pixels [1:-1, 1:-1]
    flat_half = g_half <= np.median(g_half)
    flat = np.repeat(np.repeat(flat_half, 2, axis=0), 2, axis=1)[1:h - 1, 1:w - 1]
    a = np.abs(n[flat])
    return float(np.sqrt(np.pi / 2.0) / 6.0 * 255.0 * a.mean(dtype=np.float64)) if a.size else float("nan")


def edge_density(g_half: np.ndarray) -> float:
    """Share of half-size pixels whose luma gradient (``g_half``) exceeds ``EDGE_GRADIENT`` per pixel."""
    return float(np.count_nonzero(g_half > EDGE_GRADIENT) / g_half.size)


def texture_density(y_half: np.ndarray) -> float:
    """Share of 8 x 8 tiles (half size) whose luma std exceeds ``TEXTURE_STD`` (4/255)."""
    h, w = (y_half.shape[0] // TILE) * TILE, (y_half.shape[1] // TILE) * TILE
    if h == 0 or w == 0:
        return float("nan")
    tiles = y_half[:h, :w].reshape(h // TILE, TILE, w // TILE, TILE).transpose(0, 2, 1, 3).reshape(-1, TILE * TILE)
    return float((tiles.std(axis=1) > TEXTURE_STD).mean())


def vignetting(y_half: np.ndarray) -> float:
    """Dark corners: the bright level (``BRIGHT`` percentile of luma) of the pixels at least
    ``CORNERS`` of the half-diagonal from the image centre, over that of the pixels within
    ``CENTRE`` of it. 1: corners as bright as the centre; a lens's fall-off, and a scene darker
    at its edges than where the camera aims, make it less. NaN when the centre's level is black or
    clipped (``CLIPPED``): the ratio then says nothing of the lens."""
    h, w = y_half.shape
    if h < 4 or w < 4:
        return float("nan")
    cy, cx = (h - 1) / 2.0, (w - 1) / 2.0
    yy, xx = np.mgrid[0:h, 0:w]
    rho = np.sqrt(((yy - cy) ** 2 + (xx - cx) ** 2) / (cy * cy + cx * cx))
    centre = float(np.percentile(y_half[rho <= CENTRE], BRIGHT))
    if not 1.0 / 255.0 < centre < CLIPPED:
        return float("nan")
    return float(np.percentile(y_half[rho >= CORNERS], BRIGHT)) / centre


def image_stats(rgb8: np.ndarray) -> dict[str, float]:
    """Every statistic of ``IMAGE_STATS`` for one HxWx3 uint8 sRGB image."""
    rgb8 = np.asarray(rgb8)
    y = luma(rgb8)
    rgb8_half = half_rgb8(rgb8)
    rgb_half = rgb8_half.astype(np.float32) * np.float32(1.0 / 255.0)
    y_half = luma(rgb8_half)
    g_half = gradient_magnitude(y_half)
    g2 = gradient_squared(np.asarray(y, np.float32))  # full size: sharpness and halo read the same edges' gradients
    p5, p95 = percentiles(y_half, (5, 95))
    return {
        "brightness": float(y_half.mean()),
        "contrast": float(p95 - p5),
        "colourfulness": colourfulness(rgb_half),
        "saturation": saturation(rgb_half),
        "sharpness": sharpness(y, g2),
        "halo": halo(y, g2),
        "noise": noise_level(y, g_half),
        "edge_density": edge_density(g_half),
        "texture_density": texture_density(y_half),
        "vignetting": vignetting(y_half),
    }


def srgb8_to_linear(v: np.ndarray) -> np.ndarray:
    c = np.asarray(v, np.float64) / 255.0
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def lab_of_linear(rgb_linear) -> tuple[float, float, float]:
    """CIELAB (D65) of a linear sRGB colour."""
    m = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]])
    xyz = m @ np.asarray(rgb_linear, np.float64) / np.array([0.95047, 1.0, 1.08883])
    f = np.where(xyz > (6 / 29) ** 3, np.cbrt(xyz), xyz / (3 * (6 / 29) ** 2) + 4 / 29)
    return float(116 * f[1] - 16), float(500 * (f[0] - f[1])), float(200 * (f[1] - f[2]))


def linear_of_lab(L: float, a: float, b: float) -> np.ndarray:
    """The linear sRGB colour of a CIELAB (D65) one: :func:`lab_of_linear` inverted."""
    fy = (L + 16) / 116
    f = np.array([fy + a / 500, fy, fy - b / 200])
    xyz = np.where(f > 6 / 29, f ** 3, 3 * (6 / 29) ** 2 * (f - 4 / 29)) * np.array([0.95047, 1.0, 1.08883])
    m = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]])
    return np.linalg.solve(m, xyz)


OBJECT_STATS = ("obj_brightness", "obj_lightness", "obj_a", "obj_b")
MIN_OBJECT_PIXELS = 100


def object_stats(rgb8: np.ndarray, mask: np.ndarray) -> dict[str, float] | None:
    """An object's look inside its visible mask: mean luma, and the CIELAB L*, a*, b* of its mean
    (linear) colour. None when fewer than ``MIN_OBJECT_PIXELS`` pixels are visible."""
    px = np.asarray(rgb8)[np.asarray(mask, bool)]
    if len(px) < MIN_OBJECT_PIXELS:
        return None
    L, a, b = lab_of_linear(srgb8_to_linear(px).mean(0))
    return {"obj_brightness": float((px.astype(np.float64) @ _WEIGHTS).mean() / 255.0), "obj_lightness": L,
            "obj_a": a, "obj_b": b}
