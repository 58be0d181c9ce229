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
of a cluster v is within :data:`~kernel.importance.CLUSTER_NEAR` radii of by picks (or by local rays, below);
the others by these rays.

**Local rays** (:func:`local_events`) serve the large targets (leaves) of the clusters v is near: rays drawn as
the photon would leave v (cosine-weighted, each side in proportion to its largest diffuse reflectance or
transmittance), the first organ met tallied if it is such a target, neither counted on the photon's own
segment (within √near2) nor of a far cluster.  Their own events and picks then skip them.  Amid a canopy a
vertex on a leaf is near dozens of leaves: two own-event rays each, and picks by 1/d² that mostly meet a leaf
hidden behind another; 8 rays meet the leaves v sees, each in proportion to its share of v's light, with a
deposit that cannot exceed the photon's weight / (rays · the side's probability).  16 roses: the p90 leaf's
σ² was 58 % picks from vertices on organs (for 5 % of its light), and a vertex on a leaf cast ~20 own-event
rays.

Lengths in scene units, solid angles in steradians, deposits in photons of weight.
"""
import math

import numpy as np

from .importance import CLUSTER_NEAR, near_cluster
from .jit import helper
from .nee import INV_4PI, deposit, mean_weight, view_factors
from .rays import first_hit
from .records import DIFFUSE_R, DIFFUSE_T, T_MESH2, V_ISOTROPIC, V_LAMBERT, V_SURFACE  # noqa: F401
from .rng import n_draws, uniform
from .sampling import cosine_hemisphere, search_cdf, uniform_cone, uniform_sphere
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


#: A vertex's cone rays follow what they can bring: their mean is ``cones`` × (its photon's weight, the mean over
#: bands, 1 at the lamp) × (the share C of its light the cones hold, :func:`cone_cdf`) / W_FULL, capped at
#: RAY_CAP × ``cones``, and NEAR_SHARE of that at a vertex within :data:`CLUSTER_NEAR` radii of a cluster.
#: Each hit then deposits about the same weight, whatever the vertex: the rays that a variance summed over the
#: leaves asks (n_v ∝ its deposit per hit, √ its share of rays that meet a leaf: Σ_v h_v d_v² / n_v least).
#: Amid a canopy a vertex is near a cluster (on a leaf, the table under the bushes) and most of its cone rays
#: meet the leaves around it; its far clusters' leaves are served better from the ceiling and the walls.
#: 16 roses (nineteenth session, 1e6 photons, seed 3, the same ~41-45 M cone rays): the p90 leaf's σ² from the
#: cone rays 0.67x that of ``cones`` × min(1, √(C / 0.25)) at every vertex, as before (that rule sent 8.2 M rays,
#: 20 %, from leaves for 11 % of the cones' light, and 3.7 M from the floor and table mat for 0.9 %).
W_FULL = 0.5
RAY_CAP = 4.0
NEAR_SHARE = 0.25


@helper
def ray_mean(cones, total, weight, near):
    """The mean number of cone rays at a vertex whose photon has mean weight ``weight`` over the bands and whose
    cones hold ``total`` = C of its light, ``near`` whether it is near a cluster (see :data:`W_FULL`); ``cones``
    the setting (:attr:`lpy_light.estimators.registry.NextEventSettings.cones`,
    :func:`lpy_light.estimators.kernel_scene.cones_for`)."""
    return cones * min(RAY_CAP, (NEAR_SHARE if near else 1.0) * weight * total / W_FULL)


#: per cluster, after the K cumulative weights, CONE_DATA planes of K values (:func:`cone_cdf`): the cone's axis
#: x, y, z, its 1 − cos θ and c_k / Ω_k (planes, so that :func:`cone_pdf`'s loop reads each one straight on)
CONE_DATA = 5
AXIS_X, AXIS_Y, AXIS_Z, OMC, DENSITY = 1, 2, 3, 4, 5     # plane p of cluster k: cdf[at + p · K + k]


@helper
def cone_cdf(v, side, cl, cdf, at):
    """Cumulative weights ``c_k`` of the K clusters' cones seen from vertex v into ``cdf[at : at + K]``, and each
    cone's axis, ``1 − cos θ`` (0: a near cluster) and ``c_k / Ω_k`` into ``cdf[at + p · K + k]``, p =
    :data:`AXIS_X` ... :data:`DENSITY`; returns the sum C of the weights, and whether v is within
    :data:`CLUSTER_NEAR` radii of a cluster.  ``side`` = (front, back): how much of
    the leaving light goes to each side of a surface (its bands' largest diffuse reflectance and transmittance;
    (1, 0) for a Lambertian emitter, (1, 1) isotropic)."""
    vx, vy, vz, nx, ny, nz, mode, m, vscale, vtri = v
    c0, c1 = view_factors(mode)
    front, back = side
    n_k = cl.radius.shape[0]
    cum, px, py = cdf[at:at + n_k], cdf[at + AXIS_X * n_k:at + (AXIS_X + 1) * n_k], cdf[at + AXIS_Y * n_k:]
    pz, po, pd = cdf[at + AXIS_Z * n_k:], cdf[at + OMC * n_k:], cdf[at + DENSITY * n_k:]   # views: see cone_pdf
    total = 0.0
    near = False
    for k in range(n_k):
        d, ax, ay, az, s, omc = cone_of(k, vx, vy, vz, cl)
        c = 0.0
        near = near or not omc > 0.0
        if omc > 0.0:
            cosc = ax * nx + ay * ny + az * nz
            f = front if cosc - s > 0.0 else (back if cosc + s < 0.0 else max(front, back))
            c = 2.0 * math.pi * omc * f * (c0 + c1 * min(1.0, abs(cosc) + s))
        total += c
        cum[k] = total
        px[k], py[k], pz[k] = ax, ay, az
        po[k] = omc
        pd[k] = c / (2.0 * math.pi * omc) if c > 0.0 else 0.0
    return total, near


@helper
def cone_pdf(dx, dy, dz, total, n_k, cdf, at):
    """The density (1/sr) of direction d among :func:`cone_cdf`'s cones (summing to ``total``): Σ over the cones
    holding d of (c_k / C) / Ω_k (a near cluster's c_k is 0).  Without branches, in two sums: a ray's
    direction is in a few cones of the K, unpredictably.  (Over views of the planes, indexed from 0: the
    index needs no wraparound test, and the loop is ~3x shorter than with ``cdf[at + p · K + k]``.)"""
    ax, ay = cdf[at + AXIS_X * n_k:at + (AXIS_X + 1) * n_k], cdf[at + AXIS_Y * n_k:at + (AXIS_Y + 1) * n_k]
    az, om = cdf[at + AXIS_Z * n_k:at + (AXIS_Z + 1) * n_k], cdf[at + OMC * n_k:at + (OMC + 1) * n_k]
    de = cdf[at + DENSITY * n_k:at + (DENSITY + 1) * n_k]
    pdf0 = pdf1 = 0.0
    for j in range(n_k // 2):
        k, k1 = np.uint64(2 * j), np.uint64(2 * j + 1)      # unsigned: no wraparound test either
        in0 = 1.0 - (dx * ax[k] + dy * ay[k] + dz * az[k]) <= om[k]
        in1 = 1.0 - (dx * ax[k1] + dy * ay[k1] + dz * az[k1]) <= om[k1]
        pdf0 += de[k] if in0 else 0.0
        pdf1 += de[k1] if in1 else 0.0
    if n_k % 2 == 1:
        k = n_k - 1
        pdf0 += de[k] if 1.0 - (dx * ax[k] + dy * ay[k] + dz * az[k]) <= om[k] else 0.0
    return (pdf0 + pdf1) / total


@helper
def cone_direction(u0, u1, u2, total, n_k, cdf, at):
    """A direction drawn from :func:`cone_cdf`'s cones (weights in ``cdf[at:]``, summing to ``total``) from three
    uniforms: a cone in proportion to its weight, then a direction uniform within it.  Its density is
    :func:`cone_pdf`."""
    k = search_cdf(cdf, at, at + n_k - 1, u0 * total) - at
    return uniform_cone(cdf[at + AXIS_X * n_k + k], cdf[at + AXIS_Y * n_k + k], cdf[at + AXIS_Z * n_k + k],
                        cdf[at + OMC * n_k + k], u1, u2)


@helper
def target_met(origin, d, geo, tgt, photon):
    """The first surface a ray from ``origin`` (already off its surface) along unit ``d`` meets, if a target organ:
    ``(t, triangle)``; (-1, -1) where it meets nothing, the chamber, or an organ that is no target."""
    tri, _, _, _ = first_hit(geo, photon.scratch, origin[0], origin[1], origin[2], d[0], d[1], d[2], _TFAR_MAX,
                             photon.state)
    rec = geo.receiver[tri] if tri >= 0 else -1
    if rec < 0 or tgt.receiver_target[rec] < 0:
        return -1, -1
    return tgt.receiver_target[rec], tri


@helper
def first_target(origin, d, near, near_r2, geo, tgt, organs, photon, n_k, at):
    """Trace a cone ray from ``origin`` (already off its surface) along unit ``d``: ``(t, triangle, cos θ_x)`` of
    the first surface met if it is a target organ that cone rays serve from the point the cones were drawn
    from (``cdf[at:]``, :func:`cone_cdf`), else t = -1.  ``near`` = (point, test): with test, a target whose
    centre is within √``near_r2[t]`` of the point is served otherwise (an own event, or a counted crossing)."""
    t, tri = target_met(origin, d, geo, tgt, photon)
    if t < 0:
        return -1, -1, 0.0
    px, py, pz, test = near
    ex, ey, ez = px - tgt.center[t, 0], py - tgt.center[t, 1], pz - tgt.center[t, 2]
    if test and ex * ex + ey * ey + ez * ez < near_r2[t]:
        return -1, -1, 0.0                        # served by its own event there (or counted)
    if organs.far_weight[t] > 0.0:
        return -1, -1, 0.0                        # a small target: served by picks from every cluster
    if photon.cdf[at + OMC * n_k + organs.cluster_of[t]] == 0.0:
        return -1, -1, 0.0                        # its cluster is near: served by local rays (or picks)
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
def leaving_deposit(met, scale, side, v, stat, geo, mat, tgt, photon, stats, n_out):
    """Deposit on the target a ray from vertex ``v`` met, ``met`` = (t, triangle, cos θ_x): the photon's weights
    times v's diffuse probability on ``side`` (±1; 1 for an emitter) times ``scale`` (the leaving pdf over the
    ray's, over the mean number of rays), unless nothing is; counted in ``stats.nee_stats[stat]``.  Returns the
    new count of ``photon.out_k`` / ``out_w``."""
    t, tri, cos_x = met
    mode, m = v[6], v[7]
    contrib, w = photon.contrib, photon.w
    any_light = False
    for b in range(w.shape[0]):
        f = 1.0 if mode != V_SURFACE else mat.prob[m, DIFFUSE_R if side > 0.0 else DIFFUSE_T, b]
        contrib[b] = w[b] * f * scale
        any_light = any_light or contrib[b] > 0.0
    if any_light:
        n_out = deposit(t, tri, cos_x, (stat, stat), geo, mat, tgt, photon, stats, n_out)
    return n_out


@helper
def cone_events(v, stat, geo, mat, tgt, organs, photon, stats, n_out):
    """Rays from vertex ``v`` (:class:`~kernel.records.Vertex`) into the cones of the far clusters of organ
    targets (see above): a random whole number of them, of mean μ = :func:`ray_mean`; the deposits of those
    that first meet a target organ served by them, divided by μ, go to ``photon.out_k`` / ``photon.out_w`` from
    ``n_out`` on.  Returns the new count."""
    vx, vy, vz, nx, ny, nz, mode, m, vscale, vtri = v
    cl = organs.clusters
    n_k = cl.radius.shape[0]
    cdf, state = photon.cdf, photon.state
    counters, nee_stats = stats.counters, stats.nee_stats
    at = tgt.kind.shape[0] + n_k            # after the picks' importances (kernel.importance.cluster_cdf)
    front, back = leaving_sides(v, mat)
    total, near = cone_cdf(v, (front, back), cl, cdf, at)
    if not total > 0.0:
        return n_out
    mean = ray_mean(organs.cones, total, mean_weight(photon.w), near)
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
        n_out = leaving_deposit((t, tri, cos_x), p_leave / (mean * pdf), side, v, stat, geo, mat, tgt, photon, stats,
                                n_out)
    return n_out


@helper
def any_near_cluster(vx, vy, vz, cl):
    """Is vertex v within :data:`CLUSTER_NEAR` radii of any cluster of targets?"""
    for k in range(cl.radius.shape[0]):
        ex, ey, ez = cl.center[k, 0] - vx, cl.center[k, 1] - vy, cl.center[k, 2] - vz
        r = CLUSTER_NEAR * cl.radius[k]
        if ex * ex + ey * ey + ez * ez < r * r:
            return True
    return False


@helper
def local_target(origin, d, v, geo, tgt, organs, photon):
    """Trace a local ray from ``origin`` (already off its surface) along unit ``d``: ``(t, triangle, cos θ_x)`` of
    the first surface met if it is a target organ that local rays serve from vertex ``v`` (a large target,
    ``organs.near_weight`` 0, of a cluster v is near, not counted on the photon's own segment -- within
    √``tgt.near2``), else t = -1.  (Its own events at v skip it: :func:`kernel.nee.next_event`.)"""
    t, tri = target_met(origin, d, geo, tgt, photon)
    if t < 0:
        return -1, -1, 0.0
    if organs.near_weight[t] > 0.0 or not near_cluster(t, v[0], v[1], v[2], organs):
        return -1, -1, 0.0                        # served by picks (a small target), or by cone rays (far)
    ex, ey, ez = v[0] - tgt.center[t, 0], v[1] - tgt.center[t, 1], v[2] - tgt.center[t, 2]
    if ex * ex + ey * ey + ez * ez < tgt.near2[t]:
        return -1, -1, 0.0                        # counted on the photon's own segment
    cos_x = d[0] * geo.normal[tri, 0] + d[1] * geo.normal[tri, 1] + d[2] * geo.normal[tri, 2]
    if tgt.kind[t] != T_MESH2 and cos_x >= 0.0:
        return -1, -1, 0.0                        # a one-sided receiver, met from behind
    return t, tri, cos_x


@helper
def local_events(v, stat, geo, mat, tgt, organs, photon, stats, n_out):
    """Rays from vertex ``v`` drawn as the photon would leave it (cosine-weighted, on each side in proportion
    to :func:`leaving_sides`), the first organ met tallied if local rays serve it (:func:`local_target`): the
    large targets of the clusters v is near, which picks then skip (``organs.near_weight`` 0).  Amid a canopy
    a pick is one leaf drawn by 1/d² among the cluster's, most of them hidden or turned away; a ray meets the
    leaves v sees, each in proportion to its share of v's light.  A random whole number of rays, only at vertices
    near a cluster, of mean ``organs.local`` × the photon's mean weight / :data:`W_FULL` (at most :data:`RAY_CAP`
    × ``organs.local``): as for cone rays, each hit then deposits about the same weight (16 roses' cost to leaves'
    p90 3 % 28.6 → 26.6 CPU s against ``organs.local`` at every such vertex, nineteenth session).  Deposits to
    ``photon.out_k`` / ``out_w`` from ``n_out`` on.
    Returns the new count."""
    vx, vy, vz, nx, ny, nz, mode, m, vscale, vtri = v
    if not any_near_cluster(vx, vy, vz, organs.clusters):
        return n_out
    state = photon.state
    counters, nee_stats = stats.counters, stats.nee_stats
    front, back = leaving_sides(v, mat)
    if not front + back > 0.0:
        return n_out
    mean = organs.local * min(RAY_CAP, mean_weight(photon.w) / W_FULL)
    if not mean > 0.0:
        return n_out
    n_rays = n_draws(mean, state)
    vmag = max(abs(vx), abs(vy), abs(vz), vscale)
    p_front = front / (front + back)
    for _ in range(n_rays):
        u0, u1, u2 = uniform(state), uniform(state), uniform(state)
        if mode == V_ISOTROPIC:
            dx, dy, dz = uniform_sphere(u1, u2)
            side, p_side = (1.0 if dx * nx + dy * ny + dz * nz > 0.0 else -1.0), 1.0
        elif mode == V_LAMBERT or u0 < p_front:
            dx, dy, dz = cosine_hemisphere(nx, ny, nz, u1, u2)
            side, p_side = 1.0, (1.0 if mode == V_LAMBERT else p_front)
        else:
            dx, dy, dz = cosine_hemisphere(-nx, -ny, -nz, u1, u2)
            side, p_side = -1.0, 1.0 - p_front
        eps = side * geo.offset_rel * vmag
        counters[C_SHADOW] += 1
        nee_stats[stat, 0] += 1
        t, tri, cos_x = local_target((vx + eps * nx, vy + eps * ny, vz + eps * nz), (dx, dy, dz), (vx, vy, vz),
                                     geo, tgt, organs, photon)
        if t < 0:
            continue
        # the leaving pdf over the draw's: |cos|/π over p_side · |cos|/π
        n_out = leaving_deposit((t, tri, cos_x), 1.0 / (mean * p_side), side, v, stat, geo, mat, tgt, photon, stats,
                                n_out)
    return n_out
