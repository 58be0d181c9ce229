"""Organ zone events: two-step next events through the organ surface beside an organ target.

A bud sits in the leaf axil against the stem; much of its far red is scattered to it by the stem and leaf
base within a centimetre (green tissue reflects and transmits ~0.5 there, ~0.05 in the red), i.e. by the
few photon vertices that land there, each making a large own next event (:func:`kernel.nee.next_event`).
On the rose of ``lsystems/rose.lpy`` those own events carried ~40 % of a bud's far red and ~90 % of its
variance.  The zone of an organ target t is the organ surface within its near radius (the triangles of the
other organs where a vertex makes an own event for t, :func:`organ_zones`); from every next-event vertex v
a point y of a random zone is drawn and the light that the segment leaving v would bring to t through y
estimated (:func:`organ_zone_event`): the photon vertices that land there are replaced by an estimate from
every vertex.  An open organ (rose-simple4's buds: ``F() Sphere()``, a tube open at both ends) has its own
surface in its zone too: light that enters it bounces inside.  From y, a walk follows the short legs a photon
would make inside the zone, an own event at each landing (:func:`zone_walk`).  A photon that does land on a
zone straight from a next-event vertex, or walks on there by short legs, skips those own events
(:func:`kernel.nee.zone_served`): every path is counted once, unbiased.

Deposits in photons of weight, lengths in scene units, solid angles in steradians.
"""
import math

import numpy as np
from numba import njit

from .importance import cluster_cdf, draw
from .jit import helper
from .nee import NEAR, near_listed, point_by_solid_angle, target_event, tri_point, view_factors

ZONE_BY_CONE = 0.5    # the share of zone points found by a ray from the vertex into the target's near sphere,
ZONE_BY_BUD = 0.25    # ... for an open target (own surface in its zone), into its own bounding sphere (its inside)
ZONE_BY_AREA = 0.2    # the rest drawn on the zone's surface: this share uniformly by area, the others by solid
                      # angle seen from the target's centre
ZONE_WALK = 50        # short legs a zone event's vertex walks on inside the zone at most (zone_walk): a photon in
                      # an open bud's tube bounces 20 times and more there (rose-simple4, far red)
from .embree import GEOM_ID, INVALID_ID, PRIM_ID, RAYHIT
from .ptr import load_u32
from .raylog import RAY_TARGET
from .rays import cast, first_hit, magnitude, set_ray
from .records import DIFFUSE_R, DIFFUSE_T, T_MESH2, V_ISOTROPIC, V_LAMBERT, V_SURFACE, OrganZones, Vertex
from .targets import cluster_sums
from .rng import uniform
from .sampling import cosine_hemisphere, search_cdf, uniform_cone
from .tallies import C_SHADOW


def organ_zones(tri_verts, tri_receiver, tri_pid, near_start, near_list, near_r2, kind, ref, center, clusters,
                own):
    """The zone of each organ target: the triangles of *other* organs within its near radius (where a vertex
    makes an own next event for it, :func:`kernel.targets.near_discs`), and its own where ``own`` (n,) bool (an
    open organ, e.g. the tube that rose-simple4's ``F() Sphere()`` draws for a bud, lights its own inside), with
    what :func:`organ_zone_event` draws points by: their areas and the solid angles they subtend from the
    target's centre.

    ``tri_verts`` (T, 3, 3), ``tri_receiver`` (T,), ``tri_pid`` (T,) plane ids: the organs' triangles are those
    of a receiver without a plane (-1); ``near_*`` the targets' near lists and radii²; ``kind``, ``ref``,
    ``center`` (n,) from :class:`~kernel.records.Targets`, and their ``clusters`` (:class:`~kernel.records.Clusters`).
    Returns :class:`~kernel.records.OrganZones` (``picks`` 0: the caller's to set)."""
    T = len(tri_verts)
    tri_of = np.repeat(np.arange(T), np.diff(near_start))
    t_of = np.asarray(near_list[:near_start[-1]], np.int64)
    keep = ((tri_pid[tri_of] < 0) & (tri_receiver[tri_of] >= 0) & (np.asarray(kind)[t_of] >= T_MESH2)
            & (np.asarray(near_r2)[t_of] > 0)
            & ((tri_receiver[tri_of] != np.asarray(ref)[t_of]) | np.asarray(own, bool)[t_of]))
    tri_of, t_of = tri_of[keep], t_of[keep]
    order = np.lexsort((tri_of, t_of))
    tri_of, t_of = tri_of[order], t_of[order]
    area, angle = zone_measures(np.ascontiguousarray(tri_verts, np.float64), np.ascontiguousarray(tri_of, np.int64),
                                np.ascontiguousarray(center, np.float64), np.ascontiguousarray(t_of, np.int64))
    targets, first = np.unique(t_of, return_index=True)
    start = np.append(first, len(t_of)).astype(np.int64)
    cdf_area, cdf_angle = np.zeros(len(t_of)), np.zeros(len(t_of))
    total = np.zeros((len(targets), 2))
    for z in range(len(targets)):
        for x, cdf, col in ((area, cdf_area, 0), (angle, cdf_angle, 1)):
            xz = x[start[z]:start[z + 1]]
            total[z, col] = xz.sum()
            c = np.cumsum(xz) / xz.sum() if xz.sum() > 0 else np.linspace(1, len(xz), len(xz)) / len(xz)
            c[-1] = 1.0 + 1e-12
            cdf[start[z]:start[z + 1]] = c
    zone_of = np.full(len(kind), -1, np.int64)
    zone_of[targets] = np.arange(len(targets))
    weight = (zone_of >= 0).astype(np.float64)
    cluster_weight = cluster_sums(weight, clusters)
    return OrganZones(0.0, np.ascontiguousarray(targets, np.int64), start, np.ascontiguousarray(tri_of, np.int64),
                      cdf_area, cdf_angle, total, zone_of, weight, np.ascontiguousarray(cluster_weight, np.float64),
                      np.ascontiguousarray(own, np.uint8), 0)


def solid_angles(v):
    """Solid angles (sr) of triangles ``v`` (k, 3, 3) seen from the origin (Van Oosterom & Strackee 1983)."""
    v = np.ascontiguousarray(v, np.float64)
    k = len(v)
    return zone_measures(v, np.arange(k, dtype=np.int64), np.zeros((1, 3)), np.zeros(k, np.int64))[1]


@njit(cache=True)
def zone_measures(tri_verts, tri_of, center, t_of):
    """For each pair i: the area (scene units²) of triangle ``tri_of[i]`` of ``tri_verts`` (T, 3, 3) and the
    solid angle (sr) it subtends from ``center[t_of[i]]`` ((n, 3); Van Oosterom & Strackee 1983): two (k,)
    arrays.  One compiled pass: a canopy's zones hold millions of pairs (16 roses: 5.1e6), which numpy's
    (k, 3, 3) temporaries took 3.9 s and ~1 GB for, against ~0.15 s here."""
    k = tri_of.shape[0]
    area, angle = np.empty(k), np.empty(k)
    for i in range(k):
        j, t = tri_of[i], t_of[i]
        p0x, p0y, p0z = tri_verts[j, 0, 0], tri_verts[j, 0, 1], tri_verts[j, 0, 2]
        p1x, p1y, p1z = tri_verts[j, 1, 0], tri_verts[j, 1, 1], tri_verts[j, 1, 2]
        p2x, p2y, p2z = tri_verts[j, 2, 0], tri_verts[j, 2, 1], tri_verts[j, 2, 2]
        ex, ey, ez = p1x - p0x, p1y - p0y, p1z - p0z
        fx, fy, fz = p2x - p0x, p2y - p0y, p2z - p0z
        nx, ny, nz = ey * fz - ez * fy, ez * fx - ex * fz, ex * fy - ey * fx
        area[i] = 0.5 * math.sqrt(nx * nx + ny * ny + nz * nz)
        ax, ay, az = p0x - center[t, 0], p0y - center[t, 1], p0z - center[t, 2]     # the corners seen from the centre
        bx, by, bz = p1x - center[t, 0], p1y - center[t, 1], p1z - center[t, 2]
        cx, cy, cz = p2x - center[t, 0], p2y - center[t, 1], p2z - center[t, 2]
        la = math.sqrt(ax * ax + ay * ay + az * az)
        lb = math.sqrt(bx * bx + by * by + bz * bz)
        lc = math.sqrt(cx * cx + cy * cy + cz * cz)
        num = abs(ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz) + az * (bx * cy - by * cx))
        den = (la * lb * lc + (ax * bx + ay * by + az * bz) * lc + (ax * cx + ay * cy + az * cz) * lb
               + (bx * cx + by * cy + bz * cz) * la)
        angle[i] = 2.0 * math.atan2(num, den)
    return area, angle


@helper
def organ_zone_event(v, n_draw, left, stat, geo, mat, sens, tgt, organs, photon, stats):
    """Two-step next events: the light that the segment leaving vertex ``v`` (:class:`~kernel.records.Vertex`)
    brings to an organ target t *through one diffuse vertex y on the organ surface beside it*
    (:func:`organ_zones`).

    For ``n_draw`` draws (mean ``oz.picks``): a zone z of target t, drawn with probability p_z ∝ 1 / max(d², R²)
    (:mod:`kernel.importance`), then y on it in one of three ways: with probability α = :data:`ZONE_BY_CONE`,
    the first surface met by a ray from v in a direction uniform in the cone of t's near sphere (solid angle
    Ω_c); for an open t (``oz.own``), with probability β = :data:`ZONE_BY_BUD`, the same in the cone of t's own
    bounding sphere (Ω_b: its inside, through its openings); else its triangle k with probability P_k
    (``oz.cdf``) and y uniform on it, p_A(y) = P_k / A_k (with the probability 1 − α − β of this way), and the
    ray v → y must first meet triangle k.  y must be on t's zone (within its near radius), at least that far from v, and
    the side facing v a material with next events; then from y one own next event to t
    (:func:`kernel.nee.target_event`) for a photon of weights

        w2_b = w_b · f_v,b(ω_vy) / (p(ω_vy) · p_z · picks),   p(ω) = α / Ω_c + β / Ω_b [ω in t's cone] + p_A(y) · |y − v|² / |cos θ_y|,

    the density of the three ways together in the solid angle seen from v (f_v as in
    :func:`kernel.nee.next_event`): the expected own next event that a photon leaving v diffusely would make at
    y, which a photon that does land there then skips.  The cone finds what v sees of the zone (an open bud's
    inside, through its opening), which points drawn on the zone's surface rarely do (each then a large
    deposit); those points serve the zone surface a cone ray rarely meets.  From y on, a walk on the short legs
    inside the zone makes the own events of the landings that follow (:func:`zone_walk`; ``left``: the k-th
    surface met after v may make next events if k < left).  Returns the new number of deposits in
    ``photon.out_k`` / ``photon.out_w``.
    """
    vx, vy, vz = v.x, v.y, v.z
    oz = organs.zones
    state = photon.state
    n_zone = oz.target.shape[0]
    if n_zone == 0 or n_draw <= 0 or not oz.picks > 0.0:
        return 0
    n_out = 0
    # zones drawn ∝ 1 / max(d², R²) (R the zone's radius): about the solid angle of the zone seen from v
    vpos = (vx, vy, vz)
    how = (oz.weight, oz.cluster_weight, tgt.near_r2, 1.0, False, oz.weight)
    total = cluster_cdf(vpos, how, organs.clusters, tgt, photon.cdf, photon.exact)
    if not total > 0.0:
        return 0
    for _ in range(n_draw):
        t, p_z = draw(uniform(state), uniform(state), total, vpos, how, organs.clusters, tgt, photon.cdf, photon.exact)
        if t < 0:
            continue
        n_out = zone_event_to(v, (t, p_z, oz.picks), left, stat, geo, mat, sens, tgt, organs, photon, stats, n_out)
    return n_out


@helper
def zone_event_to(v, pick, left, stat, geo, mat, sens, tgt, organs, photon, stats, n_out):
    """One draw of :func:`organ_zone_event` for the zone of target t, ``pick`` = (t, p_z, picks): the light that the
    segment leaving ``v`` brings to t through one point y of t's zone, divided by p_z · picks (the probability
    the caller drew t with, its draws' mean); from y, the walk.  Deposits from ``photon.out_k[n_out]`` /
    ``photon.out_w[n_out]`` on; returns the new count."""
    vx, vy, vz, nx, ny, nz, mode, m, vscale, _vtri = v
    t, p_z, picks = pick
    oz = organs.zones
    w, w2 = photon.w, photon.w2
    state, scratch = photon.state, photon.scratch
    n_bands = w.shape[0]
    c0, c1 = view_factors(mode)
    vmag = max(abs(vx), abs(vy), abs(vz), vscale)
    rh = scratch + RAYHIT
    z = oz.zone_of[t]
    near_r2 = tgt.near_r2[t]
    u0, u1, u2, u3 = uniform(state), uniform(state), uniform(state), uniform(state)
    cx, cy, cz = tgt.center[t, 0], tgt.center[t, 1], tgt.center[t, 2]
    ax, ay, az = cx - vx, cy - vy, cz - vz            # the cone of t's near sphere seen from v
    dc2 = ax * ax + ay * ay + az * az
    dc = math.sqrt(dc2)
    omc = 1.0 - math.sqrt(1.0 - near_r2 / dc2) if dc2 > near_r2 else 2.0    # 1 − cos of its half angle
    by_bud = ZONE_BY_BUD if oz.own[t] != 0 else 0.0
    rb2 = tgt.img_near2[t] / (NEAR * NEAR)           # t's bounding sphere (radius², about its centre)
    omc_b = 1.0 - math.sqrt(1.0 - rb2 / dc2) if dc2 > rb2 else 2.0
    by_ray = u0 < by_bud + ZONE_BY_CONE
    if by_ray:                # the first surface met in a direction from v uniform in a cone
        dx, dy, dz = uniform_cone(ax / dc, ay / dc, az / dc, omc_b if u0 < by_bud else omc, u1, u2)
        cos_v = dx * nx + dy * ny + dz * nz
        side = 0.0 if mode == V_ISOTROPIC else (1.0 if cos_v > 0.0 else -1.0)
        eps = geo.offset_rel * vmag
        stats.counters[C_SHADOW] += 1
        k, yx, yy, yz = first_hit(geo, scratch, vx + side * eps * nx, vy + side * eps * ny,
                                  vz + side * eps * nz, dx, dy, dz, dc + math.sqrt(near_r2) + 4.0 * eps, state)
        if k < 0:
            return n_out
        a = geo.verts[k]
        rec = geo.receiver[k]
        if (rec < 0 or geo.plane_id[k] >= 0 or (rec == tgt.ref[t] and oz.own[t] == 0)
                or not near_listed(t, k, tgt)):
            return n_out                                   # not a triangle of t's zone
    else:                     # a point drawn on the zone's surface
        by_angle = u3 >= ZONE_BY_AREA and oz.total[z, 1] > 0.0
        u4 = uniform(state)
        i = search_cdf(oz.cdf_angle if by_angle else oz.cdf_area, oz.start[z], oz.start[z + 1] - 1, u4)
        k = oz.tri[i]
        a = geo.verts[k]
        if by_angle:          # in a direction from the target's centre uniform in the triangle's solid angle
            yx, yy, yz, om = point_by_solid_angle(cx, cy, cz, a, geo.normal[k, 0], geo.normal[k, 1],
                                                  geo.normal[k, 2], u1, u2)
            if om == 0.0:
                return n_out
        else:                 # uniform on the triangle
            yx, yy, yz = tri_point(a, u1, u2)
    kx, ky, kz = geo.normal[k, 0], geo.normal[k, 1], geo.normal[k, 2]
    ex, ey, ez = yx - cx, yy - cy, yz - cz
    d2c = ex * ex + ey * ey + ez * ez
    if not (d2c < near_r2 and d2c > 0.0):
        return n_out                                   # outside the zone (a photon there makes a pick instead)
    dx, dy, dz = yx - vx, yy - vy, yz - vz
    dist2 = dx * dx + dy * dy + dz * dz
    if not dist2 >= near_r2:
        return n_out                                   # a short leg: left to the own events and walks
    dist = math.sqrt(dist2)
    dx, dy, dz = dx / dist, dy / dist, dz / dist
    cos_v = dx * nx + dy * ny + dz * nz
    if mode == V_LAMBERT and cos_v <= 0.0:
        return n_out
    cos_in = dx * kx + dy * ky + dz * kz
    if cos_in > 0.0:                               # met from its back: the back's material, normal towards v
        m_y = geo.material[k, 1]
        kx, ky, kz = -kx, -ky, -kz
    else:
        m_y = geo.material[k, 0]
        cos_in = -cos_in
    if tgt.from_material[m_y] == 0 or not cos_in > 0.0:
        return n_out                                   # no next events from y's material: its crossings count
    ymag = magnitude(a)
    if not by_ray:
        side = 0.0 if mode == V_ISOTROPIC else (1.0 if cos_v > 0.0 else -1.0)
        eps = geo.offset_rel * (vmag + ymag)
        # the first leg: what a photon leaving v towards y meets first (past y by a little: Embree's float32)
        set_ray(scratch, vx + side * eps * nx, vy + side * eps * ny, vz + side * eps * nz, dx, dy, dz,
                dist * (1.0 + 2.0 ** -10) + 4.0 * eps)
        stats.counters[C_SHADOW] += 1
        cast(geo.intersect, geo.scene, scratch, RAY_TARGET)
        gid = load_u32(rh + GEOM_ID)
        if gid == INVALID_ID or load_u32(rh + PRIM_ID) + geo.geom_offset[gid] != k:
            return n_out                               # something else first: no such vertex y
    # the density of y, in the solid angle seen from v, of both ways of drawing it
    cos_c = abs(ex * geo.normal[k, 0] + ey * geo.normal[k, 1] + ez * geo.normal[k, 2]) / math.sqrt(d2c)
    by_surface = 1.0 - by_bud - ZONE_BY_CONE
    if oz.total[z, 1] > 0.0:      # by area or by solid angle from the centre (per unit area of the zone)
        p_a = by_surface * (ZONE_BY_AREA / oz.total[z, 0] + (1.0 - ZONE_BY_AREA) * cos_c / (d2c * oz.total[z, 1]))
    else:
        p_a = by_surface / oz.total[z, 0]
    p_w = ZONE_BY_CONE / (2.0 * math.pi * omc) + p_a * dist2 / cos_in
    if by_bud > 0.0 and 1.0 - (dx * ax + dy * ay + dz * az) / dc <= omc_b:    # within t's own cone too
        p_w += by_bud / (2.0 * math.pi * omc_b)
    arrive = 1.0 / (p_w * p_z * picks)
    any_light = False
    for b in range(n_bands):
        fv = c0 + c1 * abs(cos_v)
        if mode == V_SURFACE:
            fv *= mat.prob[m, 0 if cos_v > 0.0 else 2, b]
        w2[b] = w[b] * fv * arrive
        any_light = any_light or w2[b] > 0.0
    if not any_light:
        return n_out
    u5, u6, u7 = uniform(state), uniform(state), uniform(state)
    y = Vertex(yx, yy, yz, kx, ky, kz, V_SURFACE, np.int64(m_y), ymag + vmag, k)
    n_out = target_event(y, (t, d2c, 1.0), w2, (u5, u6, u7), stat, geo, mat, sens, tgt, photon, stats, n_out)
    n_out = zone_walk(y, t, min(oz.walk, left - 2), stat, geo, mat, sens, tgt, oz, photon, stats, n_out)
    return n_out


@helper
def zone_walk(y, t, n_legs, stat, geo, mat, sens, tgt, oz, photon, stats, n_out):
    """The short legs after a zone event's vertex ``y`` (:class:`~kernel.records.Vertex` on organ t's zone, reached
    by a photon of weights ``photon.w2``): where a photon leaving y diffusely lands on t's zone again, within t's
    near radius of y, the own next event it would make there for t (:func:`kernel.nee.target_event`), and so on
    from that landing, ``n_legs`` legs at most.  The far red a bud gets from the leaf tissue around it after
    several bounces there: inside an open bud (rose-simple4's tube) or a wedge between a leaf and the bud (R + T ≈ 1
    in the far red) a photon bounces many times, each time making a large own event -- rare photons, each
    carrying much of the bud's far red.

    Each leg: the side s (reflected, or transmitted) drawn with probability q_s ∝ Σ_b w_b P_s,b(m), a direction
    cosine-distributed on it, and the first surface met within √``tgt.near_r2[t]``; it must be organ surface within
    t's near radius (t in its triangle's near list) of a material with next events; on t itself, unless t's own
    surface is in its zone (``oz.own``, :func:`organ_zones`), the walk goes on without an own event there.
    The weights become w_b · P_s,b / q_s (``photon.w2``, in place).  A photon that does land there after such
    legs skips those own events (:func:`kernel.nee.zone_served`): every path counted once.  Returns the new
    number of deposits."""
    yx, yy, yz, kx, ky, kz, _mode, m, yscale, _k = y
    w2, state, scratch = photon.w2, photon.state, photon.scratch
    n_bands = w2.shape[0]
    near_r2 = tgt.near_r2[t]
    for _ in range(n_legs):
        sr = st = 0.0
        for b in range(n_bands):
            sr += w2[b] * mat.prob[m, DIFFUSE_R, b]
            st += w2[b] * mat.prob[m, DIFFUSE_T, b]
        if not sr + st > 0.0:
            return n_out
        u0, u1, u2 = uniform(state), uniform(state), uniform(state)
        if u0 * (sr + st) < sr:       # reflected: back to the side y was reached from (the normal faces it)
            ev, q, side = DIFFUSE_R, sr / (sr + st), 1.0
        else:
            ev, q, side = DIFFUSE_T, st / (sr + st), -1.0
        dx, dy, dz = cosine_hemisphere(side * kx, side * ky, side * kz, u1, u2)
        eps = geo.offset_rel * max(abs(yx), abs(yy), abs(yz), yscale)
        stats.counters[C_SHADOW] += 1
        k2, px, py, pz = first_hit(geo, scratch, yx + side * eps * kx, yy + side * eps * ky, yz + side * eps * kz,
                                   dx, dy, dz, math.sqrt(near_r2), state)
        if k2 < 0:
            return n_out
        a = geo.verts[k2]
        rec = geo.receiver[k2]
        if rec < 0 or geo.plane_id[k2] >= 0:
            return n_out                                 # not organ surface
        own = rec == tgt.ref[t] and oz.own[t] == 0      # t itself, not in its zone: the walk goes on, no own event
        lx, ly, lz = px - yx, py - yy, pz - yz
        if not lx * lx + ly * ly + lz * lz < near_r2:
            return n_out                                 # a long leg: the photon's own zone events serve it
        ex, ey, ez = px - tgt.center[t, 0], py - tgt.center[t, 1], pz - tgt.center[t, 2]
        d2c = ex * ex + ey * ey + ez * ez
        if not (d2c < near_r2 and d2c >= tgt.near2[t] and near_listed(t, k2, tgt)):
            return n_out                                 # no own event for t there
        mx, my, mz = geo.normal[k2, 0], geo.normal[k2, 1], geo.normal[k2, 2]
        if dx * mx + dy * my + dz * mz > 0.0:            # met from its back: the back's material, normal towards y
            m2 = geo.material[k2, 1]
            mx, my, mz = -mx, -my, -mz
        else:
            m2 = geo.material[k2, 0]
        if tgt.from_material[m2] == 0:
            return n_out
        for b in range(n_bands):
            w2[b] *= mat.prob[m, ev, b] / q
        yscale = magnitude(a)
        if not own:
            u3, u4, u5 = uniform(state), uniform(state), uniform(state)
            y2 = Vertex(px, py, pz, mx, my, mz, V_SURFACE, np.int64(m2), yscale, k2)
            n_out = target_event(y2, (t, d2c, 1.0), w2, (u3, u4, u5), stat, geo, mat, sens, tgt, photon, stats, n_out)
        yx, yy, yz, kx, ky, kz, m = px, py, pz, mx, my, mz, np.int64(m2)
    return n_out
