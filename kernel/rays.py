"""Ray queries: what a ray from a point meets first, through Embree's ``rtcIntersect1`` / ``rtcOccluded1``.

Rays are written into one thread's scratch block (:func:`kernel.embree.new_scratch`) as float32, as Embree
wants them.  Embree answers *which* triangle a ray meets; *where* is computed here, in float64, on the kernel's
own triangle (:func:`hit_point`): Embree's own distance and barycentrics divide through an approximate
reciprocal (``rcpps`` and a Newton step) whose last bits differ between Intel and AMD processors and between
Embree's code paths, so numbers built on them would differ from machine to machine.  Where coincident coplanar
surfaces cover a point (``coplanar = "random"``), what a photon meets there is one of those facing it,
chosen uniformly at random by rank in index order (:func:`pick_coplanar`), not whichever Embree's float32
tie returns.  Lengths in scene units; directions unit vectors.
"""
import math

from .embree import (ARGS, CAND_COUNT, DIR, GEOM_ID, HIT_U, HIT_V, INVALID_ID, LOG, LOG_CAP, LOG_COUNT, MASK, ORG,
                     PRIM_ID, RAYHIT, TFAR, TNEAR)
from .jit import helper
from .ptr import call_ptr3, load_f32, load_i64, load_u32, load_u64, store_f32, store_i64, store_u32
from .raylog import RAY_SHADOW, RAY_TARGET
from .rng import uniform


@helper
def set_ray(scratch, ox, oy, oz, dx, dy, dz, tfar):
    """Write a ray (origin, unit direction, [0, tfar]) into this thread's RTCRayHit: all masks, ray id and
    flags 0, no hit yet, no sensor candidates yet."""
    rh = scratch + RAYHIT
    store_f32(rh + ORG, ox)
    store_f32(rh + ORG + 4, oy)
    store_f32(rh + ORG + 8, oz)
    store_f32(rh + TNEAR, 0.0)
    store_f32(rh + DIR, dx)
    store_f32(rh + DIR + 4, dy)
    store_f32(rh + DIR + 8, dz)
    store_f32(rh + DIR + 12, 0.0)
    store_f32(rh + TFAR, tfar)
    store_u32(rh + MASK, 0xFFFFFFFF)
    store_u32(rh + MASK + 4, 0)
    store_u32(rh + MASK + 8, 0)
    store_u32(rh + GEOM_ID, INVALID_ID)
    store_i64(scratch + CAND_COUNT, 0)


@helper
def _log_ray(scratch, log, kind):
    """Append the ray in the scratch block to the ray log at address ``log`` (:mod:`kernel.raylog`)."""
    counter = load_u64(scratch + LOG_COUNT)
    n = load_i64(counter)
    store_i64(counter, n + 1)
    if n < load_i64(scratch + LOG_CAP):
        row, rh = log + 32 * n, scratch + RAYHIT
        for j in range(3):
            store_f32(row + 4 * j, load_f32(rh + ORG + 4 * j))
            store_f32(row + 12 + 4 * j, load_f32(rh + DIR + 4 * j))
        store_f32(row + 24, load_f32(rh + TFAR))
        store_f32(row + 28, float(kind))


@helper
def cast(fn, scene, scratch, kind):
    """Cast the ray set in the scratch block: ``fn`` is ``rtcIntersect1`` or ``rtcOccluded1``'s address, ``kind``
    what the ray is for (:data:`kernel.raylog.KINDS`, logged where a ray log is open)."""
    log = load_u64(scratch + LOG)
    if log != 0:
        _log_ray(scratch, log, kind)
    call_ptr3(fn, scene, scratch + RAYHIT, scratch + ARGS)


@helper
def visible(geo, scratch, ox, oy, oz, dx, dy, dz, tfar):
    """Is the segment from o along unit d, up to tfar, free of surfaces?  One ``rtcOccluded1`` call."""
    set_ray(scratch, ox, oy, oz, dx, dy, dz, tfar)
    cast(geo.occluded, geo.scene, scratch, RAY_SHADOW)
    return load_f32(scratch + RAYHIT + TFAR) >= 0.0


@helper
def magnitude(v):
    """Largest |coordinate| of the three vertices v (3, 3): the scale of a triangle's float32 round-off."""
    m = 0.0
    for i in range(3):
        for j in range(3):
            m = max(m, abs(v[i, j]))
    return m


@helper
def hit_point(geo, scratch, k):
    """Where the ray in the scratch block (the float32 origin and direction Embree traced) meets the plane of
    triangle ``k`` (global index), in float64 on the kernel's own vertices: ``(t, x, y, z)``.  Möller-Trumbore's
    barycentrics, clamped onto the triangle (Embree found the hit inside it; float64 may put it a rounding
    outside); the point is their combination of the vertices, so it lies on the triangle's plane to float64
    precision even on sliver triangles, where o + t·d with a float32 t would not.  Plain IEEE arithmetic:
    the same bits on every x86-64 processor.  A ray parallel to the plane (a degenerate hit) falls back on
    Embree's own answer."""
    rh = scratch + RAYHIT
    ox, oy, oz = float(load_f32(rh + ORG)), float(load_f32(rh + ORG + 4)), float(load_f32(rh + ORG + 8))
    dx, dy, dz = float(load_f32(rh + DIR)), float(load_f32(rh + DIR + 4)), float(load_f32(rh + DIR + 8))
    a = geo.verts[k]
    e1x, e1y, e1z = a[1, 0] - a[0, 0], a[1, 1] - a[0, 1], a[1, 2] - a[0, 2]
    e2x, e2y, e2z = a[2, 0] - a[0, 0], a[2, 1] - a[0, 1], a[2, 2] - a[0, 2]
    px, py, pz = dy * e2z - dz * e2y, dz * e2x - dx * e2z, dx * e2y - dy * e2x
    det = e1x * px + e1y * py + e1z * pz
    if det != 0.0 and math.isfinite(det):
        inv = 1.0 / det
        sx, sy, sz = ox - a[0, 0], oy - a[0, 1], oz - a[0, 2]
        bu = (sx * px + sy * py + sz * pz) * inv
        qx, qy, qz = sy * e1z - sz * e1y, sz * e1x - sx * e1z, sx * e1y - sy * e1x
        bv = (dx * qx + dy * qy + dz * qz) * inv
        t = (e2x * qx + e2y * qy + e2z * qz) * inv
        bu = max(bu, 0.0)
        bv = max(bv, 0.0)
        if bu + bv > 1.0:
            s = bu + bv
            bu, bv = bu / s, bv / s
    else:
        bu, bv, t = float(load_f32(rh + HIT_U)), float(load_f32(rh + HIT_V)), float(load_f32(rh + TFAR))
    b0 = 1.0 - bu - bv
    return (t, b0 * a[0, 0] + bu * a[1, 0] + bv * a[2, 0], b0 * a[0, 1] + bu * a[1, 1] + bv * a[2, 1],
            b0 * a[0, 2] + bu * a[1, 2] + bv * a[2, 2])


@helper
def competes(j, px, py, pz, dx, dy, dz, geo):
    """Does triangle j contain p (on its plane) and face the ray (or is it two-sided)?"""
    box, verts = geo.cop_box, geo.verts
    if not (box[j, 0, 0] <= px <= box[j, 1, 0] and box[j, 0, 1] <= py <= box[j, 1, 1]
            and box[j, 0, 2] <= pz <= box[j, 1, 2]):
        return False
    nx, ny, nz = geo.normal[j, 0], geo.normal[j, 1], geo.normal[j, 2]
    if geo.two_sided[j] == 0 and dx * nx + dy * ny + dz * nz >= 0.0:
        return False
    for i in range(3):
        k = (i + 1) % 3
        ax, ay, az = (verts[j, k, 0] - verts[j, i, 0], verts[j, k, 1] - verts[j, i, 1],
                      verts[j, k, 2] - verts[j, i, 2])
        bx, by, bz = px - verts[j, i, 0], py - verts[j, i, 1], pz - verts[j, i, 2]
        if (ay * bz - az * by) * nx + (az * bx - ax * bz) * ny + (ax * by - ay * bx) * nz < 0.0:
            return False
    return True


@helper
def partner_free(tri, px, py, pz, geo):
    """Is p inside the box of triangle ``tri`` that none of its coplanar partners reaches?"""
    free = geo.cop_free
    return (free[tri, 0, 0] < px < free[tri, 1, 0] and free[tri, 0, 1] < py < free[tri, 1, 1]
            and free[tri, 0, 2] < pz < free[tri, 1, 2])


@helper
def pick_coplanar(tri, px, py, pz, dx, dy, dz, geo, state):
    """One of ``tri`` and its coplanar partners that contain p and face the ray, uniformly at random: one random
    number where there are several, none where there is one; the one picked is the r-th in index order, so the
    pick does not depend on which of them Embree's float32 tie returned."""
    if partner_free(tri, px, py, pz, geo):
        return tri                                  # where no partner reaches
    start, end = geo.cop_start[tri], geo.cop_start[tri + 1]
    n_in = 1
    for a in range(start, end):
        if competes(geo.cop_list[a], px, py, pz, dx, dy, dz, geo):
            n_in += 1
    if n_in == 1:
        return tri
    r = min(int(uniform(state) * n_in), n_in - 1)
    for a in range(start - 1, end):                 # a == start - 1 stands for tri itself
        m = tri if a < start else geo.cop_list[a]
        if m != tri and not competes(m, px, py, pz, dx, dy, dz, geo):
            continue
        rank = 1 if tri < m else 0
        for b in range(start, end):
            j = geo.cop_list[b]
            if j < m and competes(j, px, py, pz, dx, dy, dz, geo):
                rank += 1
        if rank == r:
            return m
    return tri


@helper
def first_hit(geo, scratch, ox, oy, oz, dx, dy, dz, tfar, state):
    """The first surface a ray from o (already off its surface) along unit d meets within ``tfar``:
    ``(triangle, x, y, z)``, triangle -1 where none; the point on the triangle's own vertices (float64,
    :func:`hit_point`), coincident surfaces picked as a photon picks among them."""
    rh = scratch + RAYHIT
    set_ray(scratch, ox, oy, oz, dx, dy, dz, tfar)
    cast(geo.intersect, geo.scene, scratch, RAY_TARGET)
    gid = load_u32(rh + GEOM_ID)
    if gid == INVALID_ID:
        return -1, ox, oy, oz
    k = load_u32(rh + PRIM_ID) + geo.geom_offset[gid]
    _, px, py, pz = hit_point(geo, scratch, k)
    if geo.cop_start[k + 1] > geo.cop_start[k]:   # coincident surfaces: as a photon picks among them
        k = pick_coplanar(k, px, py, pz, dx, dy, dz, geo, state)
    return k, px, py, pz


@helper
def hit_on_plane(geo, scratch, plane_of, plane, dx, dy, dz, state):
    """Trace the ray already set in the scratch block (direction d); if what a photon would meet first (a
    coplanar tie picked at random, as at a photon's hit) lies on plane ``plane`` of ``plane_of`` (T,), return
    (triangle, hit point, its normal turned towards the ray's origin, the material of that side);
    triangle -1 otherwise."""
    rh = scratch + RAYHIT
    cast(geo.intersect, geo.scene, scratch, RAY_TARGET)
    gid = load_u32(rh + GEOM_ID)
    if gid == INVALID_ID:
        return -1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0
    cop_start = geo.cop_start
    tri = load_u32(rh + PRIM_ID) + geo.geom_offset[gid]
    if plane_of[tri] != plane and cop_start[tri + 1] == cop_start[tri]:
        return -1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0
    _, hx, hy, hz = hit_point(geo, scratch, tri)
    if cop_start[tri + 1] > cop_start[tri]:
        tri = pick_coplanar(tri, hx, hy, hz, dx, dy, dz, geo, state)
    if plane_of[tri] != plane:
        return -1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0    # something else first
    tnx, tny, tnz = geo.normal[tri, 0], geo.normal[tri, 1], geo.normal[tri, 2]
    if dx * tnx + dy * tny + dz * tnz > 0.0:
        return tri, hx, hy, hz, -tnx, -tny, -tnz, geo.material[tri, 1]
    return tri, hx, hy, hz, tnx, tny, tnz, geo.material[tri, 0]


@helper
def reaches(geo, scratch, origin, direction, near, far, receiver, point):
    """The share of the light arriving at x = ``point``, a point of a mesh target reached from ``origin`` along
    the unit ``direction``, that receiver ``receiver`` gets: 0 unless the first surface met, before ``far``, no
    nearer than ``near``, lies at x; one ``rtcIntersect1`` call (the filters as for photons).  With near and
    far L ∓ x's float32 tolerance (L its distance): x is seen, and neither the target itself (a bud's front)
    nor another surface within that tolerance of x (the internode a bud sinks into) is in the way — which a
    shadow ray stopping that tolerance short of x cannot tell.  Where coincident coplanar surfaces cover x
    (``coplanar = "random"``: a photon there picks one of those facing it at random, :func:`pick_coplanar`),
    the share is the receiver's part of them — what the photon's pick gives it on average (a patch lying
    on the floor: 1/2) — not whichever of them Embree's tie happens to return first."""
    ox, oy, oz = origin
    dx, dy, dz = direction
    px, py, pz = point
    set_ray(scratch, ox, oy, oz, dx, dy, dz, far)
    cast(geo.intersect, geo.scene, scratch, RAY_TARGET)
    gid = load_u32(scratch + RAYHIT + GEOM_ID)
    if gid == INVALID_ID:
        return 0.0
    tri = load_u32(scratch + RAYHIT + PRIM_ID) + geo.geom_offset[gid]
    if hit_point(geo, scratch, tri)[0] < near:
        return 0.0
    mine = 1 if geo.receiver[tri] == receiver else 0
    if geo.cop_start[tri + 1] == geo.cop_start[tri] or partner_free(tri, px, py, pz, geo):
        return float(mine)                                  # no partner reaches x
    n_in = 1
    for a in range(geo.cop_start[tri], geo.cop_start[tri + 1]):
        j = geo.cop_list[a]
        if competes(j, px, py, pz, dx, dy, dz, geo):
            n_in += 1
            if geo.receiver[j] == receiver:
                mine += 1
    return mine / n_in


@helper
def seen_share(g, geo, scratch, origin, direction, near, far, receiver, point):
    """The share of the light at x = ``point`` that a target gets, seen from ``origin`` along the unit
    ``direction``: for a mesh target (``g`` >= 0, its triangle) :func:`reaches`; for a sensor 1 if nothing is
    in the way up to ``near`` (its tolerance short of x), else 0."""
    if g >= 0:
        return reaches(geo, scratch, origin, direction, near, far, receiver, point)
    ox, oy, oz = origin
    dx, dy, dz = direction
    return 1.0 if visible(geo, scratch, ox, oy, oz, dx, dy, dz, near) else 0.0
