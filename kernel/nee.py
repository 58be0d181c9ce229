"""Next-event tallies: the expected light a small target gets from one photon vertex.

A 10 mm sensor or a bud catches ~1e-5 of the emitted photons, so counting
crossings needs ~1e9 photons for 1%.  Instead, at every vertex where the photon
leaves diffusely (its emission from a lamp, a diffuse reflection or
transmission), we add, for every target, the *expected* weight the next flight
segment deposits on it:

    E[crossing] = ∫_target p(ω(x)) · |cos θ_x| / |x − v|² · V(v, x) dA(x)

estimated with one point x sampled uniformly on the target (area A):
``A · p(ω) · |cos θ_x| / d² · V``, V from one ray: a shadow ray for a sensor, for a
mesh an intersection that must find the mesh itself at x (:func:`reaches`).  p is the pdf of the
direction the photon leaves v in: 1/(4π) for isotropic line lamps, cos/π for
Lambertian emitters, and for a surface ``P_dR,b · cos⁺/π + P_dT,b · cos⁻/π``
(the diffuse events' physical probabilities per band, whatever event the
photon then draws).  Segments after a specular event (mirror, Phong lobe,
straight transmission) are not covered and are counted by their real
crossings, so every segment is counted exactly once in expectation: the
estimator is unbiased.  For organs the expected absorbed weight,
``E[crossing] · P_abs`` of the side hit, is tallied the same way.

Targets are discs and quads (transparent sensors: crossings from the front
only) and meshes (receivers: organs, two-sided, or solid sensors, one-sided),
sampled by triangle area.

Near a target, 1/d² makes the estimate heavy-tailed (infinite variance as the
vertex approaches the target).  Discs avoid it: their point is drawn by solid
angle as seen from v (:func:`disc_point_by_solid_angle`), so a next event is
bounded however near v is.  For quads and meshes, a vertex closer to a target
than :data:`NEAR` times the target's bounding radius makes no next event for
it, and the segment's real crossing of that target is counted instead — a fixed
split of the path space, so still unbiased.

A disc right beside a wall gets much of its light through the few photons
that land on the wall next to it; :func:`near_zones` marks those patches, and
:func:`kernel.trace._zone_event` reaches them from every vertex instead (a
two-step next event), the photons that do land there skipping what it covered.
"""
import math

import numpy as np
from numba import njit

from .embree import ARGS, CAND_COUNT, DIR, GEOM_ID, INVALID_ID, MASK, ORG, PRIM_ID, RAYHIT, TFAR, TNEAR
from .ptr import call_ptr3, load_f32, load_u32, store_f32, store_i64, store_u32
from .rng import uniform
from .sampling import frame, search_cdf

T_DISC, T_QUAD, T_MESH2, T_MESH1 = 0, 1, 2, 3       # target kinds (MESH2: two-sided, MESH1: one-sided)
DIFFUSE_R, DIFFUSE_T, ABSORB = 0, 2, 4
# Embree intersects a triangle in float32 from the ray's origin: on a thin sliver (a leaf fan) the plane it
# finds is off by ~1e-5 of the distance (measured: 0.75-1e-5 · d on a 96-triangle disc), so a shadow ray
# to a point ON a mesh target must stop that much short or it is blocked by the target itself.
END_REL = 2.0 ** -13
NEAR = 3.0       # exclusion radius around a quad or mesh target, in its bounding radii
FAR = 10.0      # discs farther than FAR radii: points drawn by area
NEAR_PICKED = 1.0    # discs nearer than this · radius · √(targets) get their own next event (:func:`near_discs`)
NEAR_FLOOR = 2.0     # ... and always those nearer than this · radius (:func:`near_discs`)
ZONE_HEIGHT = 4.0    # a disc whose centre is nearer to a plane than this · its radius gets a zone on it
INV_4PI = 1.0 / (4.0 * math.pi)

# vertex modes
V_ISOTROPIC, V_LAMBERT, V_SURFACE = 0, 1, 2


@njit(inline="always", cache=True)
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


@njit(inline="always", cache=True)
def visible(occluded_fn, scene, scratch, ox, oy, oz, dx, dy, dz, tfar):
    """Is the segment from o along unit d, up to tfar, free of surfaces?  One ``rtcOccluded1`` call."""
    set_ray(scratch, ox, oy, oz, dx, dy, dz, tfar)
    call_ptr3(occluded_fn, scene, scratch + RAYHIT, scratch + ARGS)
    return load_f32(scratch + RAYHIT + TFAR) >= 0.0


@njit(inline="always", cache=True)
def _competes(j, px, py, pz, dx, dy, dz, cop_box, tri_verts, tri_normal, tri_two_sided):
    """Does triangle j contain p (on its plane) and face the ray (or is it two-sided)?"""
    if not (cop_box[j, 0, 0] <= px <= cop_box[j, 1, 0] and cop_box[j, 0, 1] <= py <= cop_box[j, 1, 1]
            and cop_box[j, 0, 2] <= pz <= cop_box[j, 1, 2]):
        return False
    nx, ny, nz = tri_normal[j, 0], tri_normal[j, 1], tri_normal[j, 2]
    if tri_two_sided[j] == 0 and dx * nx + dy * ny + dz * nz >= 0.0:
        return False
    for i in range(3):
        k = (i + 1) % 3
        ax, ay, az = (tri_verts[j, k, 0] - tri_verts[j, i, 0], tri_verts[j, k, 1] - tri_verts[j, i, 1],
                      tri_verts[j, k, 2] - tri_verts[j, i, 2])
        bx, by, bz = px - tri_verts[j, i, 0], py - tri_verts[j, i, 1], pz - tri_verts[j, i, 2]
        if (ay * bz - az * by) * nx + (az * bx - ax * bz) * ny + (ax * by - ay * bx) * nz < 0.0:
            return False
    return True


@njit(inline="always", cache=True)
def reaches(intersect_fn, scene, scratch, ox, oy, oz, dx, dy, dz, near, far, receiver, geom_offset, tri_receiver,
            px, py, pz, cop_start, cop_list, cop_box, cop_free, tri_verts, tri_normal, tri_two_sided):
    """The share of the light arriving at x = (px, py, pz), a point of a mesh target reached from o along unit
    d, that receiver ``receiver`` gets: 0 unless the first surface met, before ``far``, no nearer than
    ``near``, lies at x; one ``rtcIntersect1`` call (the filters as for photons).  With near and far L ∓
    x's float32 tolerance (L its distance): x is seen, and neither the target itself (a bud's front) nor
    another surface within that tolerance of x (the internode a bud sinks into) is in the way — which a
    shadow ray stopping that tolerance short of x cannot tell.  Where coincident coplanar surfaces cover x
    (``coplanar = "random"``: a photon there picks one of those facing it at random, :func:`kernel.trace._pick_coplanar`),
    the share is the receiver's part of them — what the photon's pick gives it on average (a patch lying
    on the floor: 1/2) — not whichever of them Embree's tie happens to return first."""
    set_ray(scratch, ox, oy, oz, dx, dy, dz, far)
    call_ptr3(intersect_fn, scene, scratch + RAYHIT, scratch + ARGS)
    gid = load_u32(scratch + RAYHIT + GEOM_ID)
    if gid == INVALID_ID or load_f32(scratch + RAYHIT + TFAR) < near:
        return 0.0
    tri = load_u32(scratch + RAYHIT + PRIM_ID) + geom_offset[gid]
    mine = 1 if tri_receiver[tri] == receiver else 0
    if cop_start[tri + 1] == cop_start[tri] or (
            cop_free[tri, 0, 0] < px < cop_free[tri, 1, 0] and cop_free[tri, 0, 1] < py < cop_free[tri, 1, 1]
            and cop_free[tri, 0, 2] < pz < cop_free[tri, 1, 2]):
        return float(mine)                                  # no partner reaches x
    n_in = 1
    for a in range(cop_start[tri], cop_start[tri + 1]):
        j = cop_list[a]
        if _competes(j, px, py, pz, dx, dy, dz, cop_box, tri_verts, tri_normal, tri_two_sided):
            n_in += 1
            if tri_receiver[j] == receiver:
                mine += 1
    return mine / n_in


@njit(inline="always", cache=True)
def seen_share(g, intersect_fn, occluded_fn, scene, scratch, ox, oy, oz, dx, dy, dz, near, far, receiver,
               geom_offset, tri_receiver, px, py, pz, cop_start, cop_list, cop_box, cop_free, tri_verts, tri_normal,
               tri_two_sided):
    """The share of the light at x = (px, py, pz) that a target gets, seen from o along unit d: for a mesh
    target (``g`` >= 0, its triangle) :func:`reaches`; for a sensor 1 if nothing is in the way up to
    ``near`` (its tolerance short of x), else 0."""
    if g >= 0:
        return reaches(intersect_fn, scene, scratch, ox, oy, oz, dx, dy, dz, near, far, receiver, geom_offset,
                       tri_receiver, px, py, pz, cop_start, cop_list, cop_box, cop_free, tri_verts, tri_normal,
                       tri_two_sided)
    return 1.0 if visible(occluded_fn, scene, scratch, ox, oy, oz, dx, dy, dz, near) else 0.0


@njit(inline="always", cache=True)
def _tri_point(a, u1, u2):
    su = math.sqrt(u1)
    b0, b1 = 1.0 - su, u2 * su
    b2 = 1.0 - b0 - b1
    return (b0 * a[0, 0] + b1 * a[1, 0] + b2 * a[2, 0],
            b0 * a[0, 1] + b1 * a[1, 1] + b2 * a[2, 1],
            b0 * a[0, 2] + b1 * a[1, 2] + b2 * a[2, 2])


@njit(inline="always", cache=True)
def mesh_point(t, u1, u2, u3, tgt_first, tgt_count, nee_tri, nee_cdf, tri_verts):
    """A point uniform on mesh target t (by area) from three uniforms: ``(triangle, x, y, z)``; u3 picks the
    triangle from t's cumulative areas ``nee_cdf[tgt_first[t] : tgt_first[t] + tgt_count[t]]``."""
    g = nee_tri[search_cdf(nee_cdf, tgt_first[t], tgt_first[t] + tgt_count[t] - 1, u3)]
    px, py, pz = _tri_point(tri_verts[g], u1, u2)
    return g, px, py, pz


@njit(inline="always", cache=True)
def _tri_area(c, i, j, k):
    ax, ay, az = c[j, 0] - c[i, 0], c[j, 1] - c[i, 1], c[j, 2] - c[i, 2]
    bx, by, bz = c[k, 0] - c[i, 0], c[k, 1] - c[i, 1], c[k, 2] - c[i, 2]
    cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    return 0.5 * math.sqrt(cx * cx + cy * cy + cz * cz)


@njit(inline="always", cache=True)
def sensor_point(kind, s, u1, u2, u3, sens_center, sens_normal, sens_radius, sens_corners):
    """A point uniform on transparent sensor s (a disc, kind T_DISC, or a planar quad) from three uniforms."""
    if kind == T_DISC:
        tb, bb = frame(sens_normal[s, 0], sens_normal[s, 1], sens_normal[s, 2])
        r = sens_radius[s] * math.sqrt(u1)
        c, sn = r * math.cos(2.0 * math.pi * u2), r * math.sin(2.0 * math.pi * u2)
        return (sens_center[s, 0] + c * tb[0] + sn * bb[0], sens_center[s, 1] + c * tb[1] + sn * bb[1],
                sens_center[s, 2] + c * tb[2] + sn * bb[2])
    cq = sens_corners[s]
    a0 = _tri_area(cq, 0, 1, 2)
    a1 = _tri_area(cq, 0, 2, 3)
    su = math.sqrt(u1)
    b0, b1 = 1.0 - su, u2 * su
    b2 = 1.0 - b0 - b1
    k1, k2 = (1, 2) if u3 * (a0 + a1) < a0 else (2, 3)
    return (b0 * cq[0, 0] + b1 * cq[k1, 0] + b2 * cq[k2, 0], b0 * cq[0, 1] + b1 * cq[k1, 1] + b2 * cq[k2, 1],
            b0 * cq[0, 2] + b1 * cq[k1, 2] + b2 * cq[k2, 2])


@njit(inline="always", cache=True)
def disc_point_by_solid_angle(vx, vy, vz, s, u1, u2, sens_center, sens_normal, sens_radius):
    """A point x on disc s drawn as seen from v, and the estimator's factor ``|cos θ_x| / |x − v|² / pdf_A(x)``
    (steradians), whose mean is the disc's solid angle seen from v.

    Polar coordinates (ρ, φ) about v's foot F on the disc's plane, v at height h in front of it: φ uniform
    over the directions in which rays from F meet the disc (all of them when F is on the disc), then along
    that ray the cosine of the angle at v uniform between its values at the disc's near and far edges
    (exact solid-angle sampling along each ray).  The factor is Δφ · (cos_near − cos_far) ≤ 2π: bounded
    however near v is to the disc, where uniform points on the disc give A·h/d³, heavy-tailed as d → 0.
    Returns ``(x, y, z, factor)``; factor 0 when v is not in front of the disc.
    """
    cx, cy, cz = sens_center[s, 0], sens_center[s, 1], sens_center[s, 2]
    mx, my, mz = sens_normal[s, 0], sens_normal[s, 1], sens_normal[s, 2]
    a = sens_radius[s]
    h = (vx - cx) * mx + (vy - cy) * my + (vz - cz) * mz
    if not h > 0.0:
        return cx, cy, cz, 0.0
    tb, bb = frame(mx, my, mz)
    ex, ey, ez = vx - cx, vy - cy, vz - cz                 # F − c in the disc's frame (the normal drops out)
    fx = ex * tb[0] + ey * tb[1] + ez * tb[2]
    fy = ex * bb[0] + ey * bb[1] + ez * bb[2]
    f2 = fx * fx + fy * fy
    if f2 <= a * a:
        dphi = 2.0 * math.pi
        phi = dphi * u1
    else:
        half = math.asin(a / math.sqrt(f2))
        dphi = 2.0 * half
        phi = math.atan2(-fy, -fx) + (2.0 * u1 - 1.0) * half
    ux, uy = math.cos(phi), math.sin(phi)
    b = ux * fx + uy * fy
    root = math.sqrt(max(b * b - (f2 - a * a), 0.0))
    rho1, rho2 = max(-b - root, 0.0), max(-b + root, 0.0)
    # 1 − cos of the angle at v, in a form without cancellation for far vertices: ρ² / (r (r + h))
    r1, r2 = math.sqrt(rho1 * rho1 + h * h), math.sqrt(rho2 * rho2 + h * h)
    d1, d2 = r1 * (r1 + h), r2 * (r2 + h)
    if not d2 > 0.0:             # h and the disc below float64's range: nothing to see
        return cx, cy, cz, 0.0
    g1 = rho1 * rho1 / d1 if d1 > 0.0 else 0.0
    g2 = rho2 * rho2 / d2
    span = g2 - g1
    if not span > 0.0:
        return cx, cy, cz, 0.0
    g = g1 + u2 * span
    c = 1.0 - g
    rho = min(max(h * math.sqrt(g * (1.0 + c)) / c, rho1), rho2) if c > 0.0 else rho2   # h·tan, from 1 − cos
    px, py = fx + rho * ux, fy + rho * uy
    return (cx + px * tb[0] + py * bb[0], cy + px * tb[1] + py * bb[1], cz + px * tb[2] + py * bb[2],
            dphi * span)


@njit(inline="always", cache=True)
def view_factors(mode):
    """(c0, c1): the pdf of leaving a vertex of this mode towards direction ω is c0 + c1 · |cos| (for a
    surface, times the band's diffuse probability on that side)."""
    if mode == V_ISOTROPIC:
        return INV_4PI, 0.0
    return 0.0, 1.0 / math.pi


_ZERO32 = np.float32(0.0)
_ONE32 = np.float32(1.0)
_TINY32 = np.float32(1e-30)


@njit(inline="always", cache=True)
def _gamma32(vx, vy, vz, nx, ny, nz, c0, c1, cx, cy, cz, mx, my, mz, area):
    """γ of a sensor of centre c, unit normal m and area A seen from v (unit normal n), in float32:
    A · cos θ_c / d² · (c0 + c1 |cos θ_v|), or ≤ 0 when v is behind the sensor's plane (all arguments
    float32: the same arithmetic in :func:`point_view` and the vectorised loop of
    :func:`kernel.trace._control_deposits`, so both get the same bits)."""
    ex, ey, ez = cx - vx, cy - vy, cz - vz
    d2 = max(ex * ex + ey * ey + ez * ez, _TINY32)
    hd = -(ex * mx + ey * my + ez * mz)                    # h · d
    inv_d = _ONE32 / math.sqrt(d2)
    cos_v = (ex * nx + ey * ny + ez * nz) * inv_d
    return area * hd * (inv_d * inv_d * inv_d) * (c0 + c1 * math.fabs(cos_v))


@njit(inline="always", cache=True)
def point_view(t, vx, vy, vz, nx, ny, nz, mode, tgt_ref, tgt_area, tgt_center, sens_normal):
    """Sensor target t's next event from v as if t were a point at its centre: ``(γ, cos_v)``.

    γ = A · cos θ_c / d_c² · p(ω_c), without the band factor of a surface vertex (its ``P_dR,b`` for
    cos_v > 0, ``P_dT,b`` below); 0 where v is behind the sensor's plane (so is the true value).  The
    control variate of :func:`next_event`: deposited to every sensor at every vertex
    (:func:`kernel.trace._control_deposits`), and subtracted from each pick, so that a pick only carries
    the difference between the true, occluded value and γ.  Computed in float32 (:func:`_gamma32`) from
    the float32 values of the same arrays as the deposits, so that the two cancel exactly on average."""
    s = tgt_ref[t]
    c0, c1 = view_factors(mode)
    f32 = np.float32
    x32, y32, z32 = f32(vx), f32(vy), f32(vz)
    n32x, n32y, n32z = f32(nx), f32(ny), f32(nz)
    cx, cy, cz = f32(tgt_center[t, 0]), f32(tgt_center[t, 1]), f32(tgt_center[t, 2])
    g = _gamma32(x32, y32, z32, n32x, n32y, n32z, f32(c0), f32(c1), cx, cy, cz, f32(sens_normal[s, 0]),
                 f32(sens_normal[s, 1]), f32(sens_normal[s, 2]), f32(tgt_area[t]))
    if not g > _ZERO32:
        return 0.0, 0.0
    ex, ey, ez = cx - x32, cy - y32, cz - z32
    up = ex * n32x + ey * n32y + ez * n32z > _ZERO32
    if mode == V_LAMBERT and not up:
        return 0.0, -1.0
    return float(g), (1.0 if up else -1.0)


@njit(inline="always", cache=True)
def _zone_of(t, pid, zone_start, zone_i):
    """Has disc target t a zone (:func:`near_zones`) on plane ``pid``?"""
    for z in range(zone_start[t], zone_start[t + 1]):
        if zone_i[z, 1] == pid:
            return True
    return False


@njit(cache=True, _nrt=False)
def next_event(vx, vy, vz, nx, ny, nz, mode, m, stat, w, state, scene, occluded_fn, scratch, offset_rel,
               tgt_kind, tgt_row, tgt_abs_row, tgt_ref, tgt_first, tgt_count, tgt_area, tgt_center, tgt_near2,
               sens_center, sens_normal, sens_radius, sens_corners,
               nee_tri, nee_cdf, tri_verts, tri_normal, tri_mat, mat_prob, contrib, out_k, out_w, counters,
               nee_stats, picks, vscale, vtri, near_start, near_list, near_r2, control, cover_pid, zone_start,
               zone_i, intersect_fn, geom_offset, tri_receiver, cop_start, cop_list, cop_box, cop_free, tri_two_sided):
    """Expected deposits of the segment leaving vertex v on every target; returns how many were written.

    v (scene units) with unit normal n (for Lambertian emission: the emitter's
    normal; for a surface: the side the photon arrived from).  ``mode``:
    V_ISOTROPIC, V_LAMBERT or V_SURFACE (material m).  ``w`` (B,) the photon's
    weights.  Deposits go to ``out_k[i]`` (tally row) and ``out_w[i, :]`` for
    i < the returned count (at most 2 per target).  ``nee_stats[stat]`` counts
    shadow rays cast and found unblocked, and sums the weight they deposit (to switch off vertices that never
    see a target: see :func:`lpy_light.simulate.KernelScene.prune_next_events`).
    ``picks`` > 0: only that many targets, drawn uniformly (with replacement),
    each deposit scaled by n_targets / picks — unbiased, and a vertex then
    costs ``picks`` shadow rays instead of one per target.
    ``vscale``: the vertex's round-off scale (its triangle's and the arriving ray's magnitudes, see
    :func:`kernel.trace.trace_chunk`); shadow rays start and stop that far (× ``offset_rel``) off surfaces.
    ``vtri``: the vertex's triangle (-1 on a lamp).  With picks, a disc target nearer to v than
    √``near_r2[t]`` gets a next event of its own, unscaled, and is skipped by the picks: a random pick
    would deposit n_targets / picks times its large expected value, rarely (see :func:`near_discs`).
    Its candidates are ``near_list[near_start[vtri] : near_start[vtri + 1]]``.
    ``cover_pid`` ≥ 0: v is a vertex on plane ``cover_pid`` reached straight from a next-event vertex, whose
    zone events (:func:`kernel.trace._zone_event`) already served the near discs that have a zone on this
    plane (``zone_i[zone_start[t] : zone_start[t + 1], 1]``): their own events are skipped here.
    A point on a mesh target is seen when the first surface met on the way is the target's, at x
    (:func:`reaches`: ``intersect_fn``, ``geom_offset``, ``tri_receiver`` are the scene's intersection query
    and triangle numbering); a sensor's, when nothing is in the way (``occluded_fn``).
    """
    n_bands = w.shape[0]
    vmag = max(abs(vx), abs(vy), abs(vz), vscale)
    n_out = 0
    n_tgt = tgt_kind.shape[0]
    if picks > 0 and picks < n_tgt:
        n_iter, scale = picks, n_tgt / picks
    else:
        n_iter, scale = n_tgt, 1.0
    n_near = near_start[vtri + 1] - near_start[vtri] if scale != 1.0 and vtri >= 0 else 0
    for j in range(n_near + n_iter):
        if j < n_near:            # a near disc: its own next event
            t = near_list[near_start[vtri] + j]
            tscale = 1.0
        else:
            t = j - n_near if scale == 1.0 else min(int(uniform(state) * n_tgt), n_tgt - 1)
            tscale = scale
        ex, ey, ez = vx - tgt_center[t, 0], vy - tgt_center[t, 1], vz - tgt_center[t, 2]
        d2c = ex * ex + ey * ey + ez * ez
        if n_near > 0 and (d2c < near_r2[t]) != (j < n_near):
            continue          # a near disc is served by its own event only; a listed one that is not near, by picks
        if j < n_near and cover_pid >= 0 and _zone_of(t, cover_pid, zone_start, zone_i):
            continue          # served by the zone events of the vertex this photon came from
        kind = tgt_kind[t]
        u1, u2, u3 = uniform(state), uniform(state), uniform(state)
        if d2c < tgt_near2[t]:
            continue          # too close: 1/d² would be heavy-tailed; this segment's crossings are counted
        # (out_k, out_w hold at most 3 per iteration: size them 3 * (picks + n_targets))
        if (control and scale != 1.0 and j >= n_near and kind <= T_QUAD     # a pick (not a near disc's own event),
                and not (kind == T_DISC and d2c < (NEAR_FLOOR * sens_radius[tgt_ref[t]]) ** 2)):   # γ a fair guess
            gam, cg = point_view(t, vx, vy, vz, nx, ny, nz, mode, tgt_ref, tgt_area, tgt_center, sens_normal)
            if gam > 0.0:
                out_k[n_out] = tgt_row[t]
                for b in range(n_bands):
                    f = 1.0 if mode != V_SURFACE else mat_prob[m, DIFFUSE_R if cg > 0.0 else DIFFUSE_T, b]
                    out_w[n_out, b] = -w[b] * gam * f * tscale
                n_out += 1
        g = -1
        omega = 0.0
        if kind == T_DISC:
            s = tgt_ref[t]
            mx, my, mz = sens_normal[s, 0], sens_normal[s, 1], sens_normal[s, 2]
            if d2c > (FAR * sens_radius[s]) ** 2:    # far: uniform on the disc, A |cos θ_x| / d² nearly constant
                if (vx - sens_center[s, 0]) * mx + (vy - sens_center[s, 1]) * my + (vz - sens_center[s, 2]) * mz <= 0.0:
                    continue
                px, py, pz = sensor_point(kind, s, u1, u2, u3, sens_center, sens_normal, sens_radius, sens_corners)
                kind = T_QUAD      # from here on: a point drawn by area
            else:
                px, py, pz, omega = disc_point_by_solid_angle(vx, vy, vz, s, u1, u2, sens_center, sens_normal,
                                                              sens_radius)
                if omega == 0.0:
                    continue     # behind the sensor's plane: cannot cross it from the front
        elif kind == T_QUAD:
            s = tgt_ref[t]
            mx, my, mz = sens_normal[s, 0], sens_normal[s, 1], sens_normal[s, 2]
            if (vx - sens_center[s, 0]) * mx + (vy - sens_center[s, 1]) * my + (vz - sens_center[s, 2]) * mz <= 0.0:
                continue
            px, py, pz = sensor_point(kind, s, u1, u2, u3, sens_center, sens_normal, sens_radius, sens_corners)
        else:
            g, px, py, pz = mesh_point(t, u1, u2, u3, tgt_first, tgt_count, nee_tri, nee_cdf, tri_verts)
            mx, my, mz = tri_normal[g, 0], tri_normal[g, 1], tri_normal[g, 2]
        dx, dy, dz = px - vx, py - vy, pz - vz
        dist2 = dx * dx + dy * dy + dz * dz
        if not dist2 > 0.0:
            continue
        dist = math.sqrt(dist2)
        dx, dy, dz = dx / dist, dy / dist, dz / dist
        cos_x = dx * mx + dy * my + dz * mz
        if kind != T_MESH2 and cos_x >= 0.0:
            continue          # sensors and one-sided receivers are met from the front only
        geom = tscale * (omega if kind == T_DISC else tgt_area[t] * abs(cos_x) / dist2)
        cos_v = dx * nx + dy * ny + dz * nz
        if mode == V_ISOTROPIC:
            for b in range(n_bands):
                contrib[b] = w[b] * INV_4PI * geom
            side = 0.0
        elif mode == V_LAMBERT:
            if cos_v <= 0.0:
                continue
            for b in range(n_bands):
                contrib[b] = w[b] * cos_v / math.pi * geom
            side = 1.0
        else:
            ev = DIFFUSE_R if cos_v > 0.0 else DIFFUSE_T
            any_light = False
            for b in range(n_bands):
                contrib[b] = w[b] * mat_prob[m, ev, b] * abs(cos_v) / math.pi * geom
                any_light = any_light or contrib[b] > 0.0
            if not any_light:
                continue
            side = 1.0 if cos_v > 0.0 else -1.0
        pmag = max(abs(px), abs(py), abs(pz))
        if g >= 0:      # a mesh target is a surface: its triangle's round-off
            for i in range(3):
                for k in range(3):
                    pmag = max(pmag, abs(tri_verts[g, i, k]))
        eps = offset_rel * (vmag + pmag)
        tol = 2.0 * eps
        if g >= 0:      # a mesh target's plane has a float32 error seen from v (END_REL · d)
            tol += END_REL * dist
        if dist - tol <= 0.0:
            continue
        counters[4] += 1
        nee_stats[stat, 0] += 1
        ox, oy, oz = vx + side * eps * nx, vy + side * eps * ny, vz + side * eps * nz
        share = seen_share(g, intersect_fn, occluded_fn, scene, scratch, ox, oy, oz, dx, dy, dz, dist - tol,
                           dist + tol, tgt_ref[t], geom_offset, tri_receiver, px, py, pz, cop_start, cop_list, cop_box,
                           cop_free, tri_verts, tri_normal, tri_two_sided)
        if share == 0.0:
            continue
        for b in range(n_bands):
            contrib[b] *= share
        nee_stats[stat, 1] += 1
        out_k[n_out] = tgt_row[t]
        for b in range(n_bands):
            out_w[n_out, b] = contrib[b]
            nee_stats[stat, 2] += contrib[b]
        n_out += 1
        if tgt_abs_row[t] >= 0:
            mm = tri_mat[g, 0] if cos_x < 0.0 else tri_mat[g, 1]
            out_k[n_out] = tgt_abs_row[t]
            for b in range(n_bands):
                out_w[n_out, b] = contrib[b] * mat_prob[mm, ABSORB, b]
            n_out += 1
    return n_out


def build_targets(n_sensors, sens_kind, sens_area, sens_center, sens_bound, n_receivers_rows, tri_receiver, tri_verts,
                  tri_two_sided, receiver_row0, absorbed_row0, sensors=True, receivers=True, receiver_mask=None):
    """Target arrays for :func:`next_event` (see there); numpy, outside the hot loop.

    ``tri_receiver`` (T,) receiver index per kernel triangle or -1;
    ``tri_two_sided`` (T,) bool.  Receiver r's incident row is
    ``receiver_row0 + r`` and absorbed row ``absorbed_row0 + r``.
    ``sens_bound`` (S,) a sensor's bounding radius about its centre.
    ``receiver_mask`` (R,) bool or None: only these receivers are targets (the
    others are still tallied, by counting).

    Returns the target arrays (kind .. nee_cdf as :func:`next_event` takes them, then the exclusion radii
    of next events through mirrors and the near-disc lists of :func:`near_discs`), then
    ``sensor_target`` (S,) and ``receiver_target`` (R,): each one's target index or -1.
    """
    kind, row, abs_row, ref, first, count, area, center, near2 = [], [], [], [], [], [], [], [], []
    img_near2 = []
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
    if receivers and n_receivers_rows:
        tri_area = 0.5 * np.linalg.norm(np.cross(tri_verts[:, 1] - tri_verts[:, 0], tri_verts[:, 2] - tri_verts[:, 0]),
                                        axis=1)
        order = np.argsort(tri_receiver, kind="stable")
        recv_sorted = tri_receiver[order]
        for r in range(n_receivers_rows):
            lo, hi = np.searchsorted(recv_sorted, r), np.searchsorted(recv_sorted, r, side="right")
            if receiver_mask is not None and not receiver_mask[r]:
                continue
            tris = order[lo:hi]
            a = tri_area[tris]
            total = a.sum()
            if len(tris) == 0 or not total > 0:
                continue
            kind.append(T_MESH2 if tri_two_sided[tris].all() else T_MESH1)
            row.append(receiver_row0 + r)
            abs_row.append(absorbed_row0 + r)
            ref.append(r)
            first.append(len(nee_tri))
            count.append(len(tris))
            area.append(float(total))
            cdf = np.cumsum(a) / total
            cdf[-1] = 1.0 + 1e-12
            nee_tri.extend(tris.tolist())
            nee_cdf.extend(cdf.tolist())
            pts = tri_verts[tris].reshape(-1, 3)
            lo_, hi_ = pts.min(axis=0), pts.max(axis=0)
            center.append((lo_ + hi_) / 2)
            near2.append(float((NEAR * np.linalg.norm(hi_ - lo_) / 2) ** 2))
            img_near2.append(near2[-1])
            receiver_target[r] = len(kind) - 1
    i64 = lambda x: np.ascontiguousarray(x, dtype=np.int64)
    f64 = lambda x: np.ascontiguousarray(x, dtype=np.float64)
    center = f64(np.reshape(center, (-1, 3)))
    disc_radius = np.zeros(len(kind))
    for s in range(n_sensors):
        if sensor_target[s] >= 0 and sens_kind[s] == 0:
            disc_radius[sensor_target[s]] = sens_bound[s]
    near_start, near_list, near_r2 = near_discs(tri_verts, center, disc_radius)
    return ((np.ascontiguousarray(kind, dtype=np.int32), i64(row), i64(abs_row), i64(ref), i64(first), i64(count),
             f64(area), center, f64(near2), i64(nee_tri if nee_tri else np.zeros(0)),
             f64(nee_cdf if nee_cdf else np.zeros(0)), f64(img_near2), near_start, near_list, near_r2),
            sensor_target, receiver_target)


def near_discs(tri_verts, center, disc_radius, factor=NEAR_PICKED):
    """Which disc targets are *near* a vertex, for :func:`next_event`'s own events, and on which triangles.

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
    near_r2 = np.ascontiguousarray(radius ** 2, dtype=np.float64)
    lo, hi = tri_verts.min(axis=1), tri_verts.max(axis=1)
    pairs_tri, pairs_t = [], []
    for t in np.flatnonzero(near_r2 > 0):
        gap = np.clip(center[t], lo, hi) - center[t]
        tris = np.flatnonzero(np.einsum("ij,ij->i", gap, gap) < near_r2[t])
        pairs_tri.append(tris)
        pairs_t.append(np.full(len(tris), t))
    tris = np.concatenate(pairs_tri) if pairs_tri else np.zeros(0, np.int64)
    ts = np.concatenate(pairs_t) if pairs_t else np.zeros(0, np.int64)
    order = np.argsort(tris, kind="stable")
    near_start = np.zeros(len(tri_verts) + 1, np.int64)
    np.cumsum(np.bincount(tris, minlength=len(tri_verts)), out=near_start[1:])
    return near_start, np.ascontiguousarray(ts[order], dtype=np.int64), near_r2


def near_zones(tri_verts, tri_pid, n_chamber, near_start, near_list, near_r2, center, disc_radius, normal):
    """The zones of surface beside each disc target that a two-step next event serves (:func:`kernel.trace._zone_event`).

    A disc beside a wall gets much of its light from the few centimetres of wall next to it, i.e. from
    the rare photon vertices that land there, each making a large own next event: most of such a disc's
    variance.  Zone (t, P) is the part of plane P (chamber triangles with id P in ``tri_pid``) inside
    disc t's near sphere |y − c_t|² < ``near_r2[t]`` -- where a vertex makes an own next event for t --
    for planes that the disc's centre is within :data:`ZONE_HEIGHT` disc radii of, and that reach in front
    of the disc (an own event's variance grows as 1 / h² with the disc's height h over the plane; farther
    planes' vertices are many for what they bring, and are left to the own events).
    From every next-event vertex a point y of a random zone is drawn (density ∝ 1 / (r² + h²) about the
    foot c' of the disc's centre on P, r ≤ ρ = √(near_r2 − h²), h = the centre's height over P, at least
    the disc's radius), so that the light arriving there, and its own next event, are estimated from
    every vertex instead of the few that land there; a real vertex in the zone reached straight from a
    next-event vertex then skips that own event (:func:`next_event`, ``cover_pid``).

    ``tri_verts`` (T, 3, 3); ``tri_pid`` (T,) plane ids (:func:`lpy_light.geometry.plane_ids`); only the
    first ``n_chamber`` triangles (the chamber, not organs) make zones; ``near_*`` from :func:`near_discs`;
    ``center`` (n, 3), ``disc_radius`` (n,) (0: not a disc) and unit ``normal`` (n, 3) of the targets.
    Returns ``zone_f`` (Z, 14) float64 (c' (3), unit plane normal (3), e1 (3), e2 (3), h_s², L =
    ln(1 + ρ²/h_s²)), ``zone_i`` (Z, 2) int64 (target, plane id), ``zone_start`` (n + 1,) int64 (zones of
    target t: ``zone_start[t] : zone_start[t + 1]``, sorted by target).
    """
    rows_f, rows_i = [], []
    n = len(center)
    n_chamber = min(n_chamber, len(near_start) - 1)
    count = np.diff(near_start[:n_chamber + 1])
    tri_of = np.repeat(np.arange(n_chamber), count)           # (pair,) triangle; near_list gives the disc
    disc_of = near_list[:near_start[n_chamber]]
    pairs = {}                                                 # (disc, plane) -> one of its triangles
    for k, t in zip(tri_of.tolist(), disc_of.tolist()):
        if tri_pid[k] >= 0 and near_r2[t] > 0.0 and disc_radius[t] > 0.0:
            pairs.setdefault((t, int(tri_pid[k])), k)
    for (t, pid), k in sorted(pairs.items()):
        v = tri_verts[k]
        m = np.cross(v[1] - v[0], v[2] - v[0])
        m = m / np.linalg.norm(m)
        h = float(np.dot(center[t] - v[0], m))
        rho2 = near_r2[t] - h * h
        if not (rho2 > 0.0 and abs(h) < ZONE_HEIGHT * disc_radius[t]):
            continue
        foot = center[t] - h * m
        lean = normal[t] - np.dot(normal[t], m) * m           # the disc's normal along the plane
        if np.dot(foot - center[t], normal[t]) + math.sqrt(rho2) * np.linalg.norm(lean) <= 0.0:
            continue                                           # the zone is all behind the disc
        e1 = np.cross(m, [1.0, 0.0, 0.0] if abs(m[0]) < 0.9 else [0.0, 1.0, 0.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(m, e1)
        hs2 = max(h * h, disc_radius[t] ** 2)
        rows_f.append(np.concatenate([foot, m, e1, e2, [hs2, math.log1p(rho2 / hs2)]]))
        rows_i.append([t, pid])
    zone_f = np.ascontiguousarray(np.reshape(rows_f, (-1, 14)), dtype=np.float64)
    zone_i = np.ascontiguousarray(np.reshape(rows_i, (-1, 2)), dtype=np.int64)
    zone_start = np.zeros(n + 1, np.int64)
    if len(zone_i):
        np.cumsum(np.bincount(zone_i[:, 0], minlength=n), out=zone_start[1:])
    return zone_f, zone_i, zone_start
