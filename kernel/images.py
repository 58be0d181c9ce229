"""Next events through a mirror: the light a target gets from a vertex after one perfect specular reflection.

The chamber's metal walls have a mirror part; the light a sensor or an organ gets by way of them is lost to
next events (a segment after a specular event is counted, not estimated), and counting it held over half
the leaves' variance on the rose.  The image method estimates it from every next-event vertex v instead:
a point x on a target and its image x' across a mirror plane P; the ray v → x' meets P where a photon
would reflect to x (:func:`image_event`).  A photon that does leave a vertex, reflect on P and cross the
target skips that crossing (:func:`image_counted`), so every path is counted once: unbiased.

Deposits in photons of weight, lengths in scene units, solid angles in steradians; the planes are
``kernel.records.Mirrors`` (``lpy_light.chamber.geometry.mirror_planes``).
"""
import math

from .jit import helper
from .cones import cone_cdf, cone_direction, cone_pdf, first_target, leaving, leaving_sides, ray_mean
from .importance import cluster_cdf, draw
from .nee import (END_REL, INV_4PI, NEAR, deposit, disc_point_by_solid_angle, mean_weight, mesh_point, seen_deposit,
                  sensor_point)
from .rays import hit_on_plane, magnitude, set_ray
from .records import DIFFUSE_R, DIFFUSE_T, SPECULAR_R, T_DISC, T_MESH2, V_SURFACE
from .rng import n_draws, uniform
from .sampling import search_cdf
from .tallies import C_SHADOW

NO_EVENT = -2  # image_target_point: no event for this target from this image point
MIX2 = 0.25    # events through two mirrors: each plane's importance plus this share of the mean (plane_cdf)


@helper
def plane_importance(vx, vy, vz, pl, mir):
    """How much mirror plane ``pl`` can matter to next events through it from point v: its specular reflectance
    ``mir.spec[pl]`` times an upper bound of the solid angle it subtends at v, A |s| / d³ (area A, v at
    signed distance s from the plane and at least d from the plane's bounding box: every point of the plane is
    at least d away and seen at |cos| = |s| / r ≤ |s| / d), capped at 2π.  Zero where no reflection on the
    plane can join v to a target: v in the plane, or behind a one-sided mirror.  Drawing planes in proportion
    to it (:func:`image_event`) spends the events on the planes beside v: a strip of aluminium right above
    a wall vertex, drawn as rarely as a far wall, made rare deposits of a whole photon's weight."""
    mx, my, mz = mir.normal[pl, 0], mir.normal[pl, 1], mir.normal[pl, 2]
    sv = (vx - mir.point[pl, 0]) * mx + (vy - mir.point[pl, 1]) * my + (vz - mir.point[pl, 2]) * mz
    if sv == 0.0 or (mir.one_sided[pl] != 0 and sv < 0.0):
        return 0.0
    box = mir.box
    cx = min(max(vx, box[pl, 0, 0]), box[pl, 1, 0])      # the nearest point of the plane's bounding box
    cy = min(max(vy, box[pl, 0, 1]), box[pl, 1, 1])
    cz = min(max(vz, box[pl, 0, 2]), box[pl, 1, 2])
    d2 = (vx - cx) ** 2 + (vy - cy) ** 2 + (vz - cz) ** 2
    s = abs(sv)
    d2 = max(d2, s * s)
    return mir.spec[pl] * min(2.0 * math.pi, mir.area[pl] * s / (d2 * math.sqrt(d2)))


@helper
def plane_cdf(px, py, pz, mir, cdf, skip, mix, every):
    """Cumulative importances of the planes in use (``mir.plane``) seen from p into ``cdf``, the plane at
    position ``skip`` (or none: -1) left out; returns their sum.  Each is :func:`plane_importance` plus ``mix``
    times the mean of the positive ones (a defensive mixture, so that no plane that can serve a path is drawn
    too rarely), for the planes of positive importance only or, ``every``, for all: where p is a target's
    centre, a plane behind which the centre lies may still reflect light to the target's front part."""
    total = 0.0
    count = 0
    for j in range(mir.plane.shape[0]):
        g = plane_importance(px, py, pz, mir.plane[j], mir) if j != skip else 0.0
        cdf[j] = g
        total += g
        count += 1 if g > 0.0 else 0
    if mix > 0.0 and count > 0:
        floor = mix * total / count
        total = 0.0
        for j in range(mir.plane.shape[0]):
            total += cdf[j] + floor if (cdf[j] > 0.0 or (every and j != skip)) else 0.0
            cdf[j] = total
    else:
        total = 0.0
        for j in range(mir.plane.shape[0]):
            total += cdf[j]
            cdf[j] = total
    return total


@helper
def reflect(px, py, pz, pl, mir):
    """Point p's image across mirror plane ``pl`` and p's signed distance to it: ``(x, y, z, s)``."""
    mx, my, mz = mir.normal[pl, 0], mir.normal[pl, 1], mir.normal[pl, 2]
    s = (px - mir.point[pl, 0]) * mx + (py - mir.point[pl, 1]) * my + (pz - mir.point[pl, 2]) * mz
    return px - 2.0 * s * mx, py - 2.0 * s * my, pz - 2.0 * s * mz, s


@helper
def in_box(x, y, z, pl, mir):
    """Is (x, y, z) within the bounds of mirror plane ``pl``?"""
    box = mir.box
    return (box[pl, 0, 0] <= x <= box[pl, 1, 0] and box[pl, 0, 1] <= y <= box[pl, 1, 1]
            and box[pl, 0, 2] <= z <= box[pl, 1, 2])


@helper
def image_target_point(t, ix, iy, iz, u, geo, sens, tgt):
    """A point x on target t for an event through mirrors, whose unfolded source is the image point i:
    ``(g, x, y, z, nx, ny, nz, omega)``: a mesh's by area (g its triangle), a quad's by area, a disc's by solid
    angle as seen from i (omega the estimator's factor), g = -1 for sensors; n is the surface's normal at x.
    g = :data:`NO_EVENT` when there is none: i within t's exclusion radius (the crossing is counted instead),
    or behind a disc."""
    u1, u2, u3 = u
    kind = tgt.kind[t]
    ex, ey, ez = ix - tgt.center[t, 0], iy - tgt.center[t, 1], iz - tgt.center[t, 2]
    if ex * ex + ey * ey + ez * ez < tgt.img_near2[t]:
        return NO_EVENT, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    if kind >= T_MESH2:
        g, px, py, pz = mesh_point(t, u1, u2, u3, tgt, geo)
        return g, px, py, pz, geo.normal[g, 0], geo.normal[g, 1], geo.normal[g, 2], 0.0
    s = tgt.ref[t]
    omega = 0.0
    if kind == T_DISC:
        px, py, pz, omega = disc_point_by_solid_angle(ix, iy, iz, s, u1, u2, sens)
        if omega == 0.0:
            return NO_EVENT, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    else:
        px, py, pz = sensor_point(kind, s, u1, u2, u3, sens)
    return -1, px, py, pz, sens.normal[s, 0], sens.normal[s, 1], sens.normal[s, 2], omega


@helper
def leaving_pdf(v, cos_v, b, mat):
    """The density (per steradian) with which a photon leaves vertex v in a direction at cosine ``cos_v`` to
    its normal, in band b."""
    mode, m = v[6], v[7]
    if mode == 0:
        return INV_4PI
    if mode == 1:
        return cos_v / math.pi
    return mat.prob[m, 0 if cos_v > 0.0 else 2, b] * abs(cos_v) / math.pi


@helper
def leaving_towards(dx, dy, dz, n, mode):
    """Leaving vertex v (unit normal ``n``, its ``mode``) along d = (dx, dy, dz), not normalised:
    ``(|d|², cos_v, side)``, side 0 for an isotropic lamp and ±1 the side of a surface or emitter it leaves;
    side NaN where no photon leaves that way (d null, or behind a Lambertian emitter)."""
    L2 = dx * dx + dy * dy + dz * dz
    if not L2 > 0.0:
        return L2, 0.0, math.nan
    cos_v = (dx * n[0] + dy * n[1] + dz * n[2]) / math.sqrt(L2)
    if mode == 1 and cos_v <= 0.0:                     # V_LAMBERT: emits into its front only
        return L2, cos_v, math.nan
    return L2, cos_v, 0.0 if mode == 0 else (1.0 if cos_v > 0.0 else -1.0)


@helper
def last_leg(target, hit, omag, rows, geo, mat, tgt, photon, stats, n_out):
    """The last leg of an event through mirrors: from the last mirror's hit to the point x on the target.
    ``target`` = (t, g, x, y, z, nx, ny, nz) as :func:`image_target_point` gave it, ``hit`` = (triangle, point,
    its normal towards the arriving ray) on the last mirror, ``omag`` the magnitude of the ray's origin there.
    ``photon.contrib`` (B,) holds the deposit without x's cosine (a disc's solid angle factor already in): x
    must be reached from its front (sensors, one-sided meshes) and be seen (:func:`kernel.rays.seen_share`);
    the deposit, times |cos θ_x| unless on a disc, goes to t's row (and what the side met absorbs to its
    absorbed row), and to ``stats.nee_stats[rows]`` (found, weight).  Returns the new count."""
    t, g, px, py, pz, snx, sny, snz = target
    tri, hx, hy, hz, tnx, tny, tnz = hit
    contrib = photon.contrib
    offset_rel, kind, n_bands = geo.offset_rel, tgt.kind[t], contrib.shape[0]
    fx, fy, fz = px - hx, py - hy, pz - hz
    d2 = math.sqrt(fx * fx + fy * fy + fz * fz)
    if not d2 > 0.0:
        return n_out
    fx, fy, fz = fx / d2, fy / d2, fz / d2
    cos_x = fx * snx + fy * sny + fz * snz
    if kind != T_MESH2 and cos_x >= 0.0:
        return n_out                                   # a sensor (one-sided mesh) is crossed from its front only
    any_light = False
    for b in range(n_bands):
        if kind != T_DISC:
            contrib[b] *= abs(cos_x)
        any_light = any_light or contrib[b] > 0.0
    if not any_light:
        return n_out
    hmag = max(magnitude(geo.verts[tri]), abs(hx), abs(hy), abs(hz))
    pmag = max(abs(px), abs(py), abs(pz))
    if g >= 0:                                         # a mesh target is a surface: its triangle's round-off
        pmag = max(pmag, magnitude(geo.verts[g]))
    eps = offset_rel * (hmag + omag)
    tol = offset_rel * (hmag + pmag) * 2.0
    if g >= 0:                                         # its float32 plane's error (as in next_event)
        tol += END_REL * d2
    if d2 - tol <= 0.0:
        return n_out
    stats.counters[C_SHADOW] += 1
    ox, oy, oz = hx + eps * tnx, hy + eps * tny, hz + eps * tnz
    return seen_deposit(t, g, cos_x, ((ox, oy, oz), (fx, fy, fz), (px, py, pz), d2, tol), rows, geo, mat, tgt, photon,
                        stats, n_out)


@helper
def mirror_ray(origin, omag, side_n, target, pl, geo, photon, state, stats):
    """Cast a ray from ``origin`` (magnitude ``omag``; offset along ``side_n``, the origin surface's normal
    on the side the ray leaves, (0, 0, 0) at a lamp) towards ``target``; the first surface met must be mirror
    plane ``pl`` on a perfect mirror's side: returns (triangle, hit, normal towards the origin, material), or
    triangle -1."""
    ox, oy, oz = origin
    tx, ty, tz = target
    dx, dy, dz = tx - ox, ty - oy, tz - oz
    L = math.sqrt(dx * dx + dy * dy + dz * dz)
    if not L > 0.0:
        return -1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0
    dx, dy, dz = dx / L, dy / L, dz / L
    eps = geo.offset_rel * omag
    set_ray(photon.scratch, ox + eps * side_n[0], oy + eps * side_n[1], oz + eps * side_n[2], dx, dy, dz, L)
    stats.counters[C_SHADOW] += 1
    return hit_on_plane(geo, photon.scratch, geo.mirror_plane, pl, dx, dy, dz, state)


@helper
def image_event(v, n_draw, stat0, geo, mat, sens, tgt, mir, organs, photon, stats):
    """Next events through one perfect mirror: the expected light that the segment leaving vertex ``v``
    (:class:`~kernel.records.Vertex`) brings to a target (transparent sensor or mesh) after one specular
    reflection on a mirror plane (the image method).

    For ``n_draw`` draws (a random whole number whose mean is ``mir.picks``, :func:`kernel.rng.n_draws`): a
    mirror plane P (one of ``mir.plane``, drawn with probability p_k in proportion to :func:`plane_importance`
    at v, computed once for the draws) and a target t, with probability p_t: uniform (1 / n_targets) among
    sensors; among organs (``organs``, :class:`~kernel.records.OrganEvents`) split as the direct events split
    them, but seen from v's image i across P: picked by importance from i (:mod:`kernel.importance`; the far
    clusters' targets by their far weights), and where cone rays are on, the far clusters' large targets served
    by cone rays from i instead (:func:`image_cones`) -- drawn uniformly, a leaf of a 16-rose canopy got one
    event in 5,504, and those carried half its variance; a point x on t (a disc's by
    solid angle as seen from v's image, a quad's or a mesh's by area), its image x' across P; the ray v → x'
    must first meet a triangle of P (after the coplanar pick, as a photon would), from a side whose material
    is a perfect mirror, and the leg from there to x must be free (for a mesh: the first surface met is the
    mesh, at x, :func:`kernel.rays.reaches`).  Deposit
    w · f_v(ω) · P_spec,b · A_t |cos θ_x| / |x' − v|² / (p_t · p_k · picks)  (a mirror keeps solid angle),
    and on a mesh with an absorbed row that times the absorptance of the side met.  Sensors and one-sided
    meshes are met from their front only, two-sided meshes from either side.
    A vertex whose image across P lies within the target's exclusion radius (``tgt.img_near2``) makes no
    such event: the crossing is counted instead (:func:`image_counted`).  ``stats.nee_stats[stat0 + P]``
    counts rays cast, paths found, weight deposited.  Returns the number of deposits in ``photon.out_k`` /
    ``photon.out_w`` (at most two per draw).
    """
    vx, vy, vz, nx, ny, nz, mode, m, vscale, _vtri = v
    w, contrib, state = photon.w, photon.contrib, photon.state
    n_bands, n_tgt, n_mir = w.shape[0], tgt.kind.shape[0], mir.plane.shape[0]
    if n_tgt == 0 or n_mir == 0 or n_draw <= 0 or not mir.picks > 0.0:
        return 0
    total = plane_cdf(vx, vy, vz, mir, photon.plane_cdf, -1, 0.0, False)
    if not total > 0.0:
        return 0
    scale = n_tgt / mir.picks
    vmag = max(abs(vx), abs(vy), abs(vz), vscale)
    n_out = 0
    for _ in range(n_draw):
        t = min(int(uniform(state) * n_tgt), n_tgt - 1) if organs is None else -1
        k = search_cdf(photon.plane_cdf, 0, n_mir - 1, uniform(state) * total)     # a plane, by importance at v
        p_k = (photon.plane_cdf[k] - (photon.plane_cdf[k - 1] if k > 0 else 0.0)) / total
        u = (uniform(state), uniform(state), uniform(state))
        pl = mir.plane[k]
        ix, iy, iz, sv = reflect(vx, vy, vz, pl, mir)                   # v's image across P
        if not p_k > 0.0 or sv == 0.0 or (mir.one_sided[pl] != 0 and sv < 0.0):
            continue
        if organs is not None:       # an organ by its importance seen from the image (its solid angle, about)
            image = (ix, iy, iz)
            if organs.cones > 0.0:   # and the far clusters' leaves by rays into their cones seen from the image
                n_out = image_cones(v, (ix, iy, iz, pl), p_k, stat0 + pl, geo, mat, tgt, mir, organs, photon, stats,
                                    n_out)
            how = (organs.weight, organs.cluster_weight, tgt.img_near2, NEAR * NEAR, False, organs.far_weight)
            sum_t = cluster_cdf(image, how, organs.clusters, tgt, photon.cdf, photon.exact)
            if not sum_t > 0.0:
                continue
            t, p_t = draw(uniform(state), uniform(state), sum_t, image, how, organs.clusters, tgt, photon.cdf,
                          photon.exact)
            if t < 0:
                continue
            scale = 1.0 / (p_t * mir.picks)
        g, px, py, pz, snx, sny, snz, omega = image_target_point(t, ix, iy, iz, u, geo, sens, tgt)
        kind = tgt.kind[t]
        if g == NO_EVENT:
            continue
        jx, jy, jz, sx = reflect(px, py, pz, pl, mir)                   # x's image x'
        if sx * sv <= 0.0:
            continue                                   # x and v on opposite sides of P: no reflection joins them
        f = sv / (sv + sx)                             # where the ray v → x' crosses P: reject without rays
        rx, ry, rz = vx + f * (jx - vx), vy + f * (jy - vy), vz + f * (jz - vz)
        if not in_box(rx, ry, rz, pl, mir):
            continue
        if kind != T_MESH2 and (px - rx) * snx + (py - ry) * sny + (pz - rz) * snz >= 0.0:
            continue                                   # would reach the sensor (one-sided mesh) from behind
        L2, cos_v, side = leaving_towards(jx - vx, jy - vy, jz - vz, (nx, ny, nz), mode)
        if math.isnan(side):
            continue
        stats.nee_stats[stat0 + pl, 0] += 1
        tri, hx, hy, hz, tnx, tny, tnz, mm = mirror_ray((vx, vy, vz), vmag, (side * nx, side * ny, side * nz),
                                                        (jx, jy, jz), pl, geo, photon, state, stats)
        if tri < 0 or not math.isinf(mat.phong[mm]):
            continue                                   # something else first, or not a perfect mirror's side
        for b in range(n_bands):
            contrib[b] = (w[b] * leaving_pdf(v, cos_v, b, mat) * mat.prob[mm, SPECULAR_R, b] * scale / p_k
                          * (omega if kind == T_DISC else tgt.area[t] / L2))
        n_out = last_leg((t, g, px, py, pz, snx, sny, snz), (tri, hx, hy, hz, tnx, tny, tnz), vmag,
                         (stat0 + pl, stat0 + pl), geo, mat, tgt, photon, stats, n_out)
    return n_out


@helper
def image_cones(v, image, p_k, stat, geo, mat, tgt, mir, organs, photon, stats, n_out):
    """Cone rays through a mirror (:mod:`kernel.cones` from v's image): the light the segment leaving vertex
    ``v`` brings, after one perfect specular reflection on plane P, to the target organs that cone rays serve
    from v's image i (``image`` = (i, P), P drawn with probability ``p_k``).  The cones are those of the far
    clusters seen from i, with v's normal reflected across P; a direction d drawn in them (density pdf(d),
    :func:`kernel.cones.cone_pdf`) unfolds the path v → m → organ: m where the ray from i along d crosses P, the
    ray v → m must first meet P on a perfect mirror's side (:func:`mirror_ray`), and the first surface met from
    m along d is the organ tallied.  Deposit w · f_v · P_spec,b · p_leave(d) / (μ · pdf(d) · p_k · picks), μ the
    mean number of rays (:func:`kernel.cones.ray_mean`): these targets get no picks through P from v (the picks
    draw the far clusters' targets by their far weights, 0 for these), so each path is counted once.
    Returns the new count of deposits in ``photon.out_k`` / ``photon.out_w``."""
    vx, vy, vz, nx, ny, nz, mode, m, vscale, _vtri = v
    ix, iy, iz, pl = image
    cl = organs.clusters
    n_k = cl.radius.shape[0]
    w, contrib, state, cdf = photon.w, photon.contrib, photon.state, photon.cdf
    n_bands = w.shape[0]
    at = tgt.kind.shape[0] + n_k
    px, py, pz = mir.normal[pl, 0], mir.normal[pl, 1], mir.normal[pl, 2]
    dn = nx * px + ny * py + nz * pz
    inx, iny, inz = nx - 2.0 * dn * px, ny - 2.0 * dn * py, nz - 2.0 * dn * pz      # v's normal, mirrored
    front, back = leaving_sides(v, mat)
    total, near = cone_cdf((ix, iy, iz, inx, iny, inz, mode, m, vscale, -1), (front, back), cl, cdf, at)
    if not total > 0.0:
        return n_out
    mean = ray_mean(organs.cones, total, mean_weight(w), near)
    n_rays = n_draws(mean, state)
    vmag = max(abs(vx), abs(vy), abs(vz), vscale)
    si = (ix - mir.point[pl, 0]) * px + (iy - mir.point[pl, 1]) * py + (iz - mir.point[pl, 2]) * pz
    for _ in range(n_rays):
        dx, dy, dz = cone_direction(uniform(state), uniform(state), uniform(state), total, n_k, cdf, at)
        p_leave, side = leaving(dx * inx + dy * iny + dz * inz, mode, front, back)
        dd = dx * px + dy * py + dz * pz
        if not p_leave > 0.0 or not -si * dd > 0.0:
            continue                                   # no photon leaves that way, or d turns from P
        tau = -si / dd
        mx, my, mz = ix + tau * dx, iy + tau * dy, iz + tau * dz            # where the unfolded ray crosses P
        if not in_box(mx, my, mz, pl, mir):
            continue
        stats.nee_stats[stat, 0] += 1
        tri, hx, hy, hz, tnx, tny, tnz, mm = mirror_ray((vx, vy, vz), vmag, (side * nx, side * ny, side * nz),
                                                        (2.0 * mx - vx, 2.0 * my - vy, 2.0 * mz - vz), pl, geo,
                                                        photon, state, stats)    # (a ray ending at m may stop short)
        if tri < 0 or not math.isinf(mat.phong[mm]):
            continue                                   # something else first, or not a perfect mirror's side
        eps = geo.offset_rel * max(magnitude(geo.verts[tri]), abs(hx), abs(hy), abs(hz))
        stats.counters[C_SHADOW] += 1
        t, g, cos_x = first_target((hx + eps * tnx, hy + eps * tny, hz + eps * tnz), (dx, dy, dz),
                                   (ix, iy, iz, True), tgt.img_near2, geo, tgt, organs, photon, n_k, at)
        if t < 0:
            continue
        pdf = cone_pdf(dx, dy, dz, total, n_k, cdf, at)
        if not pdf > 0.0:
            continue
        scale = p_leave / (mean * pdf * p_k * mir.picks)
        any_light = False
        for b in range(n_bands):
            f = 1.0 if mode != V_SURFACE else mat.prob[m, DIFFUSE_R if side > 0.0 else DIFFUSE_T, b]
            contrib[b] = w[b] * f * mat.prob[mm, SPECULAR_R, b] * scale
            any_light = any_light or contrib[b] > 0.0
        if any_light:
            n_out = deposit(t, g, cos_x, (stat, stat), geo, mat, tgt, photon, stats, n_out)
    return n_out


@helper
def double_image_event(v, n_draw, stat0, geo, mat, sens, tgt, mir, photon, stats):
    """Next events through two perfect mirrors: the expected light that the segment leaving vertex ``v``
    brings to a target after specular reflections on two mirror planes, P1 then P2.

    Photons that reach a sensor that way (between the parallel metal walls of a chamber, off a wall and the
    aluminium under its ceiling) were counted, each with its whole weight: the heavy tail of the Angers sensors
    once :func:`image_event` served one reflection.  Per draw (``n_draw``, mean ``mir.picks2``): a target t
    (uniform), P1 by :func:`plane_importance` at v (probability p1), P2 by its importance at t's centre (P1
    itself left out; probability p2) -- each mirror by what it subtends where the path touches it; both mixed
    with :data:`MIX2` of the mean (:func:`plane_cdf`) --, a point x on t (a disc's by solid angle from v'', v' across
    P2); x' = x across P2, x'' = x' across P1.  The ray v → x'' must first meet P1 (a perfect mirror's side) at
    r1, the ray r1 → x' then P2 at r2, and x must be seen from r2.  Deposit
    w · f_v(ω) · P_spec1,b · P_spec2,b · A_t |cos θ_x| / |x'' − v|² · n_targets / (p1 p2 · picks2).
    A vertex whose double image v'' lies within the target's exclusion radius makes no such event (the crossing
    is counted: :func:`double_image_counted`).  ``stats.nee_stats[stat0 + P]`` as in :func:`image_event` (rays
    on P1; paths and weight on both planes).  Returns the number of deposits (at most two per draw).
    """
    vx, vy, vz, nx, ny, nz, mode, m, vscale, _vtri = v
    w, contrib, state, cdf = photon.w, photon.contrib, photon.state, photon.plane_cdf
    n_bands, n_tgt, n_mir = w.shape[0], tgt.kind.shape[0], mir.plane.shape[0]
    if n_tgt == 0 or n_mir < 2 or n_draw <= 0 or not mir.picks2 > 0.0:
        return 0
    scale = n_tgt / mir.picks2
    vmag = max(abs(vx), abs(vy), abs(vz), vscale)
    n_out = 0
    total1 = plane_cdf(vx, vy, vz, mir, cdf, -1, MIX2, False)                # P1 by its importance at v
    cdf2 = cdf[n_mir:]                                                          # P2's, per draw
    for _ in range(n_draw):
        t = min(int(uniform(state) * n_tgt), n_tgt - 1)
        u1, u2 = uniform(state), uniform(state)
        u = (uniform(state), uniform(state), uniform(state))
        if not total1 > 0.0:
            return n_out
        k1 = search_cdf(cdf, 0, n_mir - 1, u1 * total1)
        p1 = (cdf[k1] - (cdf[k1 - 1] if k1 > 0 else 0.0)) / total1
        pl1 = mir.plane[k1]
        ax, ay, az, sv1 = reflect(vx, vy, vz, pl1, mir)                 # v' = v across P1
        if not p1 > 0.0 or sv1 == 0.0 or (mir.one_sided[pl1] != 0 and sv1 < 0.0):
            continue
        cx, cy, cz = tgt.center[t, 0], tgt.center[t, 1], tgt.center[t, 2]
        total2 = plane_cdf(cx, cy, cz, mir, cdf2, k1, MIX2, True)             # P2 by its importance at t's centre
        if not total2 > 0.0:
            continue
        k2 = search_cdf(cdf2, 0, n_mir - 1, u2 * total2)
        p2 = (cdf2[k2] - (cdf2[k2 - 1] if k2 > 0 else 0.0)) / total2
        pl2 = mir.plane[k2]
        bx, by, bz, sa2 = reflect(ax, ay, az, pl2, mir)                 # v'' = v' across P2
        if k2 == k1 or not p2 > 0.0 or sa2 == 0.0 or (mir.one_sided[pl2] != 0 and sa2 < 0.0):
            continue
        g, px, py, pz, snx, sny, snz, omega = image_target_point(t, bx, by, bz, u, geo, sens, tgt)
        kind = tgt.kind[t]
        if g == NO_EVENT:
            continue
        jx, jy, jz, sx2 = reflect(px, py, pz, pl2, mir)                 # x' = x across P2
        if sx2 * sa2 <= 0.0:
            continue                                   # x and v' on opposite sides of P2
        kx, ky, kz, sx1 = reflect(jx, jy, jz, pl1, mir)                 # x'' = x' across P1
        if sx1 * sv1 <= 0.0:
            continue                                   # x' and v on opposite sides of P1
        f2 = sa2 / (sa2 + sx2)                         # r2: where the line v' → x' crosses P2
        r2x, r2y, r2z = ax + f2 * (jx - ax), ay + f2 * (jy - ay), az + f2 * (jz - az)
        f1 = sv1 / (sv1 + sx1)                         # r1: where the line v → x'' crosses P1
        r1x, r1y, r1z = vx + f1 * (kx - vx), vy + f1 * (ky - vy), vz + f1 * (kz - vz)
        if not (in_box(r1x, r1y, r1z, pl1, mir) and in_box(r2x, r2y, r2z, pl2, mir)):
            continue
        if kind != T_MESH2 and (px - r2x) * snx + (py - r2y) * sny + (pz - r2z) * snz >= 0.0:
            continue                                   # would reach the sensor (one-sided mesh) from behind
        L2, cos_v, side = leaving_towards(kx - vx, ky - vy, kz - vz, (nx, ny, nz), mode)
        if math.isnan(side):
            continue
        stats.nee_stats[stat0 + pl1, 0] += 1
        tri1, hx, hy, hz, tnx, tny, tnz, mm1 = mirror_ray((vx, vy, vz), vmag, (side * nx, side * ny, side * nz),
                                                          (kx, ky, kz), pl1, geo, photon, state, stats)
        if tri1 < 0 or not math.isinf(mat.phong[mm1]):
            continue
        hmag = max(magnitude(geo.verts[tri1]), abs(hx), abs(hy), abs(hz))
        tri2, h2x, h2y, h2z, t2x, t2y, t2z, mm2 = mirror_ray((hx, hy, hz), hmag + vmag, (tnx, tny, tnz),
                                                             (jx, jy, jz), pl2, geo, photon, state, stats)
        if tri2 < 0 or not math.isinf(mat.phong[mm2]):
            continue
        for b in range(n_bands):
            contrib[b] = (w[b] * leaving_pdf(v, cos_v, b, mat) * mat.prob[mm1, SPECULAR_R, b]
                          * mat.prob[mm2, SPECULAR_R, b] * scale / (p1 * p2)
                          * (omega if kind == T_DISC else tgt.area[t] / L2))
        n_out = last_leg((t, g, px, py, pz, snx, sny, snz), (tri2, h2x, h2y, h2z, t2x, t2y, t2z), hmag,
                         (stat0 + pl1, stat0 + pl2), geo, mat, tgt, photon, stats, n_out)
    return n_out


@helper
def image_counted(t, wx, wy, wz, pl, mir, tgt):
    """Is a crossing of target t counted on a segment that leaves mirror plane ``pl`` after a photon came
    from the next-event vertex w?  Only when w's image across the plane was too near t (as in
    :func:`image_event`)."""
    point, normal = mir.point, mir.normal
    sv = (wx - point[pl, 0]) * normal[pl, 0] + (wy - point[pl, 1]) * normal[pl, 1] \
        + (wz - point[pl, 2]) * normal[pl, 2]
    ix = wx - 2.0 * sv * normal[pl, 0]
    iy = wy - 2.0 * sv * normal[pl, 1]
    iz = wz - 2.0 * sv * normal[pl, 2]
    ex, ey, ez = ix - tgt.center[t, 0], iy - tgt.center[t, 1], iz - tgt.center[t, 2]
    return ex * ex + ey * ey + ez * ez < tgt.img_near2[t]


@helper
def double_image_counted(t, wx, wy, wz, pl1, pl2, mir, tgt):
    """Is a crossing of target t counted on a segment that leaves mirror plane ``pl2`` after a photon came from
    the next-event vertex w by way of ``pl1``?  Only when w's double image (across pl1, then pl2) was too near t
    (as in :func:`double_image_event`)."""
    ax, ay, az, _ = reflect(wx, wy, wz, pl1, mir)
    bx, by, bz, _ = reflect(ax, ay, az, pl2, mir)
    ex, ey, ez = bx - tgt.center[t, 0], by - tgt.center[t, 1], bz - tgt.center[t, 2]
    return ex * ex + ey * ey + ez * ez < tgt.img_near2[t]
