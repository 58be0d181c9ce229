"""The hot loop: trace a chunk of photons from the lamps until absorbed, escaped or cut.

One call traces photons ``first .. first + count - 1`` of a run.  Everything the
loop needs arrives as flat arrays (see :func:`trace_chunk`); everything it finds
is *added* to the output arrays, so a caller can reduce chunks in a fixed order
and get the same sums on any number of threads.

Physics (SEC2's model, see ``docs/physics.md``):

* at a surface hit one event is drawn: diffuse reflection, specular reflection,
  diffuse transmission, specular transmission or absorption;
* all spectral bands travel together: the event e is drawn with a probability
  q_e shared by the bands and each band's weight is multiplied by P_e,b / q_e,
  which is unbiased for every band.  Two estimators choose q (see
  :func:`lpy_light.materials.sampling_tables`):

  - ``analog`` (SEC2's counting): q_e = band mean of P_e,b over the five events,
    absorption deposits the photon's weight where it ends — exactly analog for
    one band;
  - ``weighted`` (default): at every hit the expected absorbed weight
    w_b·P_abs,b is deposited; then a scattering event is drawn with
    q_e = max_b P_e,b (the photon ends with the remaining probability), so no
    band's weight ever grows — bands as different as a 20% and an 80% wall
    stay as precise as their own analog runs;
* where surfaces coincide (same plane, overlapping), a hit picks one of those
  containing the point and facing the ray, uniformly at random, rather than
  whichever Embree's float32 arithmetic happens to find (``coplanar="random"``);
* transparent sensors record each crossing from their front side at the
  photon's current weight; receivers (solid sensors, organs) record each hit
  (incident) and the weight absorbed on them.

Tallies are per photon first, then multiplied band by band, so ``tally_prod``
gives the sample covariance between bands of per-photon contributions (a photon
may cross a sensor twice; all bands ride on the same photons, so a sum of bands
such as PAR, or a ratio such as R:FR, needs the covariances for its σ).  The
photon's fates (absorbed per material, escaped, cut, lost) are tallied the same
way, in rows after the sensors, and a last row holds each photon's total
deposit, whose mean is 1 per band: energy closure with its own standard error.
"""
import math

import numpy as np
from numba import njit

from .embree import (ARGS, CAND, CAND_CAP, CAND_COUNT, DIR, GEOM_ID, HIT_U, HIT_V, INVALID_ID, MASK, NG, ORG,
                     PRIM_ID, RAYHIT, TFAR, TNEAR)
from .ptr import call_ptr3, load_f32, load_i64, load_u32, store_f32, store_i64, store_u32
from .rng import seed_stream, uniform
from .nee import (_ZERO32, _competes, _gamma32, END_REL, INV_4PI, NEAR_FLOOR, T_DISC, T_MESH2, V_ISOTROPIC,
                  V_LAMBERT, V_SURFACE, disc_point_by_solid_angle, mesh_point, next_event, seen_share,
                  sensor_point, set_ray, view_factors, visible)
from .sampling import cosine_hemisphere, mirror, phong_lobe, search_cdf, to_world, uniform_sphere

# scattering events, in the order their probabilities are accumulated
DIFFUSE_R, SPECULAR_R, DIFFUSE_T, SPECULAR_T, ABSORB = 0, 1, 2, 3, 4
N_EVENTS = 5

# emitter element kinds
EMIT_LINE, EMIT_TRIANGLE, EMIT_CYLINDER, EMIT_POINT, EMIT_SPHERE = 0, 1, 2, 3, 4

# sensor kinds
SENSOR_DISC, SENSOR_QUAD = 0, 1

# counters
C_RAYS, C_CAND_OVERFLOW, C_SCRATCH_FLUSH, C_LOST, C_SHADOW, C_BATCHES = 0, 1, 2, 3, 4, 5
N_COUNTERS = 6


_TFAR_MAX = 3.0e38


@njit(inline="always", cache=True)
def _record(k, w, acc, touched, rows, n_rows):
    """Add weights ``w`` (B,) to this photon's row k; returns the number of rows the photon has touched."""
    if touched[k] == 0:
        touched[k] = 1
        rows[n_rows] = k
        n_rows += 1
    for b in range(w.shape[0]):     # explicit loops: slice assignment costs ~15% at 12 bands
        acc[k, b] += w[b]
    return n_rows


@njit(inline="always", cache=True)
def _flush(n_rows, rows, touched, acc, tally, tally_sq, fate0, tot):
    """Add one photon's contributions (its rows of ``acc``, in the order first touched): sums and products
    between bands; clear them for the next photon.

    Rows ``fate0 ..`` are fates; the last row receives the photon's total deposit (closure), summed in
    ``tot`` (B,) scratch."""
    total_row = tally.shape[0] - 1
    n_bands = acc.shape[1]
    tot[:] = 0.0
    for a in range(n_rows):
        k = rows[a]
        if k < 0:
            continue
        for b in range(n_bands):
            x = acc[k, b]
            tally[k, b] += x
            for b2 in range(n_bands):
                tally_sq[k, b, b2] += x * acc[k, b2]
            if k >= fate0:
                tot[b] += x
        for b in range(n_bands):
            acc[k, b] = 0.0
        touched[k] = 0
    if n_rows > 0:
        for b in range(n_bands):
            tally[total_row, b] += tot[b]
            for b2 in range(n_bands):
                tally_sq[total_row, b, b2] += tot[b] * tot[b2]


@njit(cache=True, _nrt=False)
def _control_deposits(vx, vy, vz, nx, ny, nz, mode, m, w, near, cv_center, cv_normal, cv_area, cv_thr, cv_runs,
                      cv_plane, mat_prob, g_r, g_t, cv_acc):
    """Add γ (:func:`kernel.nee.point_view`) of every sensor target, seen from v, to its batch's ``cv_acc``
    (B, n) -- except where a pick of :func:`kernel.nee.next_event` would not serve it (inside an exclusion
    radius, or a near disc with an event of its own: ``cv_thr[near]`` (2, n) holds those radii²).

    Targets come in runs of one plane and normal (``cv_runs`` (r, 3): first, end, run's plane offset
    n·c); a run whose plane v is behind is skipped whole (γ = 0 there).  Within a run the loop is
    branch-free so that it vectorises: γ split by the side of v it leaves (``g_r``, ``g_t`` (n,)
    scratch), then one pass per band."""
    c0, c1 = view_factors(mode)
    c0, c1 = np.float32(c0), np.float32(c1)
    thr = cv_thr[near]
    cx, cy, cz = cv_center[0], cv_center[1], cv_center[2]
    mx, my, mz = cv_normal[0], cv_normal[1], cv_normal[2]
    vx, vy, vz = np.float32(vx), np.float32(vy), np.float32(vz)
    nx, ny, nz = np.float32(nx), np.float32(ny), np.float32(nz)
    for r in range(cv_runs.shape[0]):
        lo, n = cv_runs[r, 0], cv_runs[r, 1] - cv_runs[r, 0]
        if lo < 0 or vx * mx[lo] + vy * my[lo] + vz * mz[lo] <= cv_plane[r]:
            continue
        for i in range(n):          # (indices from 0: no wrap-around test, so the loop vectorises)
            t = lo + i
            g = _gamma32(vx, vy, vz, nx, ny, nz, c0, c1, cx[t], cy[t], cz[t], mx[t], my[t], mz[t], cv_area[t])
            ex, ey, ez = cx[t] - vx, cy[t] - vy, cz[t] - vz
            ok = (ex * ex + ey * ey + ez * ez >= thr[t]) & (g > _ZERO32)
            g = g * np.float32(ok)     # arithmetic, not branches: vectorises
            up = np.float32(ex * nx + ey * ny + ez * nz > _ZERO32)
            g_r[t] = g * up
            g_t[t] = g - g * up
        for b in range(w.shape[0]):
            if mode == V_SURFACE:
                a_r, a_t = w[b] * mat_prob[m, DIFFUSE_R, b], w[b] * mat_prob[m, DIFFUSE_T, b]
            elif mode == V_LAMBERT:
                a_r, a_t = w[b], 0.0
            else:
                a_r, a_t = w[b], w[b]
            acc = cv_acc[b]
            for i in range(n):
                t = lo + i
                acc[t] += a_r * g_r[t] + a_t * g_t[t]


@njit(cache=True, _nrt=False)
def _fold_control(n_rows, rows, touched, acc, cv_acc, sensor_target, n_sens):
    """End of a photon, with the control variate on: fold its other deposits on the sensor targets' rows
    into its batch's ``cv_acc`` (B, n), so that the batch's products are taken whole by
    :func:`_control_products`; the photon's other rows are left to :func:`_flush` (those folded become -1
    in ``rows``)."""
    n_bands = acc.shape[1]
    n = cv_acc.shape[1]
    for a in range(n_rows):
        k = rows[a]
        if k < n_sens and sensor_target[k] >= 0 and sensor_target[k] < n:
            t = sensor_target[k]
            for b in range(n_bands):
                cv_acc[b, t] += acc[k, b]
                acc[k, b] = 0.0
            touched[k] = 0
            rows[a] = -1


@njit(cache=True, _nrt=False)
def _control_products(cv_acc, size, cv_tally, cv_sq):
    """Add one batch of ``size`` photons -- their summed sensor-target deposits ``cv_acc`` (B, n) -- to the
    chunk's ``cv_tally`` (B, n) and ``cv_sq`` (B, B, n): S_b · S_b2 / size, upper triangle b ≤ b2 (the
    caller mirrors it); clear ``cv_acc``.

    Batch means: with the control variate every photon deposits on all n sensor rows, and products
    between bands per photon (B(B+1)/2 · n of them) cost as much as the rest of a 12-band photon.  Summed
    over batches instead, Q = Σ_j S_j S_jᵀ / m_j satisfies E[Q − T Tᵀ / N] = (n_b − 1) Σ (Σ the covariance
    of one photon, T the total of N photons in n_b batches of m_j photons), so ``Result`` estimates
    the covariance of T as N / (n_b − 1) · (Q − T Tᵀ / N): the per-photon formula with n_b − 1 in place
    of N − 1 (:func:`lpy_light.simulate.effective_samples`)."""
    n_bands, n = cv_acc.shape[0], cv_acc.shape[1]
    inv = 1.0 / size
    for b in range(n_bands):         # contiguous over the targets: vectorises
        x = cv_acc[b]
        tb = cv_tally[b]
        for t in range(n):
            tb[t] += x[t]
        for b2 in range(b, n_bands):
            y = cv_acc[b2]
            sq = cv_sq[b, b2]
            for t in range(n):
                sq[t] += x[t] * y[t] * inv
    for b in range(n_bands):
        x = cv_acc[b]
        for t in range(n):
            x[t] = 0.0


@njit(inline="always", cache=True)
def _inside(s, px, py, pz, kind, center, radius, corners, normal):
    """Is the point p (on the sensor's plane) inside sensor s?  Exact for discs and quads."""
    if kind[s] == SENSOR_DISC:
        ex, ey, ez = px - center[s, 0], py - center[s, 1], pz - center[s, 2]
        return ex * ex + ey * ey + ez * ez <= radius[s] * radius[s]
    # convex quad: p must lie left of every edge, seen along the normal
    for i in range(4):
        j = (i + 1) % 4
        ax, ay, az = corners[s, j, 0] - corners[s, i, 0], corners[s, j, 1] - corners[s, i, 1], corners[s, j, 2] - corners[s, i, 2]
        bx, by, bz = px - corners[s, i, 0], py - corners[s, i, 1], pz - corners[s, i, 2]
        cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
        if cx * normal[s, 0] + cy * normal[s, 1] + cz * normal[s, 2] < 0.0:
            return False
    return True


@njit(inline="always", cache=True)
def _counted(skip, t, x, y, z, tgt_center, tgt_near2):
    """Is a crossing of target t counted on a segment that starts at vertex (x, y, z)?

    Always when the segment is not covered by next events (``skip`` False),
    else only when the vertex was too near target t for a next event."""
    if not skip or t < 0:
        return True
    ex, ey, ez = x - tgt_center[t, 0], y - tgt_center[t, 1], z - tgt_center[t, 2]
    return ex * ex + ey * ey + ez * ez < tgt_near2[t]


@njit(inline="always", cache=True)
def _pick_coplanar(tri, px, py, pz, dx, dy, dz, cop_start, cop_list, cop_box, cop_free, tri_verts, tri_normal,
                   tri_two_sided, state):
    """One of ``tri`` and its coplanar candidates that contain p and face the ray, uniformly at random
    (reservoir sampling: one random number per competing candidate, none where there is none)."""
    if (cop_free[tri, 0, 0] < px < cop_free[tri, 1, 0] and cop_free[tri, 0, 1] < py < cop_free[tri, 1, 1]
            and cop_free[tri, 0, 2] < pz < cop_free[tri, 1, 2]):
        return tri                                  # where no partner reaches
    chosen = tri
    n_in = 1
    for a in range(cop_start[tri], cop_start[tri + 1]):
        j = cop_list[a]
        if _competes(j, px, py, pz, dx, dy, dz, cop_box, tri_verts, tri_normal, tri_two_sided):
            n_in += 1
            if uniform(state) * n_in < 1.0:
                chosen = j
    return chosen


@njit(inline="always", cache=True)
def _hit_on_plane(scene, intersect_fn, rh, args, plane_of, plane, dx, dy, dz, geom_offset, tri_verts, tri_normal,
                  tri_mat, tri_two_sided, cop_start, cop_list, cop_box, cop_free, state):
    """Trace the ray already set in ``rh`` (direction d); if what a photon would meet first (a coplanar tie
    picked at random, as at a photon's hit) lies on plane ``plane`` of ``plane_of`` (T,), return
    (triangle, hit point, its normal turned towards the ray's origin, the material of that side);
    triangle -1 otherwise."""
    call_ptr3(intersect_fn, scene, rh, args)
    gid = load_u32(rh + GEOM_ID)
    if gid == INVALID_ID:
        return -1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0
    tri = load_u32(rh + PRIM_ID) + geom_offset[gid]
    if plane_of[tri] != plane and cop_start[tri + 1] == cop_start[tri]:
        return -1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0
    bu, bv = load_f32(rh + HIT_U), load_f32(rh + HIT_V)
    b0 = 1.0 - bu - bv
    hx = b0 * tri_verts[tri, 0, 0] + bu * tri_verts[tri, 1, 0] + bv * tri_verts[tri, 2, 0]
    hy = b0 * tri_verts[tri, 0, 1] + bu * tri_verts[tri, 1, 1] + bv * tri_verts[tri, 2, 1]
    hz = b0 * tri_verts[tri, 0, 2] + bu * tri_verts[tri, 1, 2] + bv * tri_verts[tri, 2, 2]
    if cop_start[tri + 1] > cop_start[tri]:
        tri = _pick_coplanar(tri, hx, hy, hz, dx, dy, dz, cop_start, cop_list, cop_box, cop_free,
                             tri_verts, tri_normal, tri_two_sided, state)
    if plane_of[tri] != plane:
        return -1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0    # something else first
    tnx, tny, tnz = tri_normal[tri, 0], tri_normal[tri, 1], tri_normal[tri, 2]
    if dx * tnx + dy * tny + dz * tnz > 0.0:
        return tri, hx, hy, hz, -tnx, -tny, -tnz, tri_mat[tri, 1]
    return tri, hx, hy, hz, tnx, tny, tnz, tri_mat[tri, 0]


@njit(cache=True, _nrt=False)
def _image_event(vx, vy, vz, nx, ny, nz, mode, m, w, state, scene, intersect_fn, occluded_fn, scratch, offset_rel,
                 vscale, tgt_kind, tgt_row, tgt_abs_row, tgt_ref, tgt_first, tgt_count, nee_tri, nee_cdf, tgt_area,
                 tgt_center, tgt_near2, tri_receiver, sens_center, sens_normal,
                 sens_radius, sens_corners, geom_offset, tri_verts, tri_normal, tri_mat, tri_two_sided, mat_prob,
                 mat_phong, cop_start, cop_list, cop_box, cop_free, tri_plane, mir_point, mir_normal, mir_list,
                 mir_cdf, mir_inv_p, mir_box, mir_one_sided, n_draw, picks, contrib, out_k, out_w, counters,
                 nee_stats, stat0):
    """Next events through one perfect mirror: the expected light that the segment leaving v brings to a
    target (transparent sensor or mesh) after one specular reflection on a mirror plane (the image method).

    For ``n_draw`` draws (a random whole number whose mean is ``picks``, see :func:`_n_images`): a target t
    (uniform over the targets) and a mirror plane P (``mir_list[k]``, k drawn from the cumulative ``mir_cdf``;
    its weight ``mir_inv_p[k]`` = 1 / p_k); a point x on t (a disc's by solid angle as seen from v's image, a
    quad's or a mesh's by area), its image x' across P; the ray v → x' must first meet a triangle of P (after
    the coplanar pick, as a photon would), from a side whose material is a perfect mirror, and the leg from
    there to x must be free (for a mesh: the first surface met is the mesh, at x, :func:`kernel.nee.reaches`).  Deposit
    w · f_v(ω) · P_spec,b · A_t |cos θ_x| / |x' − v|² · n_targets / (p_k · picks)  (a mirror keeps solid angle),
    and on a mesh with an absorbed row that times the absorptance of the side met.  Sensors and one-sided
    meshes are met from their front only, two-sided meshes from either side.
    A vertex whose image across P lies within the target's exclusion radius makes no such event: the
    crossing is counted instead (:func:`trace_chunk` applies the same test).  ``nee_stats[stat0 + P]``
    counts rays cast, paths found, weight deposited.  Returns the number of deposits in ``out_k``/``out_w``
    (at most two per draw).
    """
    n_bands = w.shape[0]
    n_tgt = tgt_kind.shape[0]
    n_mir = mir_list.shape[0]
    if n_tgt == 0 or n_mir == 0 or n_draw <= 0 or not picks > 0.0:
        return 0
    scale = n_tgt / picks
    vmag = max(abs(vx), abs(vy), abs(vz), vscale)
    rh = scratch + RAYHIT
    args = scratch + ARGS
    n_out = 0
    for _ in range(n_draw):
        t = min(int(uniform(state) * n_tgt), n_tgt - 1)
        k = search_cdf(mir_cdf, 0, mir_cdf.shape[0] - 1, uniform(state))     # a plane, by the pilot's weights (or uniformly)
        pl = mir_list[k]
        u1, u2, u3 = uniform(state), uniform(state), uniform(state)
        kind = tgt_kind[t]
        qx, qy, qz = mir_point[pl, 0], mir_point[pl, 1], mir_point[pl, 2]
        mx, my, mz = mir_normal[pl, 0], mir_normal[pl, 1], mir_normal[pl, 2]
        sv = (vx - qx) * mx + (vy - qy) * my + (vz - qz) * mz
        if sv == 0.0:
            continue
        ix, iy, iz = vx - 2.0 * sv * mx, vy - 2.0 * sv * my, vz - 2.0 * sv * mz      # v's image across P
        ex, ey, ez = ix - tgt_center[t, 0], iy - tgt_center[t, 1], iz - tgt_center[t, 2]
        if ex * ex + ey * ey + ez * ez < tgt_near2[t]:
            continue                                   # too close (unfolded): the crossing is counted
        g = -1                                         # a mesh target's triangle
        omega = 0.0
        if kind >= T_MESH2:
            g, px, py, pz = mesh_point(t, u1, u2, u3, tgt_first, tgt_count, nee_tri, nee_cdf, tri_verts)
            snx, sny, snz = tri_normal[g, 0], tri_normal[g, 1], tri_normal[g, 2]
        else:
            s = tgt_ref[t]
            snx, sny, snz = sens_normal[s, 0], sens_normal[s, 1], sens_normal[s, 2]
            if kind == T_DISC:                         # a disc: drawn by solid angle as seen from v's image
                px, py, pz, omega = disc_point_by_solid_angle(ix, iy, iz, s, u1, u2, sens_center, sens_normal,
                                                              sens_radius)
                if omega == 0.0:
                    continue
            else:
                px, py, pz = sensor_point(kind, s, u1, u2, u3, sens_center, sens_normal, sens_radius, sens_corners)
        sx = (px - qx) * mx + (py - qy) * my + (pz - qz) * mz
        if sx * sv <= 0.0:
            continue                                   # x and v on opposite sides of P: no reflection joins them
        if mir_one_sided[pl] != 0 and sv < 0.0:
            continue                                   # behind a one-sided mirror
        # where the reflection would be, and the second leg's direction: reject without rays when they fail
        f = sv / (sv - (-sx))                          # fraction of the way from v to x' where P is crossed
        rx, ry, rz = vx + f * (px - 2.0 * sx * mx - vx), vy + f * (py - 2.0 * sx * my - vy), vz + f * (pz - 2.0 * sx * mz - vz)
        if not (mir_box[pl, 0, 0] <= rx <= mir_box[pl, 1, 0] and mir_box[pl, 0, 1] <= ry <= mir_box[pl, 1, 1]
                and mir_box[pl, 0, 2] <= rz <= mir_box[pl, 1, 2]):
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
        counters[4] += 1
        nee_stats[stat0 + pl, 0] += 1
        tri, hx, hy, hz, tnx, tny, tnz, mm = _hit_on_plane(scene, intersect_fn, rh, args, tri_plane, pl, dx, dy, dz,
                                                           geom_offset, tri_verts, tri_normal, tri_mat, tri_two_sided,
                                                           cop_start, cop_list, cop_box, cop_free, state)
        if tri < 0:
            continue                                   # something else first: no path through P here
        if not math.isinf(mat_phong[mm]):
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
            f = mat_prob[mm, 1, b]                     # SPECULAR_R of the mirror's side
            if mode == 0:
                f *= INV_4PI
            elif mode == 1:
                f *= cos_v / math.pi
            else:
                f *= mat_prob[m, 0 if cos_v > 0.0 else 2, b] * abs(cos_v) / math.pi
            contrib[b] = w[b] * f * scale * mir_inv_p[k] * (omega if kind == T_DISC else tgt_area[t] * abs(cos_x) / L2)
            any_light = any_light or contrib[b] > 0.0
        if not any_light:
            continue
        hmag = max(_magnitude(tri_verts[tri]), abs(hx), abs(hy), abs(hz))
        pmag = max(abs(px), abs(py), abs(pz))
        if g >= 0:                                     # a mesh target is a surface: its triangle's round-off
            pmag = max(pmag, _magnitude(tri_verts[g]))
        eps2 = offset_rel * (hmag + vmag)
        tol = offset_rel * (hmag + pmag) * 2.0
        if g >= 0:                                     # its float32 plane's error (as in next_event)
            tol += END_REL * d2
        if d2 - tol <= 0.0:
            continue
        counters[4] += 1
        ox, oy, oz = hx + eps2 * tnx, hy + eps2 * tny, hz + eps2 * tnz
        share = seen_share(g, intersect_fn, occluded_fn, scene, scratch, ox, oy, oz, fx, fy, fz, d2 - tol, d2 + tol,
                           tgt_ref[t], geom_offset, tri_receiver, px, py, pz, cop_start, cop_list, cop_box, cop_free,
                           tri_verts, tri_normal, tri_two_sided)
        if share == 0.0:
            continue
        for b in range(n_bands):
            contrib[b] *= share
        nee_stats[stat0 + pl, 1] += 1
        out_k[n_out] = tgt_row[t]
        for b in range(n_bands):
            out_w[n_out, b] = contrib[b]
            nee_stats[stat0 + pl, 2] += contrib[b]
        n_out += 1
        if g >= 0 and tgt_abs_row[t] >= 0:             # what the side met absorbs
            ma = tri_mat[g, 0] if cos_x < 0.0 else tri_mat[g, 1]
            out_k[n_out] = tgt_abs_row[t]
            for b in range(n_bands):
                out_w[n_out, b] = contrib[b] * mat_prob[ma, ABSORB, b]
            n_out += 1
    return n_out


@njit(cache=True, _nrt=False)
def _zone_event(vx, vy, vz, nx, ny, nz, mode, m, w, state, scene, intersect_fn, occluded_fn, scratch, offset_rel,
                vscale, zone_f, zone_i, n_draw, zone_picks, tgt_row, tgt_ref, tgt_center, near_r2, sens_center,
                sens_normal, sens_radius, geom_offset, tri_verts, tri_normal, tri_mat, tri_two_sided, tri_pid,
                mat_prob, mat_nee, cop_start, cop_list, cop_box, cop_free, contrib, out_k, out_w, counters):
    """Two-step next events: the light that the segment leaving v brings to a disc *through one diffuse
    vertex y in the zone of surface beside the disc* (:func:`kernel.nee.near_zones`).

    For ``n_draw`` draws (mean ``zone_picks``): a zone z (uniform over the Z zones) of disc target t on
    plane P; a point y on P about the disc's foot c' at r with density p_A(y) = 1 / (π L (r² + h_s²)); the
    ray v → y must first meet a triangle of P there (after the coplanar pick, as a photon would), inside
    t's near sphere, whose side facing v is a material with next events; then from y a point x on the disc
    by solid angle (:func:`kernel.nee.disc_point_by_solid_angle`, factor Ω̂) and a free leg y → x.  Deposit

        w · f_v(ω_vy) · |cos θ_y| / |y − v|² / p_A(y) · P_ev,b(m_y) · |cos θ'_y| / π · Ω̂ · Z / zone_picks,

    f_v as in :func:`kernel.nee.next_event`, ev the diffuse event of y's side towards x: the expected own
    next event that a photon leaving v diffusely would make at y, which a photon that does land there
    then skips.  Returns the number of deposits written to ``out_k``/``out_w``.
    """
    n_bands = w.shape[0]
    n_zone = zone_i.shape[0]
    if n_zone == 0 or n_draw <= 0 or not zone_picks > 0.0:
        return 0
    c0, c1 = view_factors(mode)
    scale = n_zone / zone_picks
    vmag = max(abs(vx), abs(vy), abs(vz), vscale)
    rh = scratch + RAYHIT
    args = scratch + ARGS
    n_out = 0
    for _ in range(n_draw):
        z = min(int(uniform(state) * n_zone), n_zone - 1)
        u1, u2, u3, u4 = uniform(state), uniform(state), uniform(state), uniform(state)
        t, pid = zone_i[z, 0], zone_i[z, 1]
        s = tgt_ref[t]
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
        counters[4] += 1
        tri, hx, hy, hz, tnx, tny, tnz, m_y = _hit_on_plane(scene, intersect_fn, rh, args, tri_pid, pid, dx, dy, dz,
                                                            geom_offset, tri_verts, tri_normal, tri_mat, tri_two_sided,
                                                            cop_start, cop_list, cop_box, cop_free, state)
        if tri < 0:
            continue                                   # something else first: no such vertex y
        ex, ey, ez = hx - tgt_center[t, 0], hy - tgt_center[t, 1], hz - tgt_center[t, 2]
        if not ex * ex + ey * ey + ez * ez < near_r2[t]:
            continue                                   # outside the zone (a photon there makes a pick instead)
        if mat_nee[m_y] == 0:
            continue                                   # no next events from y's material: its crossings count
        cos_in = -(dx * tnx + dy * tny + dz * tnz)
        gx, gy, gz = hx - vx, hy - vy, hz - vz
        arrive = cos_in / (gx * gx + gy * gy + gz * gz) * inv_pa * scale     # vertex density at y / p_A(y)
        # the second leg: y's own next event towards disc t
        px, py, pz, omega = disc_point_by_solid_angle(hx, hy, hz, s, u3, u4, sens_center, sens_normal,
                                                      sens_radius)
        if omega == 0.0:
            continue
        fx, fy, fz = px - hx, py - hy, pz - hz
        d2 = math.sqrt(fx * fx + fy * fy + fz * fz)
        if not d2 > 0.0:
            continue
        fx, fy, fz = fx / d2, fy / d2, fz / d2
        if fx * sens_normal[s, 0] + fy * sens_normal[s, 1] + fz * sens_normal[s, 2] >= 0.0:
            continue
        cos_y = fx * tnx + fy * tny + fz * tnz
        ev = 0 if cos_y > 0.0 else 2                   # DIFFUSE_R towards y's side of arrival, else DIFFUSE_T
        any_light = False
        for b in range(n_bands):
            fv = c0 + c1 * abs(cos_v)
            if mode == V_SURFACE:
                fv *= mat_prob[m, 0 if cos_v > 0.0 else 2, b]
            contrib[b] = w[b] * fv * arrive * mat_prob[m_y, ev, b] * abs(cos_y) / math.pi * omega
            any_light = any_light or contrib[b] > 0.0
        if not any_light:
            continue
        hmag = max(_magnitude(tri_verts[tri]), abs(hx), abs(hy), abs(hz))
        pmag = max(abs(px), abs(py), abs(pz))
        sy = 1.0 if cos_y > 0.0 else -1.0
        eps2 = offset_rel * (hmag + vmag)
        tfar = d2 - offset_rel * (hmag + pmag) * 2.0
        if tfar <= 0.0:
            continue
        counters[4] += 1
        if not visible(occluded_fn, scene, scratch, hx + sy * eps2 * tnx, hy + sy * eps2 * tny,
                       hz + sy * eps2 * tnz, fx, fy, fz, tfar):
            continue
        out_k[n_out] = tgt_row[t]
        for b in range(n_bands):
            out_w[n_out, b] = contrib[b]
        n_out += 1
    return n_out


@njit(inline="always", cache=True)
def _n_images(picks, state):
    """How many image events at a vertex: int(picks), plus one with probability frac(picks)."""
    n = int(picks)
    if picks - n > 0.0 and uniform(state) < picks - n:
        n += 1
    return n


@njit(inline="always", cache=True)
def _image_counted(t, wx, wy, wz, pl, mir_point, mir_normal, tgt_center, tgt_near2):
    """Is a crossing of target t counted on a segment that leaves mirror plane ``pl`` after a photon came
    from the next-event vertex w?  Only when w's image across the plane was too near t (as in
    :func:`_image_event`)."""
    sv = (wx - mir_point[pl, 0]) * mir_normal[pl, 0] + (wy - mir_point[pl, 1]) * mir_normal[pl, 1] \
        + (wz - mir_point[pl, 2]) * mir_normal[pl, 2]
    ix = wx - 2.0 * sv * mir_normal[pl, 0]
    iy = wy - 2.0 * sv * mir_normal[pl, 1]
    iz = wz - 2.0 * sv * mir_normal[pl, 2]
    ex, ey, ez = ix - tgt_center[t, 0], iy - tgt_center[t, 1], iz - tgt_center[t, 2]
    return ex * ex + ey * ey + ez * ez < tgt_near2[t]


@njit(inline="always", cache=True)
def _magnitude(v):
    """Largest |coordinate| of the three vertices v (3, 3): the scale of a triangle's float32 round-off."""
    m = 0.0
    for i in range(3):
        for j in range(3):
            m = max(m, abs(v[i, j]))
    return m


@njit(inline="always", cache=True)
def _emit(e, kind, data, state, offset_rel):
    """Sample an origin and a direction on emitter element e.

    Also returns the origin's round-off scale (see the offset note in :func:`trace_chunk`)."""
    k = kind[e]
    u1, u2, u3, u4 = uniform(state), uniform(state), uniform(state), uniform(state)
    if k == EMIT_LINE or k == EMIT_POINT:
        f = u1 if k == EMIT_LINE else 0.0
        ox = data[e, 0, 0] + f * (data[e, 1, 0] - data[e, 0, 0])
        oy = data[e, 0, 1] + f * (data[e, 1, 1] - data[e, 0, 1])
        oz = data[e, 0, 2] + f * (data[e, 1, 2] - data[e, 0, 2])
        dx, dy, dz = uniform_sphere(u2, u3)
        return ox, oy, oz, dx, dy, dz, 0.0, 0.0, 1.0, V_ISOTROPIC, max(abs(ox), abs(oy), abs(oz))
    if k == EMIT_TRIANGLE:
        su = math.sqrt(u1)
        b0, b1 = 1.0 - su, u2 * su
        b2 = 1.0 - b0 - b1
        ox = b0 * data[e, 0, 0] + b1 * data[e, 1, 0] + b2 * data[e, 2, 0]
        oy = b0 * data[e, 0, 1] + b1 * data[e, 1, 1] + b2 * data[e, 2, 1]
        oz = b0 * data[e, 0, 2] + b1 * data[e, 1, 2] + b2 * data[e, 2, 2]
        ax, ay, az = data[e, 1, 0] - data[e, 0, 0], data[e, 1, 1] - data[e, 0, 1], data[e, 1, 2] - data[e, 0, 2]
        bx, by, bz = data[e, 2, 0] - data[e, 0, 0], data[e, 2, 1] - data[e, 0, 1], data[e, 2, 2] - data[e, 0, 2]
        nx, ny, nz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
        scale = _magnitude(data[e])     # an emitting polygon is also a surface: its own round-off
    elif k == EMIT_CYLINDER:
        ax, ay, az = data[e, 1, 0] - data[e, 0, 0], data[e, 1, 1] - data[e, 0, 1], data[e, 1, 2] - data[e, 0, 2]
        length = math.sqrt(ax * ax + ay * ay + az * az)
        lx, ly, lz = to_world(math.cos(2 * math.pi * u2), math.sin(2 * math.pi * u2), 0.0,
                              ax / length, ay / length, az / length)
        r = data[e, 2, 0]
        ox, oy, oz = data[e, 0, 0] + u1 * ax + r * lx, data[e, 0, 1] + u1 * ay + r * ly, data[e, 0, 2] + u1 * az + r * lz
        nx, ny, nz = lx, ly, lz
        scale = max(abs(ox), abs(oy), abs(oz))
    else:  # EMIT_SPHERE
        nx, ny, nz = uniform_sphere(u1, u2)
        r = data[e, 1, 0]
        ox, oy, oz = data[e, 0, 0] + r * nx, data[e, 0, 1] + r * ny, data[e, 0, 2] + r * nz
        scale = max(abs(ox), abs(oy), abs(oz))
    inv = 1.0 / math.sqrt(nx * nx + ny * ny + nz * nz)
    nx, ny, nz = nx * inv, ny * inv, nz * inv
    dx, dy, dz = cosine_hemisphere(nx, ny, nz, u3, u4)
    scale += max(abs(ox), abs(oy), abs(oz), 1e-30)   # as after a hit: triangle's + origin's magnitudes
    eps = offset_rel * scale
    return ox + eps * nx, oy + eps * ny, oz + eps * nz, dx, dy, dz, nx, ny, nz, V_LAMBERT, scale


@njit(nogil=True, cache=True, _nrt=False)
def _trace_photons(scene, intersect_fn, scratch, seed, first, count,
                   geom_offset, tri_normal, tri_mat, tri_receiver,
                   mat_prob, mat_cum, band_pass, mat_phong,
                   sens_kind, sens_center, sens_normal, sens_radius, sens_corners,
                   emit_kind, emit_data, emit_cdf,
                   max_depth, offset_rel, n_receivers, expected_absorption,
                   occluded_fn, nee_sensors, nee_receivers, tgt_kind, tgt_row, tgt_abs_row, tgt_ref, tgt_first,
                   tgt_count, tgt_area, tgt_center, tgt_near2, nee_tri, nee_cdf, tgt_img_near2, near_start, near_list,
                   near_r2, sensor_target, receiver_target,
                   tri_verts, mat_nee, emit_nee, picks, cop_start, cop_list, cop_box, cop_free, tri_two_sided,
                   img_picks, tri_plane, mir_point, mir_normal, mir_list, mir_cdf, mir_inv_p, mir_on, mir_box,
                   mir_one_sided, control, cv_batch, zone_picks, zone_f, zone_i, zone_start, tri_pid, flush_start,
                   flush_list, tally, tally_sq,
                   counters, nee_stats,
                   state, w, dep, contrib, out_k, out_w, cv_row, cv_center, cv_normal, cv_area, cv_thr, cv_runs,
                   cv_plane, cv_acc, cv_tally, cv_sq, g_r, g_t, acc, touched, rows, tot, seen):
    """The photon loop of :func:`trace_chunk` (its arguments, then its work arrays), compiled without
    reference counting: array views and inlined helpers here would otherwise cost an atomic
    increment and decrement each (~20 % of a rose step's CPU time, more with two threads)."""
    n_bands = mat_prob.shape[2]
    n_mat = mat_prob.shape[0]
    n_sens = sens_center.shape[0]
    fate0 = tally.shape[0] - n_mat - 4
    f_escaped, f_cut, f_lost = fate0 + n_mat, fate0 + n_mat + 1, fate0 + n_mat + 2
    absorbed0 = n_sens + n_receivers
    n_tgt = tgt_kind.shape[0]
    n_cv = cv_row.shape[0]
    in_batch = 0         # photons in the current batch of the control variate
    rh = scratch + RAYHIT
    args = scratch + ARGS
    cand_count = scratch + CAND_COUNT
    img_on = img_picks > 0.0 and (nee_sensors or nee_receivers) and n_tgt > 0 and mir_list.shape[0] > 0
    zone_on = zone_picks > 0.0 and nee_sensors and zone_i.shape[0] > 0 and 0 < picks < n_tgt
    stat_planes = n_mat + emit_nee.shape[0]

    n_pass = mat_cum.shape[2]      # paths per photon: 1 (all bands on one), n_bands (analog), or band groups
    nh = 0
    for path in range(count * n_pass):
        i = path // n_pass           # the photon
        pb = path - i * n_pass       # its band (n_pass > 1) or 0
        if pb == 0:
            seed_stream(state, seed, first + i)
        e = search_cdf(emit_cdf, 0, emit_cdf.shape[0] - 1, (i + uniform(state)) / count)
        ox, oy, oz, dx, dy, dz, enx, eny, enz, emode, oscale = _emit(e, emit_kind, emit_data, state, offset_rel)
        if n_pass == 1:
            w[:] = 1.0
        else:                        # this path carries its bands only
            for b in range(n_bands):
                w[b] = 1.0 if band_pass[b] == pb else 0.0
        depth = 0
        after_diffuse = False   # does the current segment start at a next-event vertex?
        vx0, vy0, vz0 = ox, oy, oz   # that vertex
        seg_plane = -1          # the current segment leaves this mirror plane, reflected, after a next-event vertex
        wx, wy, wz = ox, oy, oz  # that next-event vertex
        if n_tgt > 0 and emit_nee[e] != 0:
            if control:
                _control_deposits(ox, oy, oz, enx, eny, enz, emode, 0, w, 0, cv_center, cv_normal, cv_area, cv_thr,
                                  cv_runs, cv_plane, mat_prob, g_r, g_t, cv_acc)
            n_out = next_event(ox, oy, oz, enx, eny, enz, emode, 0, n_mat + e, w, state, scene, occluded_fn, scratch,
                               offset_rel, tgt_kind, tgt_row, tgt_abs_row, tgt_ref, tgt_first, tgt_count, tgt_area,
                               tgt_center, tgt_near2, sens_center, sens_normal, sens_radius, sens_corners, nee_tri, nee_cdf, tri_verts,
                               tri_normal, tri_mat, mat_prob, contrib, out_k, out_w, counters, nee_stats,
                               picks, oscale, -1, near_start, near_list, near_r2, control, -1, zone_start, zone_i,
                               intersect_fn, geom_offset, tri_receiver, cop_start, cop_list, cop_box, cop_free,
                               tri_two_sided)
            for a in range(n_out):
                nh = _record(out_k[a], out_w[a], acc, touched, rows, nh)
            n_img = _n_images(img_picks, state) if img_on and max_depth > 0 else 0
            if n_img > 0:
                n_out = _image_event(ox, oy, oz, enx, eny, enz, emode, 0, w, state, scene, intersect_fn, occluded_fn,
                                     scratch, offset_rel, oscale, tgt_kind, tgt_row, tgt_abs_row, tgt_ref, tgt_first,
                                     tgt_count, nee_tri, nee_cdf, tgt_area, tgt_center,
                                     tgt_img_near2, tri_receiver, sens_center, sens_normal, sens_radius, sens_corners, geom_offset,
                                     tri_verts, tri_normal, tri_mat, tri_two_sided, mat_prob, mat_phong, cop_start,
                                     cop_list, cop_box, cop_free, tri_plane, mir_point, mir_normal, mir_list,
                                     mir_cdf, mir_inv_p, mir_box, mir_one_sided, n_img, img_picks, contrib, out_k,
                                     out_w, counters, nee_stats, stat_planes)
                for a in range(n_out):
                    nh = _record(out_k[a], out_w[a], acc, touched, rows, nh)
            n_zone = _n_images(zone_picks, state) if zone_on and max_depth > 0 else 0
            if n_zone > 0:
                n_out = _zone_event(ox, oy, oz, enx, eny, enz, emode, 0, w, state, scene, intersect_fn, occluded_fn,
                                    scratch, offset_rel, oscale, zone_f, zone_i, n_zone, zone_picks, tgt_row, tgt_ref,
                                    tgt_center, near_r2, sens_center, sens_normal, sens_radius, geom_offset,
                                    tri_verts, tri_normal, tri_mat, tri_two_sided, tri_pid, mat_prob, mat_nee,
                                    cop_start, cop_list, cop_box, cop_free, contrib, out_k, out_w, counters)
                for a in range(n_out):
                    nh = _record(out_k[a], out_w[a], acc, touched, rows, nh)
            after_diffuse = True
        while True:
            skip_sensors = after_diffuse and nee_sensors
            skip_receivers = after_diffuse and nee_receivers
            set_ray(scratch, ox, oy, oz, dx, dy, dz, _TFAR_MAX)
            call_ptr3(intersect_fn, scene, rh, args)
            counters[C_RAYS] += 1
            gid = load_u32(rh + GEOM_ID)
            t = math.inf if gid == INVALID_ID else float(load_f32(rh + TFAR))
            tri = -1 if gid == INVALID_ID else load_u32(rh + PRIM_ID) + geom_offset[gid]

            # transparent sensors crossed before the surface hit (exact test in float64): those Embree
            # reported, and those lying on the triangle hit, which its float32 rounding may have left out
            nc = load_i64(cand_count)
            if nc > CAND_CAP:
                counters[C_CAND_OVERFLOW] += 1
                nc = CAND_CAP
            n_flush = flush_start[tri + 1] - flush_start[tri] if tri >= 0 else 0
            if n_flush > 0:      # then the surface's distance in float64, from its own plane
                dn = dx * tri_normal[tri, 0] + dy * tri_normal[tri, 1] + dz * tri_normal[tri, 2]
                if dn != 0.0:
                    t = ((tri_verts[tri, 0, 0] - ox) * tri_normal[tri, 0] + (tri_verts[tri, 0, 1] - oy) * tri_normal[tri, 1]
                         + (tri_verts[tri, 0, 2] - oz) * tri_normal[tri, 2]) / dn
                    t += 1e-9 * (abs(t) + max(abs(ox), abs(oy), abs(oz)))     # a sensor on it is met first
            n_seen = 0
            for c in range(nc + n_flush):
                if c < nc:
                    s = load_u32(scratch + CAND + 8 * c) // 2
                else:
                    s = flush_list[flush_start[tri] + c - nc]
                dup = False
                for j in range(n_seen):
                    if seen[j] == s:
                        dup = True
                        break
                if dup:
                    continue
                seen[n_seen] = s
                n_seen += 1
                snx, sny, snz = sens_normal[s, 0], sens_normal[s, 1], sens_normal[s, 2]
                den = dx * snx + dy * sny + dz * snz
                if den >= 0.0:
                    continue
                ts = ((sens_center[s, 0] - ox) * snx + (sens_center[s, 1] - oy) * sny
                      + (sens_center[s, 2] - oz) * snz) / den
                if ts <= 0.0 or ts >= t:
                    continue
                counted = _counted(skip_sensors, sensor_target[s] if skip_sensors else -1, vx0, vy0, vz0, tgt_center,
                                   tgt_near2)
                if counted and seg_plane >= 0 and sensor_target[s] >= 0:     # covered by image events?
                    counted = _image_counted(sensor_target[s], wx, wy, wz, seg_plane, mir_point, mir_normal,
                                             tgt_center, tgt_img_near2)
                if counted and _inside(s, ox + ts * dx, oy + ts * dy, oz + ts * dz,
                                       sens_kind, sens_center, sens_radius, sens_corners, sens_normal):
                    nh = _record(s, w, acc, touched, rows, nh)

            if gid == INVALID_ID:
                nh = _record(f_escaped, w, acc, touched, rows, nh)
                break
            # the hit point from Embree's barycentrics on our float64 triangle: on its plane to float64
            # precision.  o + t·d is not: Embree's t carries the float32 error of the triangle's plane seen
            # from the ray's origin (~1e-5 of t on thin sliver triangles, as leaf fans have), which can put
            # o + t·d behind the surface, farther than any sane offset.
            bu, bv = load_f32(rh + HIT_U), load_f32(rh + HIT_V)
            b0 = 1.0 - bu - bv
            px = b0 * tri_verts[tri, 0, 0] + bu * tri_verts[tri, 1, 0] + bv * tri_verts[tri, 2, 0]
            py = b0 * tri_verts[tri, 0, 1] + bu * tri_verts[tri, 1, 1] + bv * tri_verts[tri, 2, 1]
            pz = b0 * tri_verts[tri, 0, 2] + bu * tri_verts[tri, 1, 2] + bv * tri_verts[tri, 2, 2]
            if not (math.isfinite(px) and math.isfinite(py) and math.isfinite(pz)):
                counters[C_LOST] += 1
                nh = _record(f_lost, w, acc, touched, rows, nh)
                break
            if cop_start[tri + 1] > cop_start[tri]:   # coincident surfaces: a fair choice, not float rounding
                tri = _pick_coplanar(tri, px, py, pz, dx, dy, dz, cop_start, cop_list, cop_box, cop_free,
                                     tri_verts, tri_normal, tri_two_sided, state)
            nx, ny, nz = tri_normal[tri, 0], tri_normal[tri, 1], tri_normal[tri, 2]
            if dx * nx + dy * ny + dz * nz > 0.0:      # back side of a two-sided surface
                nx, ny, nz = -nx, -ny, -nz
                m = tri_mat[tri, 1]
            else:
                m = tri_mat[tri, 0]
            # round-off scale of this hit: Embree works in float32 on the triangle's vertices and the ray's
            # origin, and returns t in float32, so the hit point's error is a few ulps of the largest of |v_i|
            # and |o| (pbrt's error bounds) -- not of |p|, which is ~0 on a large triangle through the origin
            pscale = max(_magnitude(tri_verts[tri]), abs(px), abs(py), abs(pz))
            oscale = max(abs(ox), abs(oy), abs(oz))
            rec = tri_receiver[tri]
            # counted unless the next-event tallies cover this hit
            rec_analog = rec >= 0 and _counted(skip_receivers, receiver_target[rec] if skip_receivers else -1,
                                               vx0, vy0, vz0, tgt_center, tgt_near2)
            if rec_analog and seg_plane >= 0 and receiver_target[rec] >= 0:      # covered by image events?
                rec_analog = _image_counted(receiver_target[rec], wx, wy, wz, seg_plane, mir_point, mir_normal,
                                            tgt_center, tgt_img_near2)
            if rec_analog:
                nh = _record(n_sens + rec, w, acc, touched, rows, nh)
            if depth >= max_depth:
                nh = _record(f_cut, w, acc, touched, rows, nh)
                break
            if expected_absorption:   # deposit what this surface absorbs on average
                for b in range(n_bands):
                    dep[b] = w[b] * mat_prob[m, ABSORB, b]
                nh = _record(fate0 + m, dep, acc, touched, rows, nh)
                if rec_analog:
                    nh = _record(absorbed0 + rec, dep, acc, touched, rows, nh)
            if n_tgt > 0 and mat_nee[m] != 0:   # expected light of the next segment if it leaves diffusely
                cover = tri_pid[tri] if zone_on and after_diffuse else -1     # zone events served its near discs
                if control:
                    _control_deposits(px, py, pz, nx, ny, nz, V_SURFACE, m, w,
                                      1 if near_start[tri + 1] > near_start[tri] else 0, cv_center, cv_normal,
                                      cv_area, cv_thr, cv_runs, cv_plane, mat_prob, g_r, g_t, cv_acc)
                n_out = next_event(px, py, pz, nx, ny, nz, V_SURFACE, m, m, w, state, scene, occluded_fn, scratch,
                                   offset_rel, tgt_kind, tgt_row, tgt_abs_row, tgt_ref, tgt_first, tgt_count,
                                   tgt_area, tgt_center, tgt_near2, sens_center, sens_normal, sens_radius, sens_corners, nee_tri, nee_cdf,
                                   tri_verts, tri_normal, tri_mat, mat_prob, contrib, out_k, out_w, counters,
                                   nee_stats, picks, pscale + oscale, tri, near_start, near_list, near_r2, control,
                                   cover, zone_start, zone_i, intersect_fn, geom_offset, tri_receiver, cop_start,
                                   cop_list, cop_box, cop_free, tri_two_sided)
                for a in range(n_out):
                    nh = _record(out_k[a], out_w[a], acc, touched, rows, nh)
                # and through a mirror (if not cut at that mirror); the call itself is not free: only if drawn
                n_img = _n_images(img_picks, state) if img_on and depth + 1 < max_depth else 0
                if n_img > 0:
                    n_out = _image_event(px, py, pz, nx, ny, nz, V_SURFACE, m, w, state, scene, intersect_fn,
                                         occluded_fn, scratch, offset_rel, pscale + oscale, tgt_kind, tgt_row,
                                         tgt_abs_row, tgt_ref, tgt_first, tgt_count, nee_tri, nee_cdf, tgt_area,
                                         tgt_center, tgt_img_near2, tri_receiver, sens_center, sens_normal,
                                         sens_radius, sens_corners, geom_offset, tri_verts, tri_normal, tri_mat,
                                         tri_two_sided, mat_prob, mat_phong, cop_start, cop_list, cop_box,
                                         cop_free, tri_plane, mir_point, mir_normal, mir_list, mir_cdf,
                                         mir_inv_p, mir_box, mir_one_sided, n_img, img_picks, contrib, out_k,
                                         out_w, counters, nee_stats, stat_planes)
                    for a in range(n_out):
                        nh = _record(out_k[a], out_w[a], acc, touched, rows, nh)
                n_zone = _n_images(zone_picks, state) if zone_on and depth + 1 < max_depth else 0
                if n_zone > 0:     # and through one diffuse vertex beside a disc
                    n_out = _zone_event(px, py, pz, nx, ny, nz, V_SURFACE, m, w, state, scene, intersect_fn,
                                        occluded_fn, scratch, offset_rel, pscale + oscale, zone_f, zone_i, n_zone,
                                        zone_picks, tgt_row, tgt_ref, tgt_center, near_r2, sens_center,
                                        sens_normal, sens_radius, geom_offset, tri_verts, tri_normal, tri_mat,
                                        tri_two_sided, tri_pid, mat_prob, mat_nee, cop_start, cop_list, cop_box,
                                        cop_free, contrib, out_k, out_w, counters)
                    for a in range(n_out):
                        nh = _record(out_k[a], out_w[a], acc, touched, rows, nh)

            # one event, drawn with probabilities q shared by the bands; weights carry the rest
            u = uniform(state)
            ev = 0
            while ev < ABSORB and u >= mat_cum[m, ev, pb]:
                ev += 1
            if ev == ABSORB and expected_absorption:   # ends here: its absorption is already deposited
                break
            q = mat_cum[m, ev, pb] - (mat_cum[m, ev - 1, pb] if ev > 0 else 0.0)
            for b in range(n_bands):
                w[b] *= mat_prob[m, ev, b] / q
            if ev == ABSORB:
                if rec_analog:
                    nh = _record(absorbed0 + rec, w, acc, touched, rows, nh)
                nh = _record(fate0 + m, w, acc, touched, rows, nh)
                break
            depth += 1
            pl = tri_plane[tri]
            if img_on and ev == SPECULAR_R and after_diffuse and pl >= 0 and mir_on[pl] != 0 and math.isinf(mat_phong[m]):
                seg_plane = pl                      # a mirror right after a next-event vertex (vx0)
                wx, wy, wz = vx0, vy0, vz0
            else:
                seg_plane = -1
            after_diffuse = n_tgt > 0 and mat_nee[m] != 0 and (ev == DIFFUSE_R or ev == DIFFUSE_T)
            vx0, vy0, vz0 = px, py, pz
            u1, u2 = uniform(state), uniform(state)
            if ev == DIFFUSE_R:
                dx, dy, dz = cosine_hemisphere(nx, ny, nz, u1, u2)
                side = 1.0
            elif ev == SPECULAR_R:
                rx, ry, rz = mirror(dx, dy, dz, nx, ny, nz)
                if math.isinf(mat_phong[m]):
                    dx, dy, dz = rx, ry, rz
                else:
                    dx, dy, dz = phong_lobe(rx, ry, rz, mat_phong[m], u1, u2)
                    if dx * nx + dy * ny + dz * nz <= 0.0:   # lobe below the surface: absorbed there
                        if rec >= 0:
                            nh = _record(absorbed0 + rec, w, acc, touched, rows, nh)
                        nh = _record(fate0 + m, w, acc, touched, rows, nh)
                        break
                side = 1.0
            elif ev == DIFFUSE_T:
                dx, dy, dz = cosine_hemisphere(-nx, -ny, -nz, u1, u2)
                side = -1.0
            else:   # SPECULAR_T: straight through a thin surface
                side = -1.0
            inv = 1.0 / math.sqrt(dx * dx + dy * dy + dz * dz)
            dx, dy, dz = dx * inv, dy * inv, dz * inv
            eps = side * offset_rel * (pscale + oscale)
            ox, oy, oz = px + eps * nx, py + eps * ny, pz + eps * nz
        if pb < n_pass - 1:
            continue         # the photon's other bands' paths still to come: one flush for all
        if control:          # batches of cv_batch photons by photon index: the same on any number of threads
            _fold_control(nh, rows, touched, acc, cv_acc, sensor_target, n_sens)
            in_batch += 1
            if (first + i + 1) % cv_batch == 0 or i == count - 1:
                _control_products(cv_acc, in_batch, cv_tally, cv_sq)
                counters[C_BATCHES] += 1
                in_batch = 0
        _flush(nh, rows, touched, acc, tally, tally_sq, fate0, tot)
        nh = 0
    for t in range(n_cv):
        for b in range(n_bands):
            tally[cv_row[t], b] += cv_tally[b, t]
            for b2 in range(n_bands):    # _control_products filled b2 >= b (x·y = y·x exactly)
                tally_sq[cv_row[t], b, b2] += cv_sq[min(b, b2), max(b, b2), t]



@njit(nogil=True, cache=True)
def trace_chunk(scene, intersect_fn, scratch, seed, first, count,
                geom_offset, tri_normal, tri_mat, tri_receiver,
                mat_prob, mat_cum, band_pass, mat_phong,
                sens_kind, sens_center, sens_normal, sens_radius, sens_corners,
                emit_kind, emit_data, emit_cdf,
                max_depth, offset_rel, n_receivers, expected_absorption,
                occluded_fn, nee_sensors, nee_receivers, tgt_kind, tgt_row, tgt_abs_row, tgt_ref, tgt_first,
                tgt_count, tgt_area, tgt_center, tgt_near2, nee_tri, nee_cdf, tgt_img_near2, near_start, near_list,
                near_r2, sensor_target, receiver_target,
                tri_verts, mat_nee, emit_nee, picks, cop_start, cop_list, cop_box, cop_free, tri_two_sided,
                img_picks, tri_plane, mir_point, mir_normal, mir_list, mir_cdf, mir_inv_p, mir_on, mir_box,
                mir_one_sided, control, cv_batch, zone_picks, zone_f, zone_i, zone_start, tri_pid, flush_start,
                flush_list, tally, tally_sq,
                counters, nee_stats):
    """Trace photons ``first .. first+count-1``; add what they do to the output arrays.

    Parameters (T triangles, M materials, B bands, S sensors, E emitter elements,
    R receivers, K = S + 2R tallies):

    scene, intersect_fn, scratch : int
        Embree scene handle, address of ``rtcIntersect1``, base of this thread's
        scratch block (:func:`kernel.embree.new_scratch`).
    seed, first, count : int
        Run seed and photon index range; photon i's random stream is a function
        of ``(seed, i)`` only.
    geom_offset : (3,) int64
        Global triangle index = Embree ``primID + geom_offset[geomID]``.
    tri_normal : (T, 3) float64, unit right-hand-rule normals.
    tri_mat : (T, 2) int32, material seen from the front / back side.
    tri_receiver : (T,) int32, receiver index or -1.
    mat_prob : (M, 5, B) float64, probability of each event per band.
    mat_cum : (M, 5, P) float64, cumulative event probabilities q of the event drawn on each of the P paths
        every photon is traced on: P = 1, shared by the bands; P = B (``analog``), one per band; or one per
        group of bands that can share q without a weight growing (:func:`lpy_light.materials.band_passes`).
    band_pass : (B,) int64, the path that carries band b: its weight starts at 1 there, 0 on the others.
    mat_phong : (M,) float64, Phong exponent of the specular lobe (inf = mirror).
    sens_* : transparent sensors: kind, centre (S, 3), unit normal (S, 3),
        radius (S,), quad corners (S, 4, 3).
    emit_kind (E,), emit_data (E, 3, 3), emit_cdf (E,) : emitter elements and the
        cumulative distribution of their power.
    max_depth : int, scattering events allowed before a photon is cut.
    offset_rel : float, ray offset relative to the round-off scale of a hit: a new ray starts
        ``offset_rel · (max(|v_i|, |p|) + |o|)`` off the surface along its normal (v_i the hit
        triangle's vertices, p the hit, o the ray's origin; ∞-norms), which bounds Embree's float32
        error a few ulps deep (``docs/stability.md``).
    expected_absorption : bool, the ``weighted`` estimator (True) or ``analog``.
    occluded_fn : int, address of ``rtcOccluded1`` (next-event shadow rays).
    nee_sensors, nee_receivers : bool, whether sensors / receivers are
        next-event targets (:mod:`kernel.nee`); their crossings and hits after
        diffuse vertices are then not counted, the targets' expected values are.
    tgt_*, nee_tri, nee_cdf, near_*, sensor_target, receiver_target : next-event
        targets (:func:`kernel.nee.build_targets`); empty arrays for none.  ``tgt_near2`` are the
        exclusion radii² of next events (0 for discs), ``tgt_img_near2`` those of next events through
        mirrors.
    tri_verts : (T, 3, 3) float64, triangle vertices (to sample points on receivers).
    mat_nee (M,), emit_nee (E,) : uint8, next events from this material's
        surfaces / this emitter element (0: its segments are counted instead).
    picks : int, targets per next event (0: all; see :func:`kernel.nee.next_event`).
    cop_start (T+1,) int64, cop_list (K,) int32 : coplanar candidates of each triangle
        (:func:`lpy_light.geometry.coplanar_partners`); a hit on a triangle with candidates
        picks, uniformly at random, one of it and the candidates that contain the hit point
        and face the ray (or are two-sided).  All-zero ``cop_start``: no such choice.
    cop_box : (T, 2, 3) float64, each triangle's bounding box, slightly widened (quick reject).
    cop_free : (T, 2, 3) float64, a box where none of the triangle's candidates reaches
        (:func:`lpy_light.geometry.partner_free_boxes`): hits inside it skip the tests.
    tri_two_sided : (T,) uint8, whether each triangle is seen from both sides.
    img_picks : float, next events through a mirror per next-event vertex, on average (0: none; fractional:
        a random whole number with that mean; :func:`_image_event`).
    tri_plane (T,) int32 : each triangle's mirror plane or -1; mir_point, mir_normal (P, 3) : a point and
        the unit normal of each plane; mir_list : int32, the planes in use, drawn by the cumulative
        probabilities mir_cdf with weights 1 / p = mir_inv_p; mir_on (P,) uint8, the planes in use as flags;
        mir_box (P, 2, 3) each plane's triangles' bounds (slightly widened); mir_one_sided (P,) uint8.
        A target's crossing (sensor or mesh) right after a perfect-mirror reflection on a plane in use, by a
        photon that came there from a next-event vertex, is then covered by the image events and not counted.
    control : bool, the control variate (with sensor targets and random picks): every sensor's γ at every
        next-event vertex (:func:`_control_deposits`); cv_batch : int, photons per batch of its products
        between bands (:func:`_control_products`; batches start at multiples of cv_batch, counted in
        ``counters[C_BATCHES]``; 1: per photon, like every other row).
    zone_picks : float, two-step next events through the zone beside a disc per next-event vertex, on
        average (0: none; :func:`_zone_event`); zone_f (Z, 14), zone_i (Z, 2), zone_start (targets + 1,)
        the zones (:func:`kernel.nee.near_zones`); tri_pid (T,) int32 each triangle's plane id.
    flush_start (T + 1,), flush_list : int64, the sensors lying on each triangle's plane
        (:meth:`lpy_light.sensors.Sensors.flush_with`), tested at every hit on it.
    nee_stats : (M + E + P, 3) float64, shadow rays cast, unblocked, and the weight
        they deposit, per material, per emitter element, then per mirror plane (image events).
    tally (K + M + 4, B), tally_sq (K + M + 4, B, B) : float64, expected hits and
        sums of products (band by band) of per-photon contributions: rows [0, S) sensor crossings, [S, S+R)
        receiver incident, [S+R, K) receiver absorbed, then fates from row K:
        weight absorbed per material (M rows), escaped, cut at max_depth, lost
        to numerical failure, and the photon's total deposit.
    counters : (6,) int64: rays traced, candidate overflows, scratch flushes, lost, shadow rays, control
        variate batches.
    """
    n_bands = mat_prob.shape[2]
    n_mat = mat_prob.shape[0]
    n_sens = sens_center.shape[0]
    fate0 = tally.shape[0] - n_mat - 4
    f_escaped, f_cut, f_lost = fate0 + n_mat, fate0 + n_mat + 1, fate0 + n_mat + 2
    absorbed0 = n_sens + n_receivers
    state = np.zeros(1, dtype=np.uint64)
    w = np.empty(n_bands)
    dep = np.empty(n_bands)
    n_tgt = tgt_kind.shape[0]
    contrib = np.empty(n_bands)
    n_slots = 3 * (n_tgt + picks) + 2 * (1 + int(max(img_picks, zone_picks)))   # near discs + picks (3 deposits
    out_k = np.empty(n_slots, dtype=np.int64)                             # each), or image / zone events
    out_w = np.empty((n_slots, n_bands))
    control = control and nee_sensors and 0 < picks < n_tgt
    n_cv = 0            # sensor targets come first
    while control and n_cv < n_tgt and tgt_kind[n_cv] <= 1:
        n_cv += 1
    cv_center = np.empty((3, n_cv), dtype=np.float32)      # float32: γ's loop runs 16 wide
    cv_normal = np.empty((3, n_cv), dtype=np.float32)
    cv_area = np.empty(n_cv, dtype=np.float32)
    cv_thr = np.empty((2, n_cv), dtype=np.float32)
    cv_row = np.empty(n_cv, dtype=np.int64)
    for t in range(n_cv):
        for c in range(3):
            cv_center[c, t] = tgt_center[t, c]
            cv_normal[c, t] = sens_normal[tgt_ref[t], c]
        cv_area[t] = tgt_area[t]
        # no control within NEAR_FLOOR radii of a disc: its point value is no approximation there
        floor2 = (NEAR_FLOOR * sens_radius[tgt_ref[t]]) ** 2 if tgt_kind[t] == T_DISC else 0.0
        cv_thr[0, t] = max(tgt_near2[t], floor2)
        cv_thr[1, t] = max(tgt_near2[t], floor2, near_r2[t])
        cv_row[t] = tgt_row[t]
    cv_runs = np.empty((n_cv, 2), dtype=np.int64)     # runs of targets on one plane with one normal:
    cv_plane = np.empty(n_cv, dtype=np.float32)       # first, end; the plane's offset n·c
    n_runs = 0
    for t in range(n_cv):
        off = cv_normal[0, t] * cv_center[0, t] + cv_normal[1, t] * cv_center[1, t] + cv_normal[2, t] * cv_center[2, t]
        if n_runs > 0 and off == cv_plane[n_runs - 1] and cv_normal[0, t] == cv_normal[0, t - 1] \
                and cv_normal[1, t] == cv_normal[1, t - 1] and cv_normal[2, t] == cv_normal[2, t - 1]:
            cv_runs[n_runs - 1, 1] = t + 1
        else:
            cv_runs[n_runs, 0], cv_runs[n_runs, 1], cv_plane[n_runs] = t, t + 1, off
            n_runs += 1
    cv_runs = cv_runs[:n_runs]
    cv_plane = cv_plane[:n_runs]
    cv_acc = np.zeros((n_bands, n_cv))     # deposits on the sensor targets, summed over a batch of photons
    cv_tally = np.zeros((n_bands, n_cv))   # and the chunk's sums (added to the tallies at its end)
    cv_sq = np.zeros((n_bands, n_bands, n_cv))
    g_r = np.empty(n_cv, dtype=np.float32)
    g_t = np.empty(n_cv, dtype=np.float32)
    acc = np.zeros((tally.shape[0], n_bands))     # this photon's sum per tally row
    touched = np.zeros(tally.shape[0], dtype=np.uint8)
    rows = np.empty(tally.shape[0], dtype=np.int64)     # the rows it touched, in order
    tot = np.empty(n_bands)
    seen = np.empty(CAND_CAP + (int(np.max(np.diff(flush_start))) if flush_start.shape[0] > 1 else 0), dtype=np.int64)
    _trace_photons(scene, intersect_fn, scratch, seed, first, count,
                   geom_offset, tri_normal, tri_mat, tri_receiver,
                   mat_prob, mat_cum, band_pass, mat_phong,
                   sens_kind, sens_center, sens_normal, sens_radius, sens_corners,
                   emit_kind, emit_data, emit_cdf,
                   max_depth, offset_rel, n_receivers, expected_absorption,
                   occluded_fn, nee_sensors, nee_receivers, tgt_kind, tgt_row, tgt_abs_row, tgt_ref, tgt_first,
                   tgt_count, tgt_area, tgt_center, tgt_near2, nee_tri, nee_cdf, tgt_img_near2, near_start, near_list,
                   near_r2, sensor_target, receiver_target,
                   tri_verts, mat_nee, emit_nee, picks, cop_start, cop_list, cop_box, cop_free, tri_two_sided,
                   img_picks, tri_plane, mir_point, mir_normal, mir_list, mir_cdf, mir_inv_p, mir_on, mir_box,
                   mir_one_sided, control, cv_batch, zone_picks, zone_f, zone_i, zone_start, tri_pid, flush_start,
                   flush_list, tally, tally_sq,
                   counters, nee_stats,
                   state, w, dep, contrib, out_k, out_w, cv_row, cv_center, cv_normal, cv_area, cv_thr, cv_runs,
                   cv_plane, cv_acc, cv_tally, cv_sq, g_r, g_t, acc, touched, rows, tot, seen)
