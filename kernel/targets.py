"""Next-event targets: which sensors and receivers next events aim at, as arrays for the kernel.

numpy, run once per scene or change of organs (``lpy_light.estimators.kernel_scene.KernelScene.retarget``), outside the
hot loop.  Targets are transparent sensors (discs and quads; sensor targets come first) and receivers
(meshes: organs, two-sided, and solid sensors, one-sided); each gets the tally row of its light, an
exclusion radius within which a vertex counts its crossings instead (1/d² is heavy-tailed near a quad or a
mesh), and, for discs, the triangles near enough to give the disc an event of its own (:func:`near_discs`).
Lengths in scene units, areas in scene units².
"""
import math

import numpy as np

from .nee import EXACT_TRIANGLES, MESH_OWN, NEAR, NEAR_FLOOR, NEAR_PICKED
from .neighbours import near_pairs, nearest_other
from .records import T_DISC, T_MESH1, T_MESH2, T_QUAD, Clusters, Targets, f64, i64
from .vectors import norm


def build_targets(sens, sens_area, sens_bound, n_receivers_rows, tri_receiver, tri_verts, tri_two_sided,
                  sensors=True, receivers=True, receiver_mask=None, *, tri_normal):
    """The next-event targets (:class:`~kernel.records.Targets`) of a scene; numpy, outside the hot loop.

    ``sens`` the sensors' :class:`~kernel.records.Sensors` (S of them), ``sens_area`` (S,) their areas and
    ``sens_bound`` (S,) their bounding radii about their centres; ``n_receivers_rows`` R;
    ``tri_receiver`` (T,) receiver index per kernel triangle or -1; ``tri_verts`` (T, 3, 3);
    ``tri_two_sided`` (T,) bool; ``tri_normal`` (T, 3) the kernel's unit normals.  Receiver r's incident row is S + r and its absorbed row S + R + r
    (:mod:`kernel.tallies`).  ``sensors``, ``receivers``: whether they are targets; ``receiver_mask`` (R,)
    bool or None: only these receivers are targets (the others are still tallied, by counting).

    Returns a :class:`~kernel.records.Targets` whose settings (``on_sensors``, ``on_receivers``: the
    flags given; ``picks``, ``from_material``, ``from_emitter``: 0 and empty) are the caller's to set.
    """
    n_sensors = len(sens.kind)
    sens_kind, sens_center = sens.kind, sens.center
    receiver_row0, absorbed_row0 = n_sensors, n_sensors + n_receivers_rows
    kind, row, abs_row, ref, first, count, area, center, near2 = [], [], [], [], [], [], [], [], []
    img_near2, facing = [], []
    sensor_target = np.full(n_sensors, -1, np.int64)
    receiver_target = np.full(n_receivers_rows, -1, np.int64)
    nee_tri, nee_cdf = [], []
    if sensors:
        for s in range(n_sensors):
            kind.append(T_DISC if sens_kind[s] == 0 else T_QUAD)
            row.append(s)
            abs_row.append(-1)
            ref.append(s)
            first.append(0)
            count.append(0)
            area.append(float(sens_area[s]))
            center.append(sens_center[s])
            # discs are sampled by solid angle (bounded next events): no exclusion zone, except through mirrors
            img_near2.append(float((NEAR * sens_bound[s]) ** 2))
            near2.append(0.0 if sens_kind[s] == 0 else img_near2[-1])
            sensor_target[s] = len(kind) - 1
            facing.append(0)
    if receivers and n_receivers_rows:
        # receivers' triangles grouped by receiver (stable: each in its own order), summed per group in numpy
        tri_area = 0.5 * np.linalg.norm(np.cross(tri_verts[:, 1] - tri_verts[:, 0], tri_verts[:, 2] - tri_verts[:, 0]),
                                        axis=1)
        order = np.argsort(tri_receiver, kind="stable")
        order = order[tri_receiver[order] >= 0]
        recv = tri_receiver[order]
        r_first = np.flatnonzero(np.r_[True, recv[1:] != recv[:-1]]) if len(recv) else np.zeros(0, np.int64)
        r_of = recv[r_first]
        r_count = np.diff(np.r_[r_first, len(recv)])
        a = tri_area[order]
        r_total = np.add.reduceat(a, r_first) if len(a) else np.zeros(0)      # (only to skip empty receivers)
        pts_lo = tri_verts[order].min(axis=1)
        pts_hi = tri_verts[order].max(axis=1)
        r_lo = np.minimum.reduceat(pts_lo, r_first) if len(a) else np.zeros((0, 3))
        r_hi = np.maximum.reduceat(pts_hi, r_first) if len(a) else np.zeros((0, 3))
        r_two = np.logical_and.reduceat(tri_two_sided[order].astype(bool), r_first) if len(a) else np.zeros(0, bool)
        keep = r_total > 0
        if receiver_mask is not None:
            keep &= np.asarray(receiver_mask, bool)[r_of]
        # closed two-sided meshes small enough for facing points (kernel.nee.facing_triangle); one-sided ones need
        # no test
        r_closed = np.zeros(int(recv.max()) + 1 if len(recv) else 0, bool)
        test = np.repeat(keep & r_two & (r_count <= EXACT_TRIANGLES), r_count)
        if test.any():
            found = closed_meshes(tri_verts[order][test], recv[test])
            r_closed[:len(found)] = found
        offset = 0
        for g in np.flatnonzero(keep):
            r = int(r_of[g])
            lo_g, hi_g = r_first[g], r_first[g] + r_count[g]
            kind.append(T_MESH2 if r_two[g] else T_MESH1)
            facing.append(1 if (not r_two[g] or r_closed[r]) and r_count[g] <= EXACT_TRIANGLES else 0)
            row.append(receiver_row0 + r)
            abs_row.append(absorbed_row0 + r)
            ref.append(r)
            first.append(offset)
            count.append(int(r_count[g]))
            offset += int(r_count[g])
            total = a[lo_g:hi_g].sum()
            area.append(float(total))
            cdf = np.cumsum(a[lo_g:hi_g]) / total          # points on a mesh target are drawn by area
            cdf[-1] = 1.0 + 1e-12
            nee_tri.append(order[lo_g:hi_g])
            nee_cdf.append(cdf)
            center.append((r_lo[g] + r_hi[g]) / 2)
            img_near2.append(float((NEAR * norm(r_hi[g] - r_lo[g]) / 2) ** 2))
            near2.append(0.0)     # no exclusion: a triangle near v is sampled by solid angle (kernel.nee)
            receiver_target[r] = len(kind) - 1
    center = f64(np.reshape(center, (-1, 3)))
    disc_radius = np.zeros(len(kind))
    for s in range(n_sensors):
        if sensor_target[s] >= 0 and sens_kind[s] == 0:
            disc_radius[sensor_target[s]] = sens_bound[s]
    # organs near a vertex get next events of their own too (a random pick would deposit n / picks times
    # their large near light, rarely: the far red a bud gets from the leaf and stem it touches)
    mesh_bound = np.array([math.sqrt(img_near2[t]) / NEAR if kind[t] >= T_MESH2 else 0.0 for t in range(len(kind))])
    mesh_radius = mesh_near_radius(center, mesh_bound)
    near_start, near_list, near_r2 = near_discs(tri_verts, center, disc_radius, mesh_radius=mesh_radius)
    tri = i64(np.concatenate(nee_tri) if nee_tri else np.zeros(0))
    tri_plane = f64(np.concatenate([np.reshape(tri_verts, (-1, 3, 3))[tri, 0], np.reshape(tri_normal, (-1, 3))[tri]],
                                   axis=1) if len(tri) else np.zeros((0, 6)))
    return Targets(bool(sensors), bool(receivers), 0, np.zeros(0, np.uint8), np.zeros(0, np.uint8),
                   np.ascontiguousarray(kind, dtype=np.int32), i64(row), i64(abs_row), i64(ref), i64(first),
                   i64(count), f64(area), center, f64(near2), f64(img_near2), tri,
                   f64(np.concatenate(nee_cdf) if nee_cdf else np.zeros(0)), tri_plane,
                   near_start, near_list, near_r2, sensor_target, receiver_target,
                   np.ascontiguousarray(facing, dtype=np.uint8))


def closed_meshes(tris, group):
    """(G,) bool, G = group.max() + 1: whether the triangles of each group (``tris`` (T, 3, 3), ``group`` (T,)
    int, e.g. each triangle's receiver) form a closed surface wound outward -- every edge shared by exactly two
    of its triangles, run in opposite directions by them (watertight, consistently wound), and a positive
    enclosed volume.  Vertices are the same where their coordinates are equal (as a mesh's triangles share
    them).  From a point outside such a surface only the triangles facing it can be seen."""
    group = np.asarray(group, np.int64)
    n_groups = int(group.max()) + 1 if len(group) else 0
    closed = np.zeros(n_groups, bool)
    if len(tris) == 0:
        return closed
    pts = np.ascontiguousarray(tris, np.float64).reshape(-1, 3)
    g3 = np.repeat(group, 3)
    srt = np.lexsort((pts[:, 2], pts[:, 1], pts[:, 0], g3))                     # a vertex is its group and place
    new = np.ones(len(srt), bool)
    new[1:] = (g3[srt][1:] != g3[srt][:-1]) | np.any(pts[srt][1:] != pts[srt][:-1], axis=1)
    vid = np.empty(len(srt), np.int64)
    vid[srt] = np.cumsum(new) - 1
    vid = vid.reshape(-1, 3)
    a, b = vid, np.roll(vid, -1, axis=1)                                        # directed edges a -> b
    n_v = int(vid.max()) + 1
    fwd = (a.ravel() * n_v + b.ravel())                                          # (vertex ids are per group)
    rev = (b.ravel() * n_v + a.ravel())
    order = np.argsort(fwd, kind="stable")
    sf = fwd[order]
    unique_edge = np.ones(len(fwd), bool)                                         # each directed edge once
    dup = np.flatnonzero(sf[1:] == sf[:-1])
    unique_edge[order[dup]] = unique_edge[order[dup + 1]] = False
    pos = np.minimum(np.searchsorted(sf, rev), len(sf) - 1)
    paired = sf[pos] == rev                                                      # and its reverse there too
    edge_ok = unique_edge & paired & (a.ravel() != b.ravel())
    bad = np.zeros(n_groups, bool)
    np.logical_or.at(bad, g3, ~edge_ok)
    lo = np.full((n_groups, 3), np.inf)
    np.minimum.at(lo, group, tris.min(axis=1))
    p = tris - lo[group][:, None, :]                                              # (volumes about a nearby corner)
    vol = np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])) / 6.0
    volume = np.bincount(group, weights=vol, minlength=n_groups)
    present = np.bincount(group, minlength=n_groups) > 0
    return present & ~bad & (volume > 0.0)


def near_discs(tri_verts, center, disc_radius, factor=NEAR_PICKED, mesh_radius=None):
    """Which disc targets are *near* a vertex, for :func:`kernel.nee.next_event`'s own events, and on which triangles.

    A random pick among n targets deposits n times a target's expected value; near a disc (solid angle
    ≳ 1/n) that is a large deposit made rarely, worse than an event of its own.  Disc t is near v when
    |v − c_t| < ``factor`` · a_t · √n (a_t its radius): there the disc's solid angle exceeds about
    π / (factor² · n).  That radius is capped at 1.5 × the distance from c_t to the nearest other target,
    so that a vertex amid a dense grid of many discs makes a handful of own events (≲ 10 in a plane), not
    hundreds -- but never below :data:`NEAR_FLOOR` · a_t: closer than that the control variate's point
    value (∝ area / distance²) is no approximation of the disc (a disc wider than the room beside a small
    one gave picks of ±10⁴ times the light, a 500 % σ).  ``tri_verts`` (T, 3, 3); ``center`` (n, 3); ``disc_radius`` (n,), 0 for targets that
    are not discs.  Returns ``near_start`` (T + 1,) int64, ``near_list`` int64 (the discs whose near zone
    meets each triangle's bounding box, a superset of those near any of its points) and ``near_r2`` (n,).
    """
    n = len(center)
    radius = factor * disc_radius * math.sqrt(max(n, 1))
    for t in np.flatnonzero(radius > 0):
        gap = center - center[t]
        d2 = np.einsum("ij,ij->i", gap, gap)
        d2[t] = np.inf
        radius[t] = max(min(radius[t], 1.5 * math.sqrt(d2.min())), NEAR_FLOOR * disc_radius[t])
    meshes = np.zeros(n, bool)
    if mesh_radius is not None:
        meshes = (disc_radius <= 0) & (np.asarray(mesh_radius) > 0)
        radius = np.where(meshes, mesh_radius, radius)
    near_r2 = np.ascontiguousarray(radius ** 2, dtype=np.float64)
    lo, hi = tri_verts.min(axis=1), tri_verts.max(axis=1)
    pairs_tri, pairs_t = [], []
    for t in np.flatnonzero((near_r2 > 0) & ~meshes):        # discs: a few hundred at most
        gap = np.clip(center[t], lo, hi) - center[t]
        tris = np.flatnonzero(np.einsum("ij,ij->i", gap, gap) < near_r2[t])
        pairs_tri.append(tris)
        pairs_t.append(np.full(len(tris), t))
    mesh_tri, mesh_t = near_pairs(lo, hi, center, radius, np.flatnonzero((near_r2 > 0) & meshes))   # organs: many
    tris = np.concatenate(pairs_tri + [mesh_tri]).astype(np.int64)
    ts = np.concatenate(pairs_t + [mesh_t]).astype(np.int64)
    order = np.argsort(tris, kind="stable")
    near_start = np.zeros(len(tri_verts) + 1, np.int64)
    np.cumsum(np.bincount(tris, minlength=len(tri_verts)), out=near_start[1:])
    return near_start, np.ascontiguousarray(ts[order], dtype=np.int64), near_r2


def mesh_near_radius(center, bound, factor=NEAR_PICKED):
    """Near radii of mesh targets (0 for the others), the rule of :func:`near_discs` for discs: a · √n (a
    the bounding radius, n the targets), where a random pick would deposit n / picks times a light of solid
    angle ≳ 1/n, capped at 1.5 × the distance to the nearest other target (a vertex amid a canopy then
    makes a handful of own events, not hundreds) and at least :data:`~kernel.nee.MESH_OWN` · a.
    ``center`` (n, 3), ``bound`` (n,).  Returns (n,) float64."""
    n = len(bound)
    radius = np.zeros(n)
    mesh = np.flatnonzero(bound > 0)
    if len(mesh) == 0:
        return radius
    nearest = nearest_other(center, mesh)
    b = bound[mesh]
    radius[mesh] = np.maximum(np.minimum(factor * b * math.sqrt(n), 1.5 * nearest), MESH_OWN * b)
    return radius


def target_clusters(center, bound, size=None):
    """Targets grouped in space for picks by importance (:func:`kernel.nee.pick_by_importance`): halves split at
    the median of their centres along the widest axis, until at most ``size`` targets (default ⌈√n⌉, at least
    8) remain.  ``center`` (n, 3), ``bound`` (n,) bounding radii.  Returns ``(start (K + 1,), member (n,),
    cluster centre (K, 3), cluster radius (K,))``: cluster k holds targets ``member[start[k] : start[k + 1]]``
    within a sphere of that centre and radius, as a :class:`~kernel.records.Clusters`."""
    n = len(center)
    if n == 0:
        return Clusters(np.zeros(1, np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0))
    size = max(8, int(math.ceil(math.sqrt(n)))) if size is None else size
    groups, todo = [], [np.arange(n)]
    while todo:
        idx = todo.pop()
        if len(idx) <= size:
            groups.append(idx)
            continue
        pts = center[idx]
        axis = int(np.argmax(pts.max(axis=0) - pts.min(axis=0)))
        order = idx[np.argsort(pts[:, axis], kind="stable")]
        todo += [order[len(order) // 2:], order[:len(order) // 2]]
    start = np.zeros(len(groups) + 1, np.int64)
    np.cumsum([len(g) for g in groups], out=start[1:])
    member = np.concatenate(groups).astype(np.int64) if groups else np.zeros(0, np.int64)
    c = np.array([(center[g].min(axis=0) + center[g].max(axis=0)) / 2 for g in groups]).reshape(-1, 3)
    r = np.array([np.max(np.linalg.norm(center[g] - c[k], axis=1) + bound[g]) for k, g in enumerate(groups)])
    return Clusters(start, member, f64(c), f64(r))


def cluster_sums(weight, clusters):
    """(K,) float64: the sum of ``weight`` (n,) over each cluster's targets."""
    member, start = clusters.member, clusters.start
    if len(member) == 0:
        return np.zeros(len(start) - 1)
    return f64(np.add.reduceat(np.asarray(weight, float)[member], start[:-1]))


#: a target is served by cone rays (:mod:`kernel.cones`) from far vertices when its area is at least this share
#: of the mean cross-section per target of the clusters' spheres; smaller ones (buds) keep their picks
CONE_SHARE = 0.1


def cone_served(area, clusters, share=None):
    """(n,) bool: the targets served by :mod:`kernel.cones` from vertices far from their cluster.

    From there a cone ray meets target t with a probability about its projected area over the cones' total
    cross-section, a pick about 1 / n (n targets): the rays serve large targets (leaves) better, picks small
    ones (buds, which a cone ray rarely meets).  Targets whose area (one side) is at least ``share`` (default
    :data:`CONE_SHARE`) of Σ_k π r_k² / n are served by rays.  ``area`` (n,), ``clusters`` their
    :class:`~kernel.records.Clusters`."""
    share = CONE_SHARE if share is None else share
    area = np.asarray(area, float)
    if len(area) == 0:
        return np.zeros(0, bool)
    cross = math.pi * float(np.sum(np.asarray(clusters.radius) ** 2)) / len(area)
    return area >= share * cross
