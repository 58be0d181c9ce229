"""Next events through a mirror: the light a target gets from a vertex after one perfect specular reflection.

The chamber's metal walls have a mirror part; the light a sensor or an organ gets by way of them is lost to
next events (a segment after a specular event is counted, not estimated), and counting it held over half
the leaves' variance on the rose.  The image method estimates it from every next-event vertex v instead:
a point x on a target and its image x' across a mirror plane P; the ray v → x' meets P where a photon
would reflect to x (:func:`image_event`).  A photon that does leave a vertex, reflect on P and cross the
target skips that crossing (:func:`image_counted`), so every path is counted once: unbiased.

Deposits in photons of weight, lengths in scene units, solid angles in steradians; the planes are
``kernel.records.Mirrors`` (``lpy_light.geometry.mirror_planes``).
"""
import math

from .jit import helper
from .nee import END_REL, INV_4PI, disc_point_by_solid_angle, mesh_point, sensor_point
from .rays import hit_on_plane, magnitude, seen_share, set_ray
from .records import ABSORB, SPECULAR_R, T_DISC, T_MESH2
from .rng import uniform
from .sampling import search_cdf
from .tallies import C_SHADOW


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
def image_event(v, n_draw, stat0, geo, mat, sens, tgt, mir, photon, stats):
    """Next events through one perfect mirror: the expected light that the segment leaving vertex ``v``
    (:class:`~kernel.records.Vertex`) brings to a target (transparent sensor or mesh) after one specular
    reflection on a mirror plane (the image method).

    For ``n_draw`` draws (a random whole number whose mean is ``mir.picks``, :func:`kernel.rng.n_draws`): a
    target t (uniform over the targets) and a mirror plane P (one of ``mir.plane``, drawn with probability p_k
    in proportion to :func:`plane_importance` at v, computed once for the draws); a point x on t (a disc's by solid angle as seen from
    v's image, a quad's or a mesh's by area), its image x' across P; the ray v → x' must first meet a
    triangle of P (after the coplanar pick, as a photon would), from a side whose material is a perfect
    mirror, and the leg from there to x must be free (for a mesh: the first surface met is the mesh, at x,
    :func:`kernel.rays.reaches`).  Deposit
    w · f_v(ω) · P_spec,b · A_t |cos θ_x| / |x' − v|² · n_targets / (p_k · picks)  (a mirror keeps solid angle),
    and on a mesh with an absorbed row that times the absorptance of the side met.  Sensors and one-sided
    meshes are met from their front only, two-sided meshes from either side.
    A vertex whose image across P lies within the target's exclusion radius (``tgt.img_near2``) makes no
    such event: the crossing is counted instead (:func:`image_counted`).  ``stats.nee_stats[stat0 + P]``
    counts rays cast, paths found, weight deposited.  Returns the number of deposits in ``photon.out_k`` /
    ``photon.out_w`` (at most two per draw).
    """
    vx, vy, vz, nx, ny, nz, mode, m, vscale, _vtri = v
    w, contrib, out_k, out_w = photon.w, photon.contrib, photon.out_k, photon.out_w
    state, scratch = photon.state, photon.scratch
    counters, nee_stats = stats.counters, stats.nee_stats
    tri_verts, offset_rel = geo.verts, geo.offset_rel
    picks = mir.picks
    n_bands = w.shape[0]
    n_tgt = tgt.kind.shape[0]
    n_mir = mir.plane.shape[0]
    if n_tgt == 0 or n_mir == 0 or n_draw <= 0 or not picks > 0.0:
        return 0
    plane_cdf = photon.plane_cdf
    total = 0.0
    for j in range(n_mir):
        total += plane_importance(vx, vy, vz, mir.plane[j], mir)
        plane_cdf[j] = total
    if not total > 0.0:
        return 0
    scale = n_tgt / picks
    vmag = max(abs(vx), abs(vy), abs(vz), vscale)
    n_out = 0
    for _ in range(n_draw):
        t = min(int(uniform(state) * n_tgt), n_tgt - 1)
        k = search_cdf(plane_cdf, 0, n_mir - 1, uniform(state) * total)     # a plane, by its importance at v
        p_k = (plane_cdf[k] - (plane_cdf[k - 1] if k > 0 else 0.0)) / total
        if not p_k > 0.0:
            continue
        pl = mir.plane[k]
        u1, u2, u3 = uniform(state), uniform(state), uniform(state)
        kind = tgt.kind[t]
        qx, qy, qz = mir.point[pl, 0], mir.point[pl, 1], mir.point[pl, 2]
        mx, my, mz = mir.normal[pl, 0], mir.normal[pl, 1], mir.normal[pl, 2]
        sv = (vx - qx) * mx + (vy - qy) * my + (vz - qz) * mz
        if sv == 0.0:
            continue
        ix, iy, iz = vx - 2.0 * sv * mx, vy - 2.0 * sv * my, vz - 2.0 * sv * mz      # v's image across P
        ex, ey, ez = ix - tgt.center[t, 0], iy - tgt.center[t, 1], iz - tgt.center[t, 2]
        if ex * ex + ey * ey + ez * ez < tgt.img_near2[t]:
            continue                                   # too close (unfolded): the crossing is counted
        g = -1                                         # a mesh target's triangle
        omega = 0.0
        if kind >= T_MESH2:
            g, px, py, pz = mesh_point(t, u1, u2, u3, tgt, geo)
            snx, sny, snz = geo.normal[g, 0], geo.normal[g, 1], geo.normal[g, 2]
        else:
            s = tgt.ref[t]
            snx, sny, snz = sens.normal[s, 0], sens.normal[s, 1], sens.normal[s, 2]
            if kind == T_DISC:                         # a disc: drawn by solid angle as seen from v's image
                px, py, pz, omega = disc_point_by_solid_angle(ix, iy, iz, s, u1, u2, sens)
                if omega == 0.0:
                    continue
            else:
                px, py, pz = sensor_point(kind, s, u1, u2, u3, sens)
        sx = (px - qx) * mx + (py - qy) * my + (pz - qz) * mz
        if sx * sv <= 0.0:
            continue                                   # x and v on opposite sides of P: no reflection joins them
        if mir.one_sided[pl] != 0 and sv < 0.0:
            continue                                   # behind a one-sided mirror
        # where the reflection would be, and the second leg's direction: reject without rays when they fail
        f = sv / (sv - (-sx))                          # fraction of the way from v to x' where P is crossed
        rx, ry, rz = vx + f * (px - 2.0 * sx * mx - vx), vy + f * (py - 2.0 * sx * my - vy), vz + f * (pz - 2.0 * sx * mz - vz)
        box = mir.box
        if not (box[pl, 0, 0] <= rx <= box[pl, 1, 0] and box[pl, 0, 1] <= ry <= box[pl, 1, 1]
                and box[pl, 0, 2] <= rz <= box[pl, 1, 2]):
            continue                                   # misses the mirror's bounds
        if kind != T_MESH2 and (px - rx) * snx + (py - ry) * sny + (pz - rz) * snz >= 0.0:
            continue                                   # would reach the sensor (one-sided mesh) from behind
        # first leg: v towards x' (x's image), unfolded length L
        jx, jy, jz = px - 2.0 * sx * mx, py - 2.0 * sx * my, pz - 2.0 * sx * mz
        dx, dy, dz = jx - vx, jy - vy, jz - vz
        L2 = dx * dx + dy * dy + dz * dz
        if not L2 > 0.0:
            continue
        L = math.sqrt(L2)
        dx, dy, dz = dx / L, dy / L, dz / L
        cos_v = dx * nx + dy * ny + dz * nz
        if mode == 1 and cos_v <= 0.0:                 # V_LAMBERT: emits into its front only
            continue
        side = 0.0 if mode == 0 else (1.0 if cos_v > 0.0 else -1.0)
        eps = offset_rel * vmag
        set_ray(scratch, vx + side * eps * nx, vy + side * eps * ny, vz + side * eps * nz, dx, dy, dz, L)
        counters[C_SHADOW] += 1
        nee_stats[stat0 + pl, 0] += 1
        tri, hx, hy, hz, tnx, tny, tnz, mm = hit_on_plane(geo, scratch, geo.mirror_plane, pl, dx, dy, dz, state)
        if tri < 0:
            continue                                   # something else first: no path through P here
        if not math.isinf(mat.phong[mm]):
            continue                                   # only perfect mirrors (the planes are built so)
        # second leg: from the mirror point to x, which must be crossed from the sensor's front
        fx, fy, fz = px - hx, py - hy, pz - hz
        d2 = math.sqrt(fx * fx + fy * fy + fz * fz)
        if not d2 > 0.0:
            continue
        fx, fy, fz = fx / d2, fy / d2, fz / d2
        cos_x = fx * snx + fy * sny + fz * snz
        if kind != T_MESH2 and cos_x >= 0.0:
            continue
        any_light = False
        for b in range(n_bands):
            f = mat.prob[mm, SPECULAR_R, b]            # of the mirror's side
            if mode == 0:
                f *= INV_4PI
            elif mode == 1:
                f *= cos_v / math.pi
            else:
                f *= mat.prob[m, 0 if cos_v > 0.0 else 2, b] * abs(cos_v) / math.pi
            contrib[b] = w[b] * f * scale / p_k * (omega if kind == T_DISC else tgt.area[t] * abs(cos_x) / L2)
            any_light = any_light or contrib[b] > 0.0
        if not any_light:
            continue
        hmag = max(magnitude(tri_verts[tri]), abs(hx), abs(hy), abs(hz))
        pmag = max(abs(px), abs(py), abs(pz))
        if g >= 0:                                     # a mesh target is a surface: its triangle's round-off
            pmag = max(pmag, magnitude(tri_verts[g]))
        eps2 = offset_rel * (hmag + vmag)
        tol = offset_rel * (hmag + pmag) * 2.0
        if g >= 0:                                     # its float32 plane's error (as in next_event)
            tol += END_REL * d2
        if d2 - tol <= 0.0:
            continue
        counters[C_SHADOW] += 1
        ox, oy, oz = hx + eps2 * tnx, hy + eps2 * tny, hz + eps2 * tnz
        share = seen_share(g, geo, scratch, (ox, oy, oz), (fx, fy, fz), d2 - tol, d2 + tol, tgt.ref[t], (px, py, pz))
        if share == 0.0:
            continue
        for b in range(n_bands):
            contrib[b] *= share
        nee_stats[stat0 + pl, 1] += 1
        out_k[n_out] = tgt.row[t]
        for b in range(n_bands):
            out_w[n_out, b] = contrib[b]
            nee_stats[stat0 + pl, 2] += contrib[b]
        n_out += 1
        if g >= 0 and tgt.abs_row[t] >= 0:             # what the side met absorbs
            ma = geo.material[g, 0] if cos_x < 0.0 else geo.material[g, 1]
            out_k[n_out] = tgt.abs_row[t]
            for b in range(n_bands):
                out_w[n_out, b] = contrib[b] * mat.prob[ma, ABSORB, b]
            n_out += 1
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
