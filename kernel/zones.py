"""Zone events: two-step next events through the surface beside a disc.

A disc a few millimetres from a wall gets much of its light from the few centimetres of wall next to it,
i.e. from the rare photon vertices that land there, each making a large own next event: most of such a
disc's variance (the 24 discs 10 mm from Angers' metal wall held half of the summed variance).  The zones
are those patches (:func:`near_zones`, numpy, once per scene); from every next-event vertex a point of a
random zone is drawn and the light it would pass on to its disc estimated (:func:`zone_event`), and a
photon that does land in a zone straight from a next-event vertex skips that own event
(:func:`kernel.nee.next_event`, ``cover_pid``): every path counted once, unbiased.

Deposits in photons of weight, lengths in scene units, solid angles in steradians.
"""
import math

import numpy as np

from .jit import helper
from .nee import ZONE_HEIGHT, disc_point_by_solid_angle, view_factors
from .rays import hit_on_plane, magnitude, set_ray, visible
from .records import V_ISOTROPIC, V_LAMBERT, V_SURFACE, Zones
from .rng import uniform
from .tallies import C_SHADOW
from .vectors import dot, norm


def near_zones(tri_verts, tri_pid, n_chamber, near_start, near_list, near_r2, center, disc_radius, normal):
    """The zones of surface beside each disc target that a two-step next event serves (:func:`zone_event`).

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
    next-event vertex then skips that own event (:func:`kernel.nee.next_event`, ``cover_pid``).

    ``tri_verts`` (T, 3, 3); ``tri_pid`` (T,) plane ids (:func:`lpy_light.chamber.geometry.plane_ids`); only the
    first ``n_chamber`` triangles (the chamber, not organs) make zones; ``near_*`` from
    :func:`kernel.targets.near_discs`;
    ``center`` (n, 3), ``disc_radius`` (n,) (0: not a disc) and unit ``normal`` (n, 3) of the targets.
    Returns :class:`~kernel.records.Zones` (``picks`` 0: the caller's to set): ``frame`` (Z, 14) float64
    (c' (3), unit plane normal (3), e1 (3), e2 (3), h_s², L = ln(1 + ρ²/h_s²)), ``target_plane`` (Z, 2) int64
    (target, plane id), ``start`` (n + 1,) int64 (zones of target t: ``start[t] : start[t + 1]``, sorted by
    target).
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
        m = m / norm(m)
        h = dot(center[t] - v[0], m)
        rho2 = near_r2[t] - h * h
        if not (rho2 > 0.0 and abs(h) < ZONE_HEIGHT * disc_radius[t]):
            continue
        foot = center[t] - h * m
        lean = normal[t] - dot(normal[t], m) * m           # the disc's normal along the plane
        if dot(foot - center[t], normal[t]) + math.sqrt(rho2) * norm(lean) <= 0.0:
            continue                                           # the zone is all behind the disc
        e1 = np.cross(m, [1.0, 0.0, 0.0] if abs(m[0]) < 0.9 else [0.0, 1.0, 0.0])
        e1 /= norm(e1)
        e2 = np.cross(m, e1)
        hs2 = max(h * h, disc_radius[t] ** 2)
        rows_f.append(np.concatenate([foot, m, e1, e2, [hs2, math.log1p(rho2 / hs2)]]))
        rows_i.append([t, pid])
    zone_f = np.ascontiguousarray(np.reshape(rows_f, (-1, 14)), dtype=np.float64)
    zone_i = np.ascontiguousarray(np.reshape(rows_i, (-1, 2)), dtype=np.int64)
    zone_start = np.zeros(n + 1, np.int64)
    if len(zone_i):
        np.cumsum(np.bincount(zone_i[:, 0], minlength=n), out=zone_start[1:])
    return Zones(0.0, zone_f, zone_i, zone_start)


@helper
def zone_event(v, n_draw, geo, mat, sens, tgt, zones, photon, stats):
    """Two-step next events: the light that the segment leaving vertex ``v`` (:class:`~kernel.records.Vertex`)
    brings to a disc *through one diffuse vertex y in the zone of surface beside the disc* (:func:`near_zones`).

    For ``n_draw`` draws (mean ``zones.picks``): a zone z (uniform over the Z zones) of disc target t on
    plane P; a point y on P about the disc's foot c' at r with density p_A(y) = 1 / (π L (r² + h_s²)); the
    ray v → y must first meet a triangle of P there (after the coplanar pick, as a photon would), inside
    t's near sphere, whose side facing v is a material with next events; then from y a point x on the disc
    by solid angle (:func:`kernel.nee.disc_point_by_solid_angle`, factor Ω̂) and a free leg y → x.  Deposit

        w · f_v(ω_vy) · |cos θ_y| / |y − v|² / p_A(y) · P_ev,b(m_y) · |cos θ'_y| / π · Ω̂ · Z / zone_picks,

    f_v as in :func:`kernel.nee.next_event`, ev the diffuse event of y's side towards x: the expected own
    next event that a photon leaving v diffusely would make at y, which a photon that does land there
    then skips.  Returns the number of deposits written to ``photon.out_k`` / ``photon.out_w``.
    """
    vx, vy, vz, nx, ny, nz, mode, m, vscale, _vtri = v
    w, contrib, out_k, out_w = photon.w, photon.contrib, photon.out_k, photon.out_w
    state, scratch = photon.state, photon.scratch
    counters = stats.counters
    zone_f, zone_i = zones.frame, zones.target_plane
    offset_rel = geo.offset_rel
    n_bands = w.shape[0]
    n_zone = zone_i.shape[0]
    if n_zone == 0 or n_draw <= 0 or not zones.picks > 0.0:
        return 0
    c0, c1 = view_factors(mode)
    scale = n_zone / zones.picks
    vmag = max(abs(vx), abs(vy), abs(vz), vscale)
    n_out = 0
    for _ in range(n_draw):
        z = min(int(uniform(state) * n_zone), n_zone - 1)
        u1, u2, u3, u4 = uniform(state), uniform(state), uniform(state), uniform(state)
        t, pid = zone_i[z, 0], zone_i[z, 1]
        s = tgt.ref[t]
        hs2, big_l = zone_f[z, 12], zone_f[z, 13]
        r2 = hs2 * math.expm1(u1 * big_l)
        r = math.sqrt(r2)
        ca, sa = r * math.cos(2.0 * math.pi * u2), r * math.sin(2.0 * math.pi * u2)
        yx = zone_f[z, 0] + ca * zone_f[z, 6] + sa * zone_f[z, 9]
        yy = zone_f[z, 1] + ca * zone_f[z, 7] + sa * zone_f[z, 10]
        yz = zone_f[z, 2] + ca * zone_f[z, 8] + sa * zone_f[z, 11]
        inv_pa = math.pi * big_l * (r2 + hs2)
        dx, dy, dz = yx - vx, yy - vy, yz - vz
        dist = math.sqrt(dx * dx + dy * dy + dz * dz)
        if not dist > 0.0:
            continue
        dx, dy, dz = dx / dist, dy / dist, dz / dist
        cos_v = dx * nx + dy * ny + dz * nz
        if mode == V_LAMBERT and cos_v <= 0.0:
            continue
        side = 0.0 if mode == V_ISOTROPIC else (1.0 if cos_v > 0.0 else -1.0)
        eps = offset_rel * vmag
        # the first leg: what a photon leaving v towards y meets first (past y by a little: Embree's float32)
        set_ray(scratch, vx + side * eps * nx, vy + side * eps * ny, vz + side * eps * nz, dx, dy, dz,
                dist * (1.0 + 2.0 ** -10) + 4.0 * eps)
        counters[C_SHADOW] += 1
        tri, hx, hy, hz, tnx, tny, tnz, m_y = hit_on_plane(geo, scratch, geo.plane_id, pid, dx, dy, dz, state)
        if tri < 0:
            continue                                   # something else first: no such vertex y
        ex, ey, ez = hx - tgt.center[t, 0], hy - tgt.center[t, 1], hz - tgt.center[t, 2]
        if not ex * ex + ey * ey + ez * ez < tgt.near_r2[t]:
            continue                                   # outside the zone (a photon there makes a pick instead)
        if tgt.from_material[m_y] == 0:
            continue                                   # no next events from y's material: its crossings count
        cos_in = -(dx * tnx + dy * tny + dz * tnz)
        gx, gy, gz = hx - vx, hy - vy, hz - vz
        arrive = cos_in / (gx * gx + gy * gy + gz * gz) * inv_pa * scale     # vertex density at y / p_A(y)
        # the second leg: y's own next event towards disc t
        px, py, pz, omega = disc_point_by_solid_angle(hx, hy, hz, s, u3, u4, sens)
        if omega == 0.0:
            continue
        fx, fy, fz = px - hx, py - hy, pz - hz
        d2 = math.sqrt(fx * fx + fy * fy + fz * fz)
        if not d2 > 0.0:
            continue
        fx, fy, fz = fx / d2, fy / d2, fz / d2
        if fx * sens.normal[s, 0] + fy * sens.normal[s, 1] + fz * sens.normal[s, 2] >= 0.0:
            continue
        cos_y = fx * tnx + fy * tny + fz * tnz
        ev = 0 if cos_y > 0.0 else 2                   # DIFFUSE_R towards y's side of arrival, else DIFFUSE_T
        any_light = False
        for b in range(n_bands):
            fv = c0 + c1 * abs(cos_v)
            if mode == V_SURFACE:
                fv *= mat.prob[m, 0 if cos_v > 0.0 else 2, b]
            contrib[b] = w[b] * fv * arrive * mat.prob[m_y, ev, b] * abs(cos_y) / math.pi * omega
            any_light = any_light or contrib[b] > 0.0
        if not any_light:
            continue
        hmag = max(magnitude(geo.verts[tri]), abs(hx), abs(hy), abs(hz))
        pmag = max(abs(px), abs(py), abs(pz))
        sy = 1.0 if cos_y > 0.0 else -1.0
        eps2 = offset_rel * (hmag + vmag)
        tfar = d2 - offset_rel * (hmag + pmag) * 2.0
        if tfar <= 0.0:
            continue
        counters[C_SHADOW] += 1
        if not visible(geo, scratch, hx + sy * eps2 * tnx, hy + sy * eps2 * tny,
                       hz + sy * eps2 * tnz, fx, fy, fz, tfar):
            continue
        out_k[n_out] = tgt.row[t]
        for b in range(n_bands):
            out_w[n_out, b] = contrib[b]
        n_out += 1
    return n_out
