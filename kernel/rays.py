"""Ray queries: what a ray from a point meets first, through Embree's ``rtcIntersect1`` / ``rtcOccluded1``.

Rays are written into one thread's scratch block (:func:`kernel.embree.new_scratch`) as float32, as Embree
wants them; hit points are recomputed in float64 on the kernel's own triangles.  Where coincident coplanar
surfaces cover a point (``coplanar = "random"``), what a photon meets there is one of those facing it,
chosen uniformly at random (:func:`pick_coplanar`), not whichever Embree's float32 tie returns.  Lengths
in scene units; directions unit vectors.
"""

from .embree import ARGS, CAND_COUNT, DIR, GEOM_ID, HIT_U, HIT_V, INVALID_ID, MASK, ORG, PRIM_ID, RAYHIT, TFAR, TNEAR
from .jit import helper
from .ptr import call_ptr3, load_f32, load_u32, store_f32, store_i64, store_u32
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
def visible(geo, scratch, ox, oy, oz, dx, dy, dz, tfar):
    """Is the segment from o along unit d, up to tfar, free of surfaces?  One ``rtcOccluded1`` call."""
    set_ray(scratch, ox, oy, oz, dx, dy, dz, tfar)
    call_ptr3(geo.occluded, geo.scene, scratch + RAYHIT, scratch + ARGS)
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
    """One of ``tri`` and its coplanar partners that contain p and face the ray, uniformly at random
    (reservoir sampling: one random number per competing partner, none where there is none)."""
    if partner_free(tri, px, py, pz, geo):
        return tri                                  # where no partner reaches
    chosen = tri
    n_in = 1
    for a in range(geo.cop_start[tri], geo.cop_start[tri + 1]):
        j = geo.cop_list[a]
        if competes(j, px, py, pz, dx, dy, dz, geo):
            n_in += 1
            if uniform(state) * n_in < 1.0:
                chosen = j
    return chosen


@helper
def first_hit(geo, scratch, ox, oy, oz, dx, dy, dz, tfar, state):
    """The first surface a ray from o (already off its surface) along unit d meets within ``tfar``:
    ``(triangle, x, y, z)``, triangle -1 where none; the point from Embree's barycentric coordinates on the
    triangle's own vertices (float64), coincident surfaces picked as a photon picks among them."""
    rh = scratch + RAYHIT
    set_ray(scratch, ox, oy, oz, dx, dy, dz, tfar)
    call_ptr3(geo.intersect, geo.scene, rh, scratch + ARGS)
    gid = load_u32(rh + GEOM_ID)
    if gid == INVALID_ID:
        return -1, ox, oy, oz
    k = load_u32(rh + PRIM_ID) + geo.geom_offset[gid]
    bu, bv = load_f32(rh + HIT_U), load_f32(rh + HIT_V)
    a = geo.verts[k]
    b0 = 1.0 - bu - bv
    px = b0 * a[0, 0] + bu * a[1, 0] + bv * a[2, 0]
    py = b0 * a[0, 1] + bu * a[1, 1] + bv * a[2, 1]
    pz = b0 * a[0, 2] + bu * a[1, 2] + bv * a[2, 2]
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
    call_ptr3(geo.intersect, geo.scene, rh, scratch + ARGS)
    gid = load_u32(rh + GEOM_ID)
    if gid == INVALID_ID:
        return -1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0
    cop_start, verts = geo.cop_start, geo.verts
    tri = load_u32(rh + PRIM_ID) + geo.geom_offset[gid]
    if plane_of[tri] != plane and cop_start[tri + 1] == cop_start[tri]:
        return -1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0
    bu, bv = load_f32(rh + HIT_U), load_f32(rh + HIT_V)
    b0 = 1.0 - bu - bv
    hx = b0 * verts[tri, 0, 0] + bu * verts[tri, 1, 0] + bv * verts[tri, 2, 0]
    hy = b0 * verts[tri, 0, 1] + bu * verts[tri, 1, 1] + bv * verts[tri, 2, 1]
    hz = b0 * verts[tri, 0, 2] + bu * verts[tri, 1, 2] + bv * verts[tri, 2, 2]
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
    call_ptr3(geo.intersect, geo.scene, scratch + RAYHIT, scratch + ARGS)
    gid = load_u32(scratch + RAYHIT + GEOM_ID)
    if gid == INVALID_ID or load_f32(scratch + RAYHIT + TFAR) < near:
        return 0.0
    tri = load_u32(scratch + RAYHIT + PRIM_ID) + geo.geom_offset[gid]
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
