"""Radiance surfaces as triangles, keeping each surface's front side.

Every function returns an ``(n, 3, 3)`` float64 array of triangles (vertex rows)
whose right-hand-rule normal points to the surface's front: for a polygon the
side its vertex order winds counter-clockwise around; outward for cylinders,
spheres and rings as Radiance defines them (``tube`` and ``bubble`` inward).
Curved surfaces are tessellated with an area-preserving radius so that the
tessellated area equals the exact one.
"""
from __future__ import annotations

import math

import numpy as np

from ..kernel.vectors import norm as vnorm

#: coordinates beyond this (in scene units) are refused: Embree traces in single precision
MAX_COORDINATE = 1e12


def newell_normal(points: np.ndarray) -> np.ndarray:
    """Area-weighted normal of a (possibly non-planar) polygon, (3,); its length is twice the area."""
    p = np.asarray(points, dtype=float)
    q = np.roll(p, -1, axis=0)
    return np.array([np.sum((p[:, 1] - q[:, 1]) * (p[:, 2] + q[:, 2])),
                     np.sum((p[:, 2] - q[:, 2]) * (p[:, 0] + q[:, 0])),
                     np.sum((p[:, 0] - q[:, 0]) * (p[:, 1] + q[:, 1]))])


def triangulate_polygon(points) -> np.ndarray:
    """Ear-clip a simple polygon (convex or not) into triangles with its winding.

    ``points``: (n, 3), n >= 3.  Repeated consecutive vertices are dropped.
    Raises ``ValueError`` for a polygon of zero area.
    """
    p = np.asarray(points, dtype=float)
    keep = np.ones(len(p), bool)
    keep[1:] = np.any(p[1:] != p[:-1], axis=1)
    p = p[keep]
    if len(p) > 1 and np.all(p[0] == p[-1]):
        p = p[:-1]
    if len(p) < 3:
        raise ValueError("polygon has fewer than 3 distinct vertices")
    normal = newell_normal(p)
    norm = vnorm(normal)
    scale = np.abs(p).max() + np.ptp(p, axis=0).max()
    if not norm > 1e-12 * scale * scale:
        raise ValueError("polygon has zero area")
    normal /= norm
    if len(p) == 3:
        return p[None].copy()
    # project to the plane's 2-D frame, counter-clockwise seen from the front
    axis = np.argmax(np.abs(normal))
    u, v = [(1, 2), (2, 0), (0, 1)][axis]
    xy = p[:, [u, v]]
    if normal[axis] < 0:
        xy = xy[:, ::-1]
    return p[np.array(_ear_clip(xy))]


def _corner_turns(xy: np.ndarray) -> np.ndarray:
    """(n,) cross product (b − a) × (c − a) at each corner b of the closed 2-D outline ``xy`` (n, 2), a and c
    its neighbours: > 0 convex (counter-clockwise), <= 0 reflex or flat."""
    a, c = np.roll(xy, 1, axis=0), np.roll(xy, -1, axis=0)
    return (xy[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (xy[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])


def _ear_clip(xy: np.ndarray) -> list:
    """Triangles (index triples) of the counter-clockwise outline ``xy`` (n, 2), by ear clipping.

    Each round clips the first corner that is convex and holds no reflex vertex (:func:`_blocks`); a convex
    outline gives the same fan at once (O(n), for the many-sided polygons of a tessellated disc)."""
    n = len(xy)
    turns = _corner_turns(xy)
    if np.all(turns > 0):
        a, c = np.roll(xy, 1, axis=0), np.roll(xy, -1, axis=0)
        winding = np.arctan2(turns, ((xy - a) * (c - xy)).sum(axis=1)).sum()
        if abs(winding - 2 * np.pi) < 1e-6:     # convex and simple (a pentagram turns twice): clip 0, 1, ...
            return [(n - 1, k, k + 1) for k in range(n - 3)] + [(n - 3, n - 2, n - 1)]
    idx = np.arange(n)
    tris = []
    while len(idx) > 3:
        pts = xy[idx]
        turns = _corner_turns(pts)
        reflex = np.flatnonzero(turns <= 0)
        m = len(idx)
        for k in np.flatnonzero(turns > 0):
            a, b, c = pts[k - 1], pts[k], pts[(k + 1) % m]
            near = reflex[(reflex != (k - 1) % m) & (reflex != k) & (reflex != (k + 1) % m)]
            if len(near) and _blocks(pts[near], a, b, c).any():
                continue
            tris.append((int(idx[k - 1]), int(idx[k]), int(idx[(k + 1) % m])))
            idx = np.delete(idx, k)
            break
        else:
            break   # no ear found (self-intersecting): fall back to a fan of what is left
    if len(idx) > 3:
        tris.extend((int(idx[0]), int(idx[k]), int(idx[k + 1])) for k in range(1, len(idx) - 1))
    else:
        tris.append(tuple(int(i) for i in idx))
    return tris


def _blocks(q: np.ndarray, a, b, c) -> np.ndarray:
    """Which reflex (or flat) vertices ``q`` (k, 2) forbid the ear (a, b, c): those inside it or on its
    edges (a convex vertex cannot be inside an ear without an edge of the outline being inside too).  One at
    the same place as a, b or c does not: a hole joined to the outline by a seam (Radiance's way of cutting a
    hole) visits the seam's two ends twice, and those copies touch the ears beside them."""
    same = np.zeros(len(q), bool)
    for corner in (a, b, c):
        same |= (q[:, 0] == corner[0]) & (q[:, 1] == corner[1])
    d1 = (q[:, 0] - b[0]) * (a[1] - b[1]) - (a[0] - b[0]) * (q[:, 1] - b[1])
    d2 = (q[:, 0] - c[0]) * (b[1] - c[1]) - (b[0] - c[0]) * (q[:, 1] - c[1])
    d3 = (q[:, 0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (q[:, 1] - a[1])
    neg = (d1 < 0) | (d2 < 0) | (d3 < 0)
    pos = (d1 > 0) | (d2 > 0) | (d3 > 0)
    return ~(neg & pos) & ~same


def _ring_points(center, axis, radius, n):
    """n points on a circle, counter-clockwise seen from +axis; radius chosen so that the
    n-gon has the circle's area."""
    axis = np.asarray(axis, float) / vnorm(axis)
    helper = np.array([1.0, 0, 0]) if abs(axis[0]) < 0.9 else np.array([0, 1.0, 0])
    t = np.cross(axis, helper)
    t /= vnorm(t)
    b = np.cross(axis, t)
    r = radius * math.sqrt(2 * math.pi / (n * math.sin(2 * math.pi / n)))
    phi = 2 * math.pi * np.arange(n) / n
    return np.asarray(center, float) + r * (np.cos(phi)[:, None] * t + np.sin(phi)[:, None] * b)


def cylinder(p0, p1, radius, segments: int = 24, inward: bool = False) -> np.ndarray:
    """Open cylinder from ``p0`` to ``p1``; outward-facing unless ``inward`` (Radiance ``tube``).

    The polygon's radius keeps the lateral area exact to first order (perimeter preserved).
    """
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    axis = p1 - p0
    ring = _ring_points(np.zeros(3), axis, 1.0, segments)
    ring *= radius * (math.pi / (segments * math.sin(math.pi / segments))) / vnorm(ring[0])
    a, b = p0 + ring, p1 + ring
    a2, b2 = np.roll(a, -1, axis=0), np.roll(b, -1, axis=0)
    tris = np.concatenate([np.stack([a, a2, b2], 1), np.stack([a, b2, b], 1)])
    return tris[:, ::-1].copy() if inward else tris


def sphere(center, radius, subdivisions: int = 2, inward: bool = False) -> np.ndarray:
    """Icosphere scaled so its total area equals 4πr²; outward unless ``inward`` (``bubble``)."""
    t = (1 + math.sqrt(5)) / 2
    v = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
                  [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], float)
    f = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
                  [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5],
                  [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]])
    tris = v[f]
    tris /= np.linalg.norm(tris, axis=2, keepdims=True)
    for _ in range(subdivisions):
        a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
        ab, bc, ca = [(x + y) / np.linalg.norm(x + y, axis=1, keepdims=True) for x, y in ((a, b), (b, c), (c, a))]
        tris = np.concatenate([np.stack(s, 1) for s in ((a, ab, ca), (ab, b, bc), (ca, bc, c), (ab, bc, ca))])
    area = triangle_areas(tris).sum()
    tris *= math.sqrt(4 * math.pi / area) * radius
    tris += np.asarray(center, float)
    return tris[:, ::-1].copy() if inward else tris


def ring(center, normal, r_inner, r_outer, segments: int = 24) -> np.ndarray:
    """Flat annulus (disc if ``r_inner`` = 0) facing ``normal``, with the exact area."""
    outer = _ring_points(center, normal, r_outer, segments)
    c = np.asarray(center, float)
    if r_inner <= 0:
        return np.stack([np.broadcast_to(c, outer.shape), outer, np.roll(outer, -1, axis=0)], 1)
    inner = _ring_points(center, normal, r_inner, segments)
    o2, i2 = np.roll(outer, -1, axis=0), np.roll(inner, -1, axis=0)
    return np.concatenate([np.stack([inner, outer, o2], 1), np.stack([inner, o2, i2], 1)])


def triangle_normals(tris: np.ndarray) -> np.ndarray:
    """Unit right-hand-rule normals of (n, 3, 3) triangles, (n, 3); zero rows for degenerate ones."""
    n = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(length > 0, n / np.where(length > 0, length, 1), 0.0)


def triangle_areas(tris: np.ndarray) -> np.ndarray:
    """Areas of (n, 3, 3) triangles, (n,)."""
    return 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)


def plane_ids(tris: np.ndarray, rel_tol: float = 1e-9) -> np.ndarray:
    """An id per triangle of (n, 3, 3) ``tris``, shared by triangles in one plane (either orientation), (n,) int32.

    Planes are compared by their unit normal up to sign and their offset, rounded to ``rel_tol`` of the
    scene's size; -1 for degenerate triangles.  Rounding may split one plane in two ids (never merges two
    planes): callers use ids as "same plane" tests that need only be consistent, not complete."""
    if len(tris) == 0:
        return np.zeros(0, np.int32)
    n = triangle_normals(tris)
    first = np.argmax(np.abs(n) > 1e-12, axis=1)
    sign = np.where(n[np.arange(len(n)), first] < 0, -1.0, 1.0)
    n = n * sign[:, None]
    d = np.einsum("ij,ij->i", n, tris[:, 0])
    scale = max(float(np.abs(tris).max()), 1e-300)
    key = np.column_stack([np.round(n / 1e-9), np.round(d / (rel_tol * scale))])
    _, ids = np.unique(key, axis=0, return_inverse=True)
    ids = ids.reshape(-1).astype(np.int32)
    ids[~np.any(n != 0, axis=1)] = -1
    return ids


def coplanar_partners(tris: np.ndarray, source: np.ndarray, two_sided=None, rel_tol: float = 1e-9):
    """Triangles lying in the same plane as another surface's triangles, with overlapping bounds.

    Two coincident surfaces (e.g. a cornice and a ceiling sheet modelled in one plane) make the
    nearest hit a tie that float rounding settles; the kernel lets such a hit pick one of the
    triangles that contain the point at random (``physics.coplanar = "random"``).  Returns CSR
    arrays ``(start (T+1,) int64, partners (K,) int32)``: triangle i's candidates are
    ``partners[start[i]:start[i+1]]`` -- triangles of *other* source surfaces whose plane is the
    same (either orientation, within ``rel_tol`` of the coordinates' magnitude: coincident as written,
    not merely close) and whose bounding boxes
    overlap i's.  With ``two_sided`` (T,) bool, a pair of one-sided triangles facing opposite ways
    is left out (a ray never sees both).  Whether the hit point lies inside a candidate is decided
    at the hit.
    """
    tris = np.asarray(tris, float)
    T = len(tris)
    start = np.zeros(T + 1, np.int64)
    if T < 2:
        return start, np.zeros(0, np.int32)
    source = np.asarray(source)
    n = triangle_normals(tris)
    # canonical orientation: first non-negligible component positive
    lead = np.argmax(np.abs(n) > 1e-9, axis=1)
    sign = np.where(n[np.arange(T), lead] < 0, -1.0, 1.0)
    cn = n * sign[:, None]
    d = np.einsum("ij,ij->i", cn, tris[:, 0])
    tol = rel_tol * max(float(np.abs(tris).max()), 1e-30)
    lo, hi = tris.min(axis=1), tris.max(axis=1)
    partners = [[] for _ in range(T)]
    valid = np.linalg.norm(n, axis=1) > 0
    key = np.round(cn / 1e-6).astype(np.int64)
    groups = {}
    for i in np.flatnonzero(valid):
        groups.setdefault(tuple(key[i]), []).append(i)
    for members in groups.values():
        if len(members) < 2:
            continue
        members = np.array(members)
        members = members[np.argsort(d[members])]
        dm = d[members]
        cut = np.flatnonzero(np.diff(dm) > tol) + 1
        for plane in np.split(members, cut):
            if len(plane) < 2 or len(np.unique(source[plane])) < 2:
                continue
            # bounding boxes overlapping by more than the tolerance (in the plane's two spanning axes)
            a_lo, a_hi = lo[plane], hi[plane]
            over = np.all((a_lo[:, None, :] < a_hi[None, :, :] - tol) | (np.abs(cn[plane[0]]) > 1 - 1e-9)[None, None, :],
                          axis=2) & np.all((a_lo[None, :, :] < a_hi[:, None, :] - tol)
                                           | (np.abs(cn[plane[0]]) > 1 - 1e-9)[None, None, :], axis=2)
            other = source[plane][:, None] != source[plane][None, :]
            if two_sided is not None:
                one = ~np.asarray(two_sided, bool)[plane]
                same_way = np.einsum("ik,jk->ij", n[plane], n[plane]) > 0
                other &= same_way | ~(one[:, None] & one[None, :])
            ii, jj = np.nonzero(over & other)
            for i, j in zip(plane[ii], plane[jj]):
                partners[i].append(j)
    for i in range(T):
        start[i + 1] = start[i] + len(partners[i])
    flat = np.array([j for p in partners for j in p], np.int32)
    return start, flat


def partner_free_boxes(tris: np.ndarray, start: np.ndarray, partners: np.ndarray, pad: float) -> np.ndarray:
    """Per triangle, an axis-aligned box inside its own bounds that meets none of its coplanar
    partners' bounds (widened by ``pad``), (T, 2, 3): a hit point inside it has no competitor, so
    the kernel skips the per-partner tests there (e.g. the whole Makrolon ceiling but its 40 mm
    rim).  Built by shrinking the triangle's box, partner by partner, along the axis that loses
    the least; empty (lo > hi) where nothing is left.  Only an accelerator: any box that avoids
    the partners is correct."""
    tris = np.asarray(tris, float)
    lo, hi = tris.min(axis=1) - pad, tris.max(axis=1) + pad
    box = np.stack([lo, hi], axis=1).copy()
    for i in range(len(tris)):
        b_lo, b_hi = box[i, 0], box[i, 1]
        for j in partners[start[i]:start[i + 1]]:
            p_lo, p_hi = lo[j], hi[j]
            if np.any(p_hi < b_lo) or np.any(p_lo > b_hi):
                continue                                  # already apart
            best, best_keep = None, -1.0
            for k in range(3):
                length = b_hi[k] - b_lo[k]
                if length <= 2 * pad:                     # the plane's own (flat) axis: no room
                    continue
                if p_lo[k] > b_lo[k] and (p_lo[k] - b_lo[k]) / length > best_keep:
                    best, best_keep = (k, 1, p_lo[k] - pad), (p_lo[k] - b_lo[k]) / length
                if p_hi[k] < b_hi[k] and (b_hi[k] - p_hi[k]) / length > best_keep:
                    best, best_keep = (k, 0, p_hi[k] + pad), (b_hi[k] - p_hi[k]) / length
            if best is None:
                b_lo[:], b_hi[:] = 1.0, -1.0              # empty
                break
            k, side, value = best
            if side == 1:
                b_hi[k] = value
            else:
                b_lo[k] = value
    return box


def mirror_planes(tris: np.ndarray, source: np.ndarray, specular: np.ndarray, two_sided=None,
                  rel_tol: float = 1e-9):
    """Planar surfaces that can reflect specularly, for next events through a mirror (the image method).

    ``tris`` (T, 3, 3), ``source`` (T,) the surface each triangle comes from, ``specular`` (T,) bool: does
    the triangle reflect specularly (perfect mirror) on a side it is seen from; ``two_sided`` (T,) bool or
    None.  A surface is a plane when all its triangles share one (within ``rel_tol`` of the coordinates'
    magnitude).  Returns ``tri_plane`` (T,) int32 (plane index or -1), ``point`` (P, 3) and unit
    ``normal`` (P, 3) (the first triangle's normal orientation), ``bounds`` (P, 2, 3) (min, max of the
    plane's vertices) and ``one_sided`` (P,) bool (no triangle of the plane is two-sided).
    """
    tri_plane = np.full(len(tris), -1, np.int32)
    points, normals = [], []
    if len(tris) == 0:
        return tri_plane, np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 2, 3)), np.zeros(0, bool)
    n = triangle_normals(tris)
    scale = max(float(np.abs(tris).max()), 1e-300)
    order = np.argsort(source, kind="stable")
    src = np.asarray(source)[order]
    bounds = np.flatnonzero(np.diff(src)) + 1
    for group in np.split(order, bounds):
        if not specular[group].any():
            continue
        n0 = n[group[0]]
        if not np.all(np.isfinite(n0)) or vnorm(n0) == 0:
            continue
        p0 = tris[group[0], 0]
        dist = np.abs(np.einsum("ijk,k->ij", tris[group] - p0, n0))      # einsum, not BLAS: the same bits everywhere
        parallel = np.abs(np.abs(np.einsum("ik,k->i", n[group], n0)) - 1.0)
        if dist.max() > rel_tol * scale or parallel.max() > 1e-9:
            continue                    # not flat: no image
        tri_plane[group] = len(points)
        points.append(p0)
        normals.append(n0)
    P, on = len(points), tri_plane >= 0
    bounds = np.stack([np.full((P, 3), np.inf), np.full((P, 3), -np.inf)], axis=1)
    np.minimum.at(bounds[:, 0], tri_plane[on], tris[on].min(axis=1))
    np.maximum.at(bounds[:, 1], tri_plane[on], tris[on].max(axis=1))
    any_two = np.zeros(P, bool)
    if two_sided is not None:
        np.logical_or.at(any_two, tri_plane[on], np.asarray(two_sided, bool)[on])
    return (tri_plane, np.array(points, float).reshape(-1, 3), np.array(normals, float).reshape(-1, 3),
            bounds, ~any_two)
