"""Spatial queries for building next-event targets, outside the hot loop: the triangles within a radius of
each target, and each target's nearest other target.

A canopy of 16 roses has ~8 000 organ targets among ~340 000 triangles; :func:`kernel.targets.near_discs`
and :func:`kernel.targets.mesh_near_radius` ran these queries in numpy, one target at a time, for ~8 s of a
step (``docs/performance.md``).  Here they run compiled (numba, cached on disk like the kernel), over a
uniform grid in which each triangle is filed in the cells its bounding box overlaps: O(targets · neighbours).
Lengths in scene units.
"""
import math

import numpy as np
from numba import njit


#: a grid holds at most this many cells; a wider scene gets coarser cells
MAX_CELLS = 1 << 22
#: triangles whose bounding box spans more than this many cells along an axis are tested against every target
WIDE_CELLS = 8


@njit(cache=True)
def _box_gap2(lo, hi, i, c):
    """Squared distance from point c to triangle i's bounding box (0 inside)."""
    g2 = 0.0
    for k in range(3):
        x = min(max(c[k], lo[i, k]), hi[i, k]) - c[k]
        g2 += x * x
    return g2


@njit(cache=True)
def _grown(a):
    """``a`` (int64) in an array twice as long."""
    b = np.empty(2 * a.shape[0], np.int64)
    b[:a.shape[0]] = a
    return b


@njit(cache=True)
def _cell_range(a, b, origin, cell, dims, k):
    """The cells along axis k that the interval [a, b] overlaps, clipped to the grid: (first, last)."""
    top = float(dims[k])               # (clamped as floats first: a far point must not overflow an int64)
    i0 = int(math.floor(min(max((a - origin[k]) / cell, -1.0), top)))
    i1 = int(math.floor(min(max((b - origin[k]) / cell, -1.0), top)))
    return max(i0, 0), min(i1, dims[k] - 1)


@njit(cache=True)
def _pairs(lo, hi, center, radius, targets, cell):
    """The pairs (triangle, target) whose triangle's bounding box is within ``radius[t]`` of ``center[t]``, for t
    in ``targets``, in that order: two int64 arrays, found in one pass (the output grows as it fills).

    Each triangle is filed in every cell of a uniform grid that its bounding box overlaps (one spanning more
    than :data:`WIDE_CELLS` cells along an axis -- a chamber wall -- is tested against every target instead);
    a target visits the cells that its sphere's bounding box overlaps, and tests each triangle met there once."""
    n_tri = lo.shape[0]
    origin = np.empty(3)
    dims = np.empty(3, np.int64)
    wide = np.zeros(n_tri, np.bool_)
    while True:                                          # the grid spans the triangles that are not wide
        for i in range(n_tri):
            wide[i] = max(hi[i, 0] - lo[i, 0], hi[i, 1] - lo[i, 1], hi[i, 2] - lo[i, 2]) > WIDE_CELLS * cell
        span, extent = np.full(3, -np.inf), np.ones(3)
        for k in range(3):
            origin[k] = np.inf
            for i in range(n_tri):
                if not wide[i]:
                    origin[k] = min(origin[k], lo[i, k])
                    span[k] = max(span[k], hi[i, k])
            extent[k] = math.floor((span[k] - origin[k]) / cell) + 1.0 if span[k] >= origin[k] else 1.0
        cells = extent[0] * extent[1] * extent[2]          # (as a float: it may overflow an int64)
        if cells <= MAX_CELLS:
            break
        cell *= 1.5 * (cells / MAX_CELLS) ** (1.0 / 3.0)
    for k in range(3):
        dims[k] = int(extent[k])
    n_cells = dims[0] * dims[1] * dims[2]
    count = np.zeros(n_cells + 1, np.int64)              # triangles filed per cell, then where each cell starts
    filed = np.empty(0, np.int64)
    fill = np.empty(0, np.int64)
    for filing in range(2):                              # count the triangles of each cell, then file them
        if filing:
            for c in range(n_cells):
                count[c + 1] += count[c]
            filed = np.empty(count[n_cells], np.int64)
            fill = count[:n_cells].copy()
        for i in range(n_tri):
            if wide[i]:
                continue
            x0, x1 = _cell_range(lo[i, 0], hi[i, 0], origin, cell, dims, 0)
            y0, y1 = _cell_range(lo[i, 1], hi[i, 1], origin, cell, dims, 1)
            z0, z1 = _cell_range(lo[i, 2], hi[i, 2], origin, cell, dims, 2)
            for ix in range(x0, x1 + 1):
                for iy in range(y0, y1 + 1):
                    for iz in range(z0, z1 + 1):
                        c = (ix * dims[1] + iy) * dims[2] + iz
                        if filing:
                            filed[fill[c]] = i
                            fill[c] += 1
                        else:
                            count[c + 1] += 1
    wide_list = np.flatnonzero(wide)
    seen = np.full(n_tri, -1, np.int64)                  # the last target that tested each triangle
    n = 0
    out_tri = np.empty(16 + 4 * targets.shape[0], np.int64)
    out_t = np.empty(16 + 4 * targets.shape[0], np.int64)
    for a in range(targets.shape[0]):
        t = targets[a]
        c = center[t]
        r2 = radius[t] * radius[t]
        for i in wide_list:
            if _box_gap2(lo, hi, i, c) < r2:
                if n == out_tri.shape[0]:
                    out_tri, out_t = _grown(out_tri), _grown(out_t)
                out_tri[n], out_t[n] = i, t
                n += 1
        x0, x1 = _cell_range(c[0] - radius[t], c[0] + radius[t], origin, cell, dims, 0)
        y0, y1 = _cell_range(c[1] - radius[t], c[1] + radius[t], origin, cell, dims, 1)
        z0, z1 = _cell_range(c[2] - radius[t], c[2] + radius[t], origin, cell, dims, 2)
        for ix in range(x0, x1 + 1):
            for iy in range(y0, y1 + 1):
                for iz in range(z0, z1 + 1):
                    cc = (ix * dims[1] + iy) * dims[2] + iz
                    for e in range(count[cc], count[cc + 1]):
                        i = filed[e]
                        if seen[i] == a:
                            continue                     # filed in another cell this target has visited
                        seen[i] = a
                        if _box_gap2(lo, hi, i, c) < r2:
                            if n == out_tri.shape[0]:
                                out_tri, out_t = _grown(out_tri), _grown(out_t)
                            out_tri[n], out_t[n] = i, t
                            n += 1
    return out_tri[:n].copy(), out_t[:n].copy()


def near_pairs(lo, hi, center, radius, targets):
    """The pairs (triangle, target) whose triangle's bounding box (``lo``, ``hi`` (T, 3)) comes within
    ``radius[t]`` of ``center[t]`` ((n, 3), (n,)), for the targets ``targets`` (int64): two int64 arrays."""
    targets = np.ascontiguousarray(targets, np.int64)
    empty = np.zeros(0, np.int64)
    if len(targets) == 0 or len(lo) == 0:
        return empty, empty
    cell = max(float(np.median(radius[targets])) / 2, 1e-30)
    return _pairs(np.ascontiguousarray(lo, np.float64), np.ascontiguousarray(hi, np.float64),
                  np.ascontiguousarray(center, np.float64), np.ascontiguousarray(radius, np.float64), targets, cell)


@njit(cache=True)
def _nearest(center, targets):
    out = np.full(targets.shape[0], np.inf)
    for a in range(targets.shape[0]):
        t = targets[a]
        best = np.inf
        for s in range(center.shape[0]):
            if s != t:
                d2 = ((center[s, 0] - center[t, 0]) ** 2 + (center[s, 1] - center[t, 1]) ** 2
                      + (center[s, 2] - center[t, 2]) ** 2)
                best = min(best, d2)
        out[a] = math.sqrt(best)
    return out


def nearest_other(center, targets):
    """Distance from each of ``targets`` to the nearest other centre of ``center`` (n, 3): (len(targets),)."""
    targets = np.ascontiguousarray(targets, np.int64)
    if len(targets) == 0:
        return np.zeros(0)
    return _nearest(np.ascontiguousarray(center, np.float64), targets)
