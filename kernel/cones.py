"""Next events to far clusters of organs: rays aimed into the cones that hold them, the first organ met tallied.

A pick (:mod:`kernel.importance`) aims a shadow ray at one point of one target.  From a vertex far from a
canopy -- the Makrolon ceiling, a wall, the table -- thousands of organs look alike: a pick is one target in n,
its deposit n / picks times the target's share, and, with the organs hiding one another, most picks meet
another organ first (a shadow ray for nothing).  A leaf's variance then grows as n (issue 28: 16 roses cost
130x one rose's, where counting photons costs 3.5x).

Here the targets of each cluster (:func:`kernel.targets.target_clusters`) that v is outside of are served
instead by rays drawn in the cone of directions that meets the cluster's bounding sphere: a cluster k is drawn
in proportion to ``c_k = Ω_k · f_k`` (Ω_k its cone's solid angle, f_k a bound of the leaving pdf's cosine
factor over the cone: about the share of v's light that goes that way), a direction uniformly within its
cone, and the ray tallies what the first surface it meets receives if that surface is a target organ of a
far cluster.  The direction's density is the mixture over all far clusters whose cones hold it,

    pdf(ω) = Σ_k [ω ∈ cone_k] · (c_k / C) / Ω_k,        C = Σ_k c_k,

and the deposit is the photon's weight times the leaving pdf p(ω) over (rays · pdf(ω)): unbiased, each
deposit at most about C / rays of the photon's weight, however many organs there are and whichever one hides
which.  Which targets which estimator serves is fixed by v alone (a split of the path space, as in
:func:`kernel.nee.next_event`): a target with an own event at v (within its near radius) by that event; one
of a cluster v is within :data:`~kernel.importance.CLUSTER_NEAR` radii of by picks; the others by these rays.

Lengths in scene units, solid angles in steradians, deposits in photons of weight.
"""
import math

from .importance import CLUSTER_NEAR
from .jit import helper
from .nee import INV_4PI, deposit, view_factors
from .ptr import call_ptr3, load_f32, load_u32
from .rays import pick_coplanar, set_ray
from .records import DIFFUSE_R, DIFFUSE_T, T_MESH2, V_ISOTROPIC, V_LAMBERT, V_SURFACE  # noqa: F401
from .embree import ARGS, GEOM_ID, HIT_U, HIT_V, INVALID_ID, PRIM_ID, RAYHIT
from .rng import n_draws, uniform
from .sampling import search_cdf, uniform_cone
from .tallies import C_SHADOW

_TFAR_MAX = 3.0e38


@helper
def cone_of(k, vx, vy, vz, cl):
    """Cluster k's cone seen from v: ``(d, ax, ay, az, sin θ, 1 − cos θ)``, a its unit axis (towards the centre,
    at distance d), θ its half angle; ``1 − cos θ`` is 0 when v is within :data:`CLUSTER_NEAR` radii of the
    cluster (served by picks, not by rays)."""
    ex, ey, ez = cl.center[k, 0] - vx, cl.center[k, 1] - vy, cl.center[k, 2] - vz
    d2 = ex * ex + ey * ey + ez * ez
    r = cl.radius[k]
    if d2 < (CLUSTER_NEAR * r) ** 2 or not d2 > 0.0:
        return 0.0, 0.0, 0.0, 1.0, 0.0, 0.0
    d = math.sqrt(d2)
    s = min(r / d, 1.0)
    return d, ex / d, ey / d, ez / d, s, s * s / (1.0 + math.sqrt(1.0 - s * s))


#: the cones' share of a vertex's light C from which it gets the full number of rays; below, √(C / C_FULL) of it
#: (rays go where they reduce the variance most: a vertex whose cones hold little of its light deposits little
#: through them.  Rose, 1.15e6 photons, leaves' p90 σ² × CPU: 20.1 with 2 rays at every vertex, 23.2 ∝ C,
#: 14.3 ∝ √C with 4 rays at C ≥ 0.25)
C_FULL = 0.25


@helper
def ray_mean(cones, total):
    """The mean number of cone rays at a vertex whose cones hold ``total`` = C of its light (see :data:`C_FULL`),
    ``cones`` the setting (:attr:`lpy_light.simulate.KernelScene.nee_cones`, :func:`lpy_light.simulate.cones_for`)."""
    return cones * min(1.0, math.sqrt(total / C_FULL))


#: per cluster, after its cumulative weight: the cone's axis (3), 1 − cos θ and c_k / Ω_k (:func:`cone_cdf`)
CONE_DATA = 5


@helper
def cone_cdf(v, side, cl, cdf, at):
    """Cumulative weights ``c_k`` of the K clusters' cones seen from vertex v into ``cdf[at : at + K]``, and each
    cone's axis, ``1 − cos θ`` (0: a near cluster) and ``c_k / Ω_k`` into ``cdf[at + K + 5k : at + K + 5k + 5]``;
    returns the sum C of the weights.  ``side`` = (front, back): how much of the leaving light goes to each side
    of a surface (its bands' largest diffuse reflectance and transmittance; (1, 0) for a Lambertian emitter,
    (1, 1) isotropic)."""
    vx, vy, vz, nx, ny, nz, mode, m, vscale, vtri = v
    c0, c1 = view_factors(mode)
    front, back = side
    n_k = cl.radius.shape[0]
    total = 0.0
    for k in range(n_k):
        d, ax, ay, az, s, omc = cone_of(k, vx, vy, vz, cl)
        c = 0.0
        if omc > 0.0:
            cosc = ax * nx + ay * ny + az * nz
            f = front if cosc - s > 0.0 else (back if cosc + s < 0.0 else max(front, back))
            c = 2.0 * math.pi * omc * f * (c0 + c1 * min(1.0, abs(cosc) + s))
        total += c
        cdf[at + k] = total
        i = at + n_k + CONE_DATA * k
        cdf[i], cdf[i + 1], cdf[i + 2], cdf[i + 3] = ax, ay, az, omc
        cdf[i + 4] = c / (2.0 * math.pi * omc) if c > 0.0 else 0.0
    return total


@helper
def cone_pdf(dx, dy, dz, total, n_k, cdf, at):
    """The density (1/sr) of direction d among :func:`cone_cdf`'s cones (summing to ``total``): Σ over the cones
    holding d of (c_k / C) / Ω_k."""
    pdf = 0.0
    for k in range(n_k):
        i = at + n_k + CONE_DATA * k
        if cdf[i + 4] > 0.0 and 1.0 - (dx * cdf[i] + dy * cdf[i + 1] + dz * cdf[i + 2]) <= cdf[i + 3]:
            pdf += cdf[i + 4]
    return pdf / total


@helper
def cone_direction(u0, u1, u2, total, n_k, cdf, at):
    """A direction drawn from :func:`cone_cdf`'s cones (weights in ``cdf[at:]``, summing to ``total``) from three
    uniforms: a cone in proportion to its weight, then a direction uniform within it.  Its density is
    :func:`cone_pdf`."""
    k = search_cdf(cdf, at, at + n_k - 1, u0 * total) - at
    i = at + n_k + CONE_DATA * k
    return uniform_cone(cdf[i], cdf[i + 1], cdf[i + 2], cdf[i + 3], u1, u2)


@helper
def first_target(origin, d, near, near_r2, geo, tgt, organs, photon, n_k, at):
    """Trace a cone ray from ``origin`` (already off its surface) along unit ``d``: ``(t, triangle, cos θ_x)`` of
    the first surface met if it is a target organ that cone rays serve from the point the cones were drawn
    from (``cdf[at:]``, :func:`cone_cdf`), else t = -1.  ``near`` = (point, test): with test, a target whose
    centre is within √``near_r2[t]`` of the point is served otherwise (an own event, or a counted crossing)."""
    scratch, cdf, state = photon.scratch, photon.cdf, photon.state
    rh = scratch + RAYHIT
    set_ray(scratch, origin[0], origin[1], origin[2], d[0], d[1], d[2], _TFAR_MAX)
    call_ptr3(geo.intersect, geo.scene, rh, scratch + ARGS)
    gid = load_u32(rh + GEOM_ID)
    if gid == INVALID_ID:
        return -1, -1, 0.0
    tri = load_u32(rh + PRIM_ID) + geo.geom_offset[gid]
    rec = geo.receiver[tri]
    if rec < 0 or tgt.receiver_target[rec] < 0:
        return -1, -1, 0.0                        # the chamber, or an organ that is no target
    bu, bv = load_f32(rh + HIT_U), load_f32(rh + HIT_V)
    b0 = 1.0 - bu - bv
    verts = geo.verts
    hx = b0 * verts[tri, 0, 0] + bu * verts[tri, 1, 0] + bv * verts[tri, 2, 0]
    hy = b0 * verts[tri, 0, 1] + bu * verts[tri, 1, 1] + bv * verts[tri, 2, 1]
    hz = b0 * verts[tri, 0, 2] + bu * verts[tri, 1, 2] + bv * verts[tri, 2, 2]
    if geo.cop_start[tri + 1] > geo.cop_start[tri]:   # coincident surfaces: as a photon picks among them
        tri = pick_coplanar(tri, hx, hy, hz, d[0], d[1], d[2], geo, state)
        rec = geo.receiver[tri]
        if rec < 0 or tgt.receiver_target[rec] < 0:
            return -1, -1, 0.0
    t = tgt.receiver_target[rec]
    px, py, pz, test = near
    ex, ey, ez = px - tgt.center[t, 0], py - tgt.center[t, 1], pz - tgt.center[t, 2]
    if test and ex * ex + ey * ey + ez * ez < near_r2[t]:
        return -1, -1, 0.0                        # served by its own event there (or counted)
    if organs.far_weight[t] > 0.0:
        return -1, -1, 0.0                        # a small target: served by picks from every cluster
    if cdf[at + n_k + CONE_DATA * organs.cluster_of[t] + 3] == 0.0:
        return -1, -1, 0.0                        # its cluster is near: served by picks
    cos_x = d[0] * geo.normal[tri, 0] + d[1] * geo.normal[tri, 1] + d[2] * geo.normal[tri, 2]
    if tgt.kind[t] != T_MESH2 and cos_x >= 0.0:
        return -1, -1, 0.0                        # a one-sided receiver, met from behind
    return t, tri, cos_x


@helper
def leaving_sides(v, mat):
    """How much of the light leaving vertex v goes to each side: ``(front, back)``, its material's largest
    diffuse reflectance and transmittance over the bands ((1, 0) for a Lambertian emitter, (1, 1) isotropic)."""
    mode, m = v[6], v[7]
    if mode == V_SURFACE:
        front, back = 0.0, 0.0
        for b in range(mat.prob.shape[2]):
            front = max(front, mat.prob[m, DIFFUSE_R, b])
            back = max(back, mat.prob[m, DIFFUSE_T, b])
        return front, back
    if mode == V_LAMBERT:
        return 1.0, 0.0
    return 1.0, 1.0


@helper
def leaving(cos_v, mode, front, back):
    """The density (1/sr) with which a photon leaves a vertex of ``mode`` at cosine ``cos_v`` to its normal, its
    scattering probability aside (:func:`leaving_sides`' ``front``, ``back``: 0 where none leaves that side), and
    the side it leaves: ``(p, ±1)``; p = 0 where no photon leaves that way."""
    if mode == V_ISOTROPIC:
        return INV_4PI, 1.0
    if mode == V_LAMBERT:
        return (cos_v / math.pi if cos_v > 0.0 else 0.0), 1.0
    side = 1.0 if cos_v > 0.0 else -1.0
    return (abs(cos_v) / math.pi if (front if side > 0.0 else back) > 0.0 else 0.0), side


@helper
def cone_events(v, stat, geo, mat, tgt, organs, photon, stats, n_out):
    """Rays from vertex ``v`` (:class:`~kernel.records.Vertex`) into the cones of the far clusters of organ
    targets (see above): a random whole number of them, of mean μ = :func:`ray_mean` (C); the deposits of those
    that first meet a target organ served by them, divided by μ, go to ``photon.out_k`` / ``photon.out_w`` from
    ``n_out`` on.  Returns the new count."""
    vx, vy, vz, nx, ny, nz, mode, m, vscale, vtri = v
    cl = organs.clusters
    n_k = cl.radius.shape[0]
    cdf, state, contrib, w = photon.cdf, photon.state, photon.contrib, photon.w
    counters, nee_stats = stats.counters, stats.nee_stats
    n_bands = w.shape[0]
    at = tgt.kind.shape[0] + n_k            # after the picks' importances (kernel.importance.cluster_cdf)
    front, back = leaving_sides(v, mat)
    total = cone_cdf(v, (front, back), cl, cdf, at)
    if not total > 0.0:
        return n_out
    mean = ray_mean(organs.cones, total)
    n_rays = n_draws(mean, state)
    vmag = max(abs(vx), abs(vy), abs(vz), vscale)
    n_near = tgt.near_start[vtri + 1] - tgt.near_start[vtri] if vtri >= 0 else 0
    for _ in range(n_rays):
        dx, dy, dz = cone_direction(uniform(state), uniform(state), uniform(state), total, n_k, cdf, at)
        p_leave, side = leaving(dx * nx + dy * ny + dz * nz, mode, front, back)
        if not p_leave > 0.0:
            continue
        eps = side * geo.offset_rel * vmag
        counters[C_SHADOW] += 1
        nee_stats[stat, 0] += 1
        t, tri, cos_x = first_target((vx + eps * nx, vy + eps * ny, vz + eps * nz), (dx, dy, dz),
                                     (vx, vy, vz, n_near > 0), tgt.near_r2, geo, tgt, organs, photon, n_k, at)
        if t < 0:
            continue
        pdf = cone_pdf(dx, dy, dz, total, n_k, cdf, at)
        if not pdf > 0.0:
            continue
        scale = p_leave / (mean * pdf)
        any_light = False
        for b in range(n_bands):
            f = 1.0 if mode != V_SURFACE else mat.prob[m, DIFFUSE_R if side > 0.0 else DIFFUSE_T, b]
            contrib[b] = w[b] * f * scale
            any_light = any_light or contrib[b] > 0.0
        if any_light:
            n_out = deposit(t, tri, cos_x, (stat, stat), geo, mat, tgt, photon, stats, n_out)
    return n_out
