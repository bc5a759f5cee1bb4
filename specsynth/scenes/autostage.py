"""Stages found in a scene's geometry: free, upward-facing surfaces that objects can be dropped on.

Pure numpy, deterministic. The collider triangles are sampled into a point cloud (a fixed
low-discrepancy pattern per triangle, no RNG) and binned on an XY grid. Vertical triangles (walls,
the sides of furniture: half of a room's area) become vertical spans instead, one per half cell
along their width: they only ever block the slab above a level, and a span blocks it exactly
where a column of points would, for a hundredth of the points. For each height level of
upward-facing samples (normal within ``max_tilt`` of +Z), a grid cell is a stage cell when:

- it holds upward samples at that level (there is a surface to land on), and
- no geometry lies in the slab ``(level, level + clearance]`` above it (room to drop: a floor under
  a shelf board 10 cm up is not a stage, and the feet of what stands on a surface are cut out).

Stage cells are shrunk by ``margin`` and covered greedily by the largest axis-aligned rectangles
(each at least ``min_side`` on both sides and ``min_area`` in all): exact polygons, and what tables, shelves, counters and
open floor are. Names are stable for the same geometry: ``auto_<height mm>_<rank>``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .types import Stage

# Part of the fingerprint of every scene whose stages are found: bump when the same geometry can
# give other stages. 2: vertical triangles as spans. 3: a scene that wants only its focus stages is searched
# inside its focus areas, and a stage is the largest rectangle at least min_side on both sides (not the
# largest one, which could be a strip too thin to keep). 4: a cell with support on three sides is support.
VERSION = 4
MAX_SAMPLES = 8_000_000  # the sampling spacing grows past this, so huge scenes stay bounded
MAX_GRID_CELLS = 400 * 400  # likewise for the XY grid


@dataclass(frozen=True)
class AutoStageParams:
    clearance: float = 0.6  # metres of free space above a stage (drop height + object size)
    cell: float = 0.02  # metres, XY grid
    max_tilt_deg: float = 10.0
    height_tol: float = 0.004  # metres: a level's samples span at most this (physics' 5 mm fall-through)
    margin: float = 0.03  # metres kept free along a stage's edges
    min_side: float = 0.2  # metres: narrower rectangles are not stages
    min_area: float = 0.06  # m^2: physics cannot keep a few objects on less (a chair's seat)
    max_per_level: int = 4


def sample_triangles(tris: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Points on the triangles (about one per spacing^2) and each point's unit face normal."""
    tris = np.asarray(tris, np.float64)
    e1, e2 = tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]
    cross = np.cross(e1, e2)
    area2 = np.linalg.norm(cross, axis=1)
    keep = area2 > 1e-12
    tris, e1, e2, cross, area2 = tris[keep], e1[keep], e2[keep], cross[keep], area2[keep]
    n = np.ceil(0.5 * area2 / spacing**2).astype(np.int64) + 1
    if n.sum() > MAX_SAMPLES:
        return sample_triangles(tris, spacing * math.sqrt(n.sum() / MAX_SAMPLES))
    owner = np.repeat(np.arange(len(tris)), n)
    k = np.arange(len(owner)) - np.repeat(np.cumsum(n) - n, n)  # index of the sample within its triangle
    # R2 low-discrepancy sequence, folded from the unit square into the triangle.
    g = 1.32471795724474602596
    u = (0.5 + k / g) % 1.0
    v = (0.5 + k / g**2) % 1.0
    fold = u + v > 1.0
    u[fold], v[fold] = 1.0 - u[fold], 1.0 - v[fold]
    pts = tris[owner, 0] + u[:, None] * e1[owner] + v[:, None] * e2[owner]
    normals = cross[owner] / area2[owner, None]
    return pts, normals


def split_vertical(tris: np.ndarray, max_width: float) -> tuple[np.ndarray, np.ndarray]:
    """(vertical, rest): steep triangles (normal over 60 degrees from +Z: never a surface to land
    on) whose XY footprint is a strip at most ``max_width`` wide."""
    tris = np.asarray(tris, np.float64)
    cross = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    n_xy = np.linalg.norm(cross[:, :2], axis=1)
    u = np.stack([-cross[:, 1], cross[:, 0]], axis=1) / np.maximum(n_xy, 1e-300)[:, None]
    t = np.einsum("tvk,tk->tv", tris[:, :, :2], u)
    length = t.max(1) - t.min(1)
    # The footprint's area is |cross_z| / 2 and its length along u is `length`: width = 2 area / length.
    steep = np.abs(cross[:, 2]) < 0.5 * np.linalg.norm(cross, axis=1)
    vertical = steep & (n_xy > 1e-12) & (np.abs(cross[:, 2]) <= max_width * length)
    return tris[vertical], tris[~vertical]


def vertical_spans(tris: np.ndarray, spacing: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(xy (M, 2), z_lo (M,), z_hi (M,)): the height range each vertical triangle covers at points
    along its width: the middles of pieces at most ``spacing`` long, as a point sample would fall."""
    tris = np.asarray(tris, np.float64)
    if len(tris) == 0:
        return np.zeros((0, 2)), np.zeros(0), np.zeros(0)
    cross = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    u = np.stack([-cross[:, 1], cross[:, 0]], axis=1)
    t = np.einsum("tvk,tk->tv", tris[:, :, :2], u / np.linalg.norm(u, axis=1)[:, None])
    order = np.argsort(t, axis=1)  # vertices a, b, c along the width
    t = np.take_along_axis(t, order, 1)
    v = np.take_along_axis(tris, order[:, :, None], 1)
    n = np.maximum(np.ceil((t[:, 2] - t[:, 0]) / spacing).astype(np.int64), 1)
    owner = np.repeat(np.arange(len(tris)), n)
    k = np.arange(len(owner)) - np.repeat(np.cumsum(n) - n, n)
    t, v = t[owner], v[owner]
    ts = t[:, 0] + (t[:, 2] - t[:, 0]) * (k + 0.5) / n[owner]
    # A vertical line at ts crosses the long edge a-c, and a-b before b, b-c after it.
    f = (ts - t[:, 0]) / np.maximum(t[:, 2] - t[:, 0], 1e-300)
    on_ac = v[:, 0] + f[:, None] * (v[:, 2] - v[:, 0])
    first = ts <= t[:, 1]
    i = np.where(first, 0, 1)
    rows = np.arange(len(ts))
    ti, tj, zi, zj = t[rows, i], t[rows, i + 1], v[rows, i, 2], v[rows, i + 1, 2]
    g = np.clip((ts - ti) / np.maximum(tj - ti, 1e-300), 0.0, 1.0)
    z_other = zi + g * (zj - zi)
    return on_ac[:, :2], np.minimum(on_ac[:, 2], z_other), np.maximum(on_ac[:, 2], z_other)


def height_levels(z: np.ndarray, tol: float, min_count: int) -> list[float]:
    """Heights where upward samples cluster: sorted samples are cut into groups no more than
    ``tol`` tall (a chain of near heights never merges two surfaces), each group's lowest height.
    A group ends at the first sample more than ``tol`` above its first: one binary search per
    group (a room has ~1 M samples in a few hundred groups)."""
    z = np.asarray(z)
    zs = z if bool(np.all(z[1:] >= z[:-1])) else np.sort(z)  # find_stages passes them sorted
    levels, start, n = [], 0, len(zs)
    while start < n:
        end = int(np.searchsorted(zs, zs[start] + tol, side="right"))
        # The search compares against zs[start] + tol; the rule is zs[i] - zs[start] > tol: settle
        # the rounding at the boundary the rule's way.
        while end < n and zs[end] - zs[start] <= tol:
            end += 1
        while end > start + 1 and zs[end - 1] - zs[start] > tol:
            end -= 1
        if end - start >= min_count:
            levels.append(float(zs[start]))
        start = end
    return levels


def fill_pinholes(support: np.ndarray) -> np.ndarray:
    """``support`` with every cell that has support on at least three of its four sides.

    Samples fall about four to a cell, not evenly: now and then a cell inside a surface gets none
    (seen inside the marker board of a dressed desk), and the margin's erosion made that one cell
    a hole of five by five in the stage. A cell outside a surface's edge, straight or stepped, has
    support on two sides at most, so edges stay where they are."""
    p = np.pad(support, 1)
    sides = p[:-2, 1:-1].astype(np.int8) + p[2:, 1:-1] + p[1:-1, :-2] + p[1:-1, 2:]
    return support | (sides >= 3)


def _erode(mask: np.ndarray, r: int) -> np.ndarray:
    """Cells whose whole (2r+1)^2 neighbourhood is in the mask."""
    if r <= 0:
        return mask
    pad = np.pad(mask.astype(np.int32), r)
    s = pad.cumsum(0).cumsum(1)
    s = np.pad(s, ((1, 0), (1, 0)))
    w = 2 * r + 1
    h, wd = mask.shape
    box = s[w : w + h, w : w + wd] - s[:h, w : w + wd] - s[w : w + h, :wd] + s[:h, :wd]
    return box == w * w


def _previous_smaller(h: np.ndarray) -> np.ndarray:
    """Per row of ``h`` (R, C): for each column, the nearest column to its left with a strictly
    smaller value (-1 if none). Binary lifting over window minima: log2(C) whole-array steps."""
    ncols = h.shape[1]
    tables = [h]  # tables[k][:, p] = min(h[:, p - 2^k + 1 : p + 1]), -1 beyond the left edge
    while (1 << len(tables)) <= ncols:
        prev, step = tables[-1], 1 << (len(tables) - 1)
        shifted = np.full_like(prev, -1)
        shifted[:, step:] = prev[:, :-step]
        tables.append(np.minimum(prev, shifted))
    pos = np.broadcast_to(np.arange(ncols, dtype=np.int64), h.shape)  # all of [pos, c) is >= h[c]
    row_start = (np.arange(h.shape[0]) * ncols)[:, None]
    for k in range(len(tables) - 1, -1, -1):
        seen = tables[k].ravel().take(row_start + np.maximum(pos - 1, 0))
        pos = np.where((pos >= (1 << k)) & (seen >= h), pos - (1 << k), pos)
    return pos - 1


def largest_rectangle(mask: np.ndarray) -> tuple[int, int, int, int, int]:
    """(area, row0, col0, row1, col1) of the largest all-True rectangle (inclusive bounds).
    Row by row, the column heights of True cells form a histogram; every cell's maximal rectangle
    (its height, as wide as no lower column interrupts) is a candidate. Ties go to the lowest
    bottom row, then the leftmost right edge, then the tallest."""
    mask = np.asarray(mask, bool)
    if not mask.any():
        return (0, 0, 0, -1, -1)
    rows, ncols = mask.shape
    index = np.arange(rows)[:, None]
    last_false = np.maximum.accumulate(np.where(mask, -1, index), axis=0)
    h = np.where(mask, index - last_false, 0).astype(np.int32)
    left = _previous_smaller(h) + 1
    right = ncols - 2 - _previous_smaller(h[:, ::-1])[:, ::-1]
    area = h * (right - left + 1)
    best = area.max()
    r, c = np.nonzero(area == best)  # row-major: lowest bottom row first
    key = np.lexsort((-h[r, c], right[r, c], r))[0]
    r, c = int(r[key]), int(c[key])
    return (int(best), r - int(h[r, c]) + 1, int(left[r, c]), r, int(right[r, c]))


def crop(triangles: np.ndarray, window: tuple[float, float, float, float]) -> np.ndarray:
    """The triangles whose XY bounding box meets ``window`` (x0, y0, x1, y1)."""
    xy_lo, xy_hi = triangles[:, :, :2].min(1), triangles[:, :, :2].max(1)
    keep = ((xy_hi[:, 0] >= window[0]) & (xy_lo[:, 0] <= window[2])
            & (xy_hi[:, 1] >= window[1]) & (xy_lo[:, 1] <= window[3]))
    return triangles[keep]


def _clip_polygon(poly: list[np.ndarray], window) -> list[np.ndarray]:
    """A convex polygon (3D points) cut to the XY ``window`` by its four half-planes (Sutherland and
    Hodgman); z follows the polygon's plane."""
    for axis, bound, keep_below in ((0, window[0], False), (0, window[2], True), (1, window[1], False),
                                    (1, window[3], True)):
        out = []
        for a, b in zip(poly, poly[1:] + poly[:1]):
            ina = a[axis] <= bound if keep_below else a[axis] >= bound
            inb = b[axis] <= bound if keep_below else b[axis] >= bound
            if ina:
                out.append(a)
            if ina != inb:
                t = (bound - a[axis]) / (b[axis] - a[axis])
                out.append(a + t * (b - a))
        poly = out
        if not poly:
            break
    return poly


def clip_large(triangles: np.ndarray, window, max_area: float = 0.01) -> np.ndarray:
    """Triangles over ``max_area`` square metres (a floor, a table top) that reach outside ``window``
    cut to it and fanned into triangles again: samples are then drawn only where they count. Steep
    triangles are left whole: they become spans, which the window selects one by one."""
    cross = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    xy_lo, xy_hi = triangles[:, :, :2].min(1), triangles[:, :, :2].max(1)
    out_of = ((xy_lo[:, 0] < window[0]) | (xy_hi[:, 0] > window[2]) | (xy_lo[:, 1] < window[1])
              | (xy_hi[:, 1] > window[3]))
    big = (area > max_area) & out_of & (np.abs(cross[:, 2]) >= 0.5 * 2 * area)
    pieces = []
    for tri in triangles[big]:
        poly = _clip_polygon(list(tri), window)
        pieces += [(poly[0], poly[k], poly[k + 1]) for k in range(1, len(poly) - 1)]
    return np.concatenate([triangles[~big], np.asarray(pieces, np.float64).reshape(-1, 3, 3)])


def _inside(xy: np.ndarray, window) -> np.ndarray:
    return (xy[:, 0] >= window[0]) & (xy[:, 0] <= window[2]) & (xy[:, 1] >= window[1]) & (xy[:, 1] <= window[3])


def find_stages(triangles: np.ndarray, params: AutoStageParams = AutoStageParams(),
                window: tuple[float, float, float, float] | None = None) -> list[Stage]:
    """Stages of a scene from its collider triangles (T, 3, 3), world metres, +Z up; with ``window``
    (x0, y0, x1, y1), only the stages inside it. A cell's verdict depends only on the geometry
    over it, so a window sees what the whole scene would there, at a fraction of the samples
    (a dressed room's desk is a twentieth of its area)."""
    triangles = np.asarray(triangles, np.float64).reshape(-1, 3, 3)
    if window is not None and len(triangles):
        triangles = clip_large(crop(triangles, window), window)
    if len(triangles) == 0:
        return []
    lo = triangles.reshape(-1, 3).min(0)
    hi = triangles.reshape(-1, 3).max(0)
    if window is not None:  # the grid spans the window only
        lo[:2] = np.maximum(lo[:2], window[:2])
        hi[:2] = np.minimum(hi[:2], window[2:])
    cell = max(params.cell, math.sqrt((hi[0] - lo[0]) * (hi[1] - lo[1]) / MAX_GRID_CELLS))
    vertical, rest = split_vertical(triangles, cell / 4)
    pts, normals = sample_triangles(rest, cell / 2)
    span_xy, span_lo, span_hi = vertical_spans(vertical, cell / 2)
    if window is not None:
        kept = _inside(pts, window)
        pts, normals = pts[kept], normals[kept]
        kept = _inside(span_xy, window)
        span_xy, span_lo, span_hi = span_xy[kept], span_lo[kept], span_hi[kept]
        if len(pts) == 0:
            return []
    shape = (int((hi[1] - lo[1]) / cell) + 1, int((hi[0] - lo[0]) / cell) + 1)

    def cells(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return (np.clip(((xy[:, 1] - lo[1]) / cell).astype(np.int64), 0, shape[0] - 1),
                np.clip(((xy[:, 0] - lo[0]) / cell).astype(np.int64), 0, shape[1] - 1))

    rows, cols = cells(pts)
    span_r, span_c = cells(span_xy)
    # Spans sorted by row: a level's bounding box takes a slice of them, not a pass over all.
    by_row = np.argsort(span_r, kind="stable")
    span_r, span_c, span_lo, span_hi = span_r[by_row], span_c[by_row], span_lo[by_row], span_hi[by_row]
    up = normals[:, 2] >= math.cos(math.radians(params.max_tilt_deg))
    min_cells = (params.min_side / cell) ** 2
    # Every slab test below is a slice of the samples sorted by height (one sort, not a pass over
    # all samples per level), and every level works only inside its own support's bounding box.
    order = np.argsort(pts[:, 2], kind="stable")
    z_all, r_all, c_all = pts[order, 2], rows[order], cols[order]
    on_up = up[order]  # the upward samples in that order: the stable sort of their heights
    z_up, r_up, c_up = z_all[on_up], r_all[on_up], c_all[on_up]
    flat_all = r_all * shape[1] + c_all  # blocked cells are marked on the whole grid by flat index:
    blocked_grid = np.zeros(shape, bool)  # cheaper than cutting each slab to the level's box first
    stages = []
    for level in height_levels(z_up, params.height_tol, int(min_cells)):
        a = np.searchsorted(z_up, level, side="left")
        b = np.searchsorted(z_up, level + params.height_tol, side="right")
        r_on, c_on, z_on = r_up[a:b], c_up[a:b], z_up[a:b]
        pad = int(math.ceil(params.margin / cell)) + 1
        r0, r1 = max(int(r_on.min()) - pad, 0), min(int(r_on.max()) + pad + 1, shape[0])
        c0, c1 = max(int(c_on.min()) - pad, 0), min(int(c_on.max()) + pad + 1, shape[1])
        box = (r1 - r0, c1 - c0)
        support = np.zeros(box, bool)
        support[r_on - r0, c_on - c0] = True
        support = fill_pinholes(support)
        top = np.full(box, -np.inf)  # highest support sample per cell: where objects land
        np.maximum.at(top, (r_on - r0, c_on - c0), z_on)
        lo_a, hi_a = np.searchsorted(z_all, [level + params.height_tol, level + params.clearance], side="right")
        blocked_grid[:] = False
        blocked_grid.ravel()[flat_all[lo_a:hi_a]] = True
        blocked = blocked_grid[r0:r1, c0:c1].copy()
        s0, s1 = np.searchsorted(span_r, [r0, r1], side="left")
        sr, sc = span_r[s0:s1], span_c[s0:s1]
        crossing = ((span_hi[s0:s1] > level + params.height_tol) & (span_lo[s0:s1] <= level + params.clearance)
                    & (sc >= c0) & (sc < c1))
        blocked[sr[crossing] - r0, sc[crossing] - c0] = True
        free = _erode(support & ~blocked, int(math.ceil(params.margin / cell)))
        origin = lo + np.array([c0 * cell, r0 * cell, 0.0])
        stages += _rectangles(free, top, origin, cell, params)
    return unique_names(stages)


def unique_names(stages: list[Stage]) -> list[Stage]:
    """Two levels a hair apart, or two windows at one height, could give one name: the second and
    later get a suffix, in order."""
    seen: dict[str, int] = {}
    out = []
    for st in stages:
        seen[st.name] = seen.get(st.name, 0) + 1
        out.append(st if seen[st.name] == 1 else Stage(name=f"{st.name}_{seen[st.name]}", polygon=st.polygon,
                                                        height=st.height))
    return out


def square_corners(mask: np.ndarray, m: int) -> np.ndarray:
    """(R - m + 1, C - m + 1): where an all-True m x m square of ``mask`` has its first row and column."""
    rows, cols = mask.shape
    if m > rows or m > cols:
        return np.zeros((0, 0), bool)
    s = np.pad(mask.astype(np.int32).cumsum(0).cumsum(1), ((1, 0), (1, 0)))
    box = s[m:, m:] - s[:-m, m:] - s[m:, :-m] + s[:-m, :-m]
    return box == m * m


def largest_fitting(mask: np.ndarray, m: int) -> tuple[int, int, int, int, int]:
    """(area, row0, col0, row1, col1) of a large all-True rectangle at least ``m`` cells on both
    sides, none when there is none. A rectangle of that size is all True exactly when the corners
    of all its m x m squares are, so it is the largest rectangle of the corners grown by m - 1:
    never a long thin strip that would end the search while a stage-sized patch is left."""
    corners = square_corners(mask, m)
    if not corners.any():
        return (0, 0, 0, -1, -1)
    _, a, b, c, d = largest_rectangle(corners)
    c, d = c + m - 1, d + m - 1
    return ((c - a + 1) * (d - b + 1), a, b, c, d)


def _rectangles(free: np.ndarray, top: np.ndarray, lo: np.ndarray, cell: float, params: AutoStageParams) -> list[Stage]:
    out = []
    min_cells = int(math.ceil(params.min_side / cell))
    free = free.copy()
    for rank in range(1, params.max_per_level + 1):
        if not free.any():
            break
        ys, xs = np.nonzero(free)  # search only the bounding box of what is left
        r0, c0 = ys.min(), xs.min()
        area, a, b, c, d = largest_fitting(free[r0 : ys.max() + 1, c0 : xs.max() + 1], min_cells)
        if area == 0 or area * cell * cell < params.min_area:
            break
        a, b, c, d = a + r0, b + c0, c + r0, d + c0
        free[a : c + 1, b : d + 1] = False
        level = float(top[a : c + 1, b : d + 1].max())  # the surface's own height, not its level's
        x0, x1 = lo[0] + b * cell, lo[0] + (d + 1) * cell
        y0, y1 = lo[1] + a * cell, lo[1] + (c + 1) * cell
        poly = tuple((round(float(x), 6), round(float(y), 6)) for x, y in ((x0, y0), (x1, y0), (x1, y1), (x0, y1)))
        out.append(Stage(name=f"auto_{int(round(level * 1000)):04d}mm_{rank}", polygon=poly, height=round(level, 6)))
    return out
