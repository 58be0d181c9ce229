"""Spatial queries for building next-event targets, outside the hot loop: the triangles within a radius of
each target, and each target's nearest other target.

A canopy of 16 roses has ~8 000 organ targets among ~340 000 triangles; :func:`kernel.targets.near_discs`
and :func:`kernel.targets.mesh_near_radius` ran these queries in numpy, one target at a time, for ~8 s of a
step (``docs/performance.md``).  Here they run compiled (numba, cached on disk like the kernel), over a
uniform grid of the triangles' bounding-box centres: O(targets · neighbours).  Lengths in scene units.
"""
import math

import numpy as np
from numba import njit


@njit(cache=True)
def _key(ix, iy, iz):
    """A hash of an integer cell: equal cells, equal keys (different cells may share one: their triangles
    are then candidates too, and the exact test sorts them out)."""
    return (ix * 73856093) ^ (iy * 19349663) ^ (iz * 83492791)


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
def _pairs(lo, hi, center, radius, targets, cell):
    """The pairs (triangle, target) whose triangle's bounding box is within ``radius[t]`` of ``center[t]``, for t
    in ``targets``, in that order: two int64 arrays, found in one pass (the output grows as it fills)."""
    n_tri = lo.shape[0]
    keys = np.empty(n_tri, np.int64)
    wide = np.zeros(n_tri, np.bool_)
    for i in range(n_tri):
        ext = max(hi[i, 0] - lo[i, 0], hi[i, 1] - lo[i, 1], hi[i, 2] - lo[i, 2])
        if ext > cell:
            wide[i] = True                      # wider than a cell: a candidate for every target
            keys[i] = np.iinfo(np.int64).max
        else:
            keys[i] = _key(int(math.floor((lo[i, 0] + hi[i, 0]) / (2 * cell))),
                           int(math.floor((lo[i, 1] + hi[i, 1]) / (2 * cell))),
                           int(math.floor((lo[i, 2] + hi[i, 2]) / (2 * cell))))
    order = np.argsort(keys)
    sorted_keys = keys[order]
    wide_list = np.flatnonzero(wide)
    n = 0
    out_tri = np.empty(16 + 4 * targets.shape[0], np.int64)
    out_t = np.empty(16 + 4 * targets.shape[0], np.int64)
    for t in targets:
        c = center[t]
        r2 = radius[t] * radius[t]
        for i in wide_list:
            if _box_gap2(lo, hi, i, c) < r2:
                if n == out_tri.shape[0]:
                    out_tri, out_t = _grown(out_tri), _grown(out_t)
                out_tri[n], out_t[n] = i, t
                n += 1
        # a small triangle near c has its centre within radius + cell (its half-diagonal is < cell) of c
        k = int(math.ceil((radius[t] + cell) / cell))
        cx, cy, cz = int(math.floor(c[0] / cell)), int(math.floor(c[1] / cell)), int(math.floor(c[2] / cell))
        for ix in range(cx - k, cx + k + 1):
            for iy in range(cy - k, cy + k + 1):
                for iz in range(cz - k, cz + k + 1):
                    key = _key(ix, iy, iz)
                    a = np.searchsorted(sorted_keys, key)
                    while a < n_tri and sorted_keys[a] == key:
                        i = order[a]
                        a += 1
                        ox = int(math.floor((lo[i, 0] + hi[i, 0]) / (2 * cell)))
                        oy = int(math.floor((lo[i, 1] + hi[i, 1]) / (2 * cell)))
                        oz = int(math.floor((lo[i, 2] + hi[i, 2]) / (2 * cell)))
                        if ox != ix or oy != iy or oz != iz:
                            continue            # another cell with the same key: met in its own turn
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
    cell = max(float(np.median(radius[targets])), 1e-30)
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
