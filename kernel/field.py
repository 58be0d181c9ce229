"""The light field at a plant's region, and a step's rays that read it (the ``field`` estimator's hot loops).

The *region* is a box (lo (3), hi (3), scene units) around the plant.  The *field* is the light entering it
through its six faces, binned by face, by cell on the face and by direction, per band:

* face f = 2a + s crosses axis a (0, 1, 2) at lo[a] (s = 0) or hi[a] (s = 1); its inward normal is +e_a or −e_a;
* a face is cut into ``grid[f, 0] × grid[f, 1]`` cells along the axes a1 = a + 1, a2 = a + 2 (mod 3);
* directions arriving through it into ``rings × sectors`` bins of equal *projected* solid angle π / (rings ·
  sectors): ring r holds sin²θ ∈ [r / rings, (r + 1) / rings) (θ from the inward normal), sector k the azimuth
  atan2(d·e_a2, d·e_a1) ∈ [2πk / sectors, 2π(k + 1) / sectors).

``field[g, bin, b]`` holds, for batch g of the store's photons, Σ w_b / A_cell over the photon segments that
entered the region through that bin: the irradiance it brings (photons of weight per scene unit², for all the
store's photons), so that the radiance of the bin is ``field · bins_per_cell / π`` and a cosine-weighted ray that
reads it estimates an irradiance of ``field · bins_per_cell``.

A step (:func:`cast_rays`) shoots, from each *side* of each element of the region (an organ, a piece of the
chamber inside the box), cosine-weighted rays from points drawn on it; each ray either leaves the region (its
bin is recorded) or meets an element's side first (that side is recorded).  What the rays read is summed by
:func:`read_field` and the light between elements solved by :func:`solve_passes`.
"""
import math

import numpy as np
from numba import njit

from .embree import GEOM_ID, INVALID_ID, PRIM_ID, RAYHIT
from .ptr import load_u32
from .raylog import RAY_FIELD
from .rays import cast, set_ray
from .rng import seed_stream, uniform
from .sampling import cosine_hemisphere, search_cdf

_TFAR_MAX = 3.0e38
#: a ray's outcome when it met a side that sends no light back (a one-sided piece from behind)
NOTHING = -(1 << 62)


@njit(cache=True)
def field_bin(box, grid, face0, rings, sectors, f, px, py, pz, ix, iy, iz):
    """The bin of the field that light arriving at the point p of face ``f`` in the (inward, unit) direction
    i falls in: an index into the field's bins, (face0[f] + cell) · rings · sectors + direction."""
    a = f // 2
    a1, a2 = (a + 1) % 3, (a + 2) % 3
    p1 = px if a1 == 0 else (py if a1 == 1 else pz)
    p2 = px if a2 == 0 else (py if a2 == 1 else pz)
    c1 = int((p1 - box[a1]) / (box[3 + a1] - box[a1]) * grid[f, 0])
    c2 = int((p2 - box[a2]) / (box[3 + a2] - box[a2]) * grid[f, 1])
    c1 = min(max(c1, 0), grid[f, 0] - 1)
    c2 = min(max(c2, 0), grid[f, 1] - 1)
    d0 = ix if a == 0 else (iy if a == 1 else iz)
    d1 = ix if a1 == 0 else (iy if a1 == 1 else iz)
    d2 = ix if a2 == 0 else (iy if a2 == 1 else iz)
    sin2 = max(0.0, 1.0 - d0 * d0)
    r = min(int(sin2 * rings), rings - 1)
    phi = math.atan2(d2, d1)
    if phi < 0.0:
        phi += 2.0 * math.pi
    k = min(int(phi / (2.0 * math.pi) * sectors), sectors - 1)
    return ((face0[f] + c1 * grid[f, 1] + c2) * rings + r) * sectors + k


@njit(cache=True)
def cell_area(box, grid, f):
    """The area of one cell of face ``f``, scene units²."""
    a = f // 2
    a1, a2 = (a + 1) % 3, (a + 2) % 3
    return (box[3 + a1] - box[a1]) / grid[f, 0] * (box[3 + a2] - box[a2]) / grid[f, 1]


@njit(nogil=True, cache=True)
def bin_crossings(seg, w0, box, grid, face0, rings, sectors, bins, weights):
    """For each stored segment (rows of ``seg``: origin (3), unit direction (3), ..., its weights from column
    ``w0``) that enters the region from outside: its bin, into ``bins`` (n,) (−1: it starts inside the region,
    or misses it), and its weights / the cell's area, into ``weights`` (n, B)."""
    n_b = weights.shape[1]
    for i in range(seg.shape[0]):
        ox, oy, oz, dx, dy, dz = seg[i, 0], seg[i, 1], seg[i, 2], seg[i, 3], seg[i, 4], seg[i, 5]
        lo, hi, face = -math.inf, math.inf, -1
        miss = False
        for a in range(3):
            o = ox if a == 0 else (oy if a == 1 else oz)
            d = dx if a == 0 else (dy if a == 1 else dz)
            if d == 0.0:
                if o < box[a] or o > box[3 + a]:
                    miss = True
                continue
            s1, s2 = (box[a] - o) / d, (box[3 + a] - o) / d
            f = 2 * a
            if s1 > s2:
                s1, s2 = s2, s1
                f = 2 * a + 1
            if s1 > lo:
                lo, face = s1, f
            hi = min(hi, s2)
        bins[i] = -1
        if miss or face < 0 or not lo > 0.0 or lo > hi:
            continue
        px, py, pz = ox + lo * dx, oy + lo * dy, oz + lo * dz
        bins[i] = field_bin(box, grid, face0, rings, sectors, face, px, py, pz, dx, dy, dz)
        inv = 1.0 / cell_area(box, grid, face)
        for b in range(n_b):
            weights[i, b] = seg[i, w0 + b] * inv


@njit(cache=True)
def add_crossings(field, batch, bins, weights):
    """Add the crossings' weights into ``field[batch]`` (bins, B), in their order (the same sums on any number of
    threads when the chunks are added in order)."""
    for i in range(bins.shape[0]):
        k = bins[i]
        if k >= 0:
            for b in range(weights.shape[1]):
                field[batch, k, b] += weights[i, b]


@njit(cache=True)
def _plane_t(a, ox, oy, oz, dx, dy, dz):
    """The distance along the ray o + t·d to the plane of triangle ``a`` (3, 3), in float64 (inf if parallel)."""
    e1x, e1y, e1z = a[1, 0] - a[0, 0], a[1, 1] - a[0, 1], a[1, 2] - a[0, 2]
    e2x, e2y, e2z = a[2, 0] - a[0, 0], a[2, 1] - a[0, 1], a[2, 2] - a[0, 2]
    nx, ny, nz = e1y * e2z - e1z * e2y, e1z * e2x - e1x * e2z, e1x * e2y - e1y * e2x
    den = nx * dx + ny * dy + nz * dz
    if den == 0.0:
        return math.inf
    return (nx * (a[0, 0] - ox) + ny * (a[0, 1] - oy) + nz * (a[0, 2] - oz)) / den


@njit(cache=True)
def _offset(a, offset_rel):
    mag = 0.0
    for v in range(3):
        for c in range(3):
            mag = max(mag, abs(a[v, c]))
    return offset_rel * 2.0 * mag


@njit(cache=True)
def exit_bin(box, grid, face0, rings, sectors, ox, oy, oz, dx, dy, dz):
    """The field's bin that the ray o + t·d (o inside the region) leaves it by: the face whose plane it reaches
    first, the cell there, and the direction the light arrives from (−d)."""
    best, face = math.inf, 0
    for ax in range(3):
        o = ox if ax == 0 else (oy if ax == 1 else oz)
        d = dx if ax == 0 else (dy if ax == 1 else dz)
        if d > 0.0:
            tt, f = (box[3 + ax] - o) / d, 2 * ax + 1
        elif d < 0.0:
            tt, f = (box[ax] - o) / d, 2 * ax
        else:
            continue
        if tt < best:
            best, face = tt, f
    best = max(best, 0.0)
    return field_bin(box, grid, face0, rings, sectors, face, ox + best * dx, oy + best * dy, oz + best * dz,
                     -dx, -dy, -dz)


@njit(cache=True)
def sphere_bin(dx, dy, dz, n_z, n_phi):
    """The bin of the unit direction d on the sphere cut in ``n_z`` bands of d_z (equal areas) × ``n_phi``
    sectors of its azimuth: each bin 4π / (n_z · n_phi) sr."""
    iz = min(max(int((dz + 1.0) * 0.5 * n_z), 0), n_z - 1)
    phi = math.atan2(dy, dx)
    if phi < 0.0:
        phi += 2.0 * math.pi
    return iz * n_phi + min(int(phi / (2.0 * math.pi) * n_phi), n_phi - 1)


@njit(cache=True)
def sphere_direction(b, n_z, n_phi, u1, u2):
    """A direction uniform in sphere bin ``b`` (:func:`sphere_bin`)."""
    iz, ip = b // n_phi, b % n_phi
    z = -1.0 + 2.0 * (iz + u1) / n_z
    r = math.sqrt(max(0.0, 1.0 - z * z))
    phi = 2.0 * math.pi * (ip + u2) / n_phi
    return r * math.cos(phi), r * math.sin(phi), z


@njit(nogil=True, cache=True)
def guide_tables(box, grid, face0, rings, sectors, light, centre, normals, n_z, n_phi, seed, first=0):
    """Where each guided side's light comes from, as drawn by :func:`cast_rays`: for side i (centre (3,) and
    normals (K, 3) of its triangles, drawn by area, turned to the side), each sphere bin (:func:`sphere_bin`)
    weighted by ``light`` (bins,) of the field's bin a ray from the centre in a direction drawn in it leaves the
    region by (the plant not in the way), times the mean over the normals of cos⁺; returns the bins' cumulative
    shares (sides, n_z · n_phi) (rows of zeros: no light).  Row i draws from the random stream (seed, first + i):
    the rows of a slice of the sides (``first``: its first side's index) are those of the whole."""
    n = centre.shape[0]
    nb = n_z * n_phi
    out = np.zeros((n, nb))
    state = np.zeros(1, np.uint64)
    K = normals.shape[1]
    for i in range(n):
        seed_stream(state, seed, first + i)
        acc = 0.0
        for b in range(nb):
            dx, dy, dz = sphere_direction(b, n_z, n_phi, uniform(state), uniform(state))
            c = 0.0
            for k in range(K):
                c += max(0.0, normals[i, k, 0] * dx + normals[i, k, 1] * dy + normals[i, k, 2] * dz)
            if c > 0.0:
                acc += c / K * light[exit_bin(box, grid, face0, rings, sectors, centre[i, 0], centre[i, 1],
                                              centre[i, 2], dx, dy, dz)]
            out[i, b] = acc
        if acc > 0.0:
            for b in range(nb):
                out[i, b] /= acc
            out[i, nb - 1] = 1.0
    return out


@njit(cache=True)
def draw_direction(guide, gi, cosine_share, n_phi, nx, ny, nz, from_cosine, u1, u2, u3):
    """A direction leaving a surface of unit normal n (its side's), from the uniforms u1, u2, u3, and its weight
    against a cosine-weighted draw ((cos θ / π) / density).  ``gi`` < 0: cosine-weighted (u1, u2).  Else from
    the mixture of ``cosine_share`` of the cosine and the rest of guide row ``gi`` (:func:`guide_tables`): drawn
    by the cosine if ``from_cosine``, else a sphere bin by u1 from the row's cumulative shares, uniform within it
    (u2, u3).  Weight 0: a direction behind the surface."""
    if gi < 0:
        dx, dy, dz = cosine_hemisphere(nx, ny, nz, u1, u2)
        return dx, dy, dz, 1.0
    n_guide = guide.shape[1]
    n_z = n_guide // n_phi
    if from_cosine:
        dx, dy, dz = cosine_hemisphere(nx, ny, nz, u1, u2)
    else:
        gb = search_cdf(guide[gi], 0, n_guide - 1, u1)
        dx, dy, dz = sphere_direction(gb, n_z, n_phi, u2, u3)
    c = dx * nx + dy * ny + dz * nz
    if not c > 0.0:
        return dx, dy, dz, 0.0
    gb = sphere_bin(dx, dy, dz, n_z, n_phi)
    p_bin = guide[gi, gb] - (guide[gi, gb - 1] if gb > 0 else 0.0)
    pdf = cosine_share * c / math.pi + (1.0 - cosine_share) * p_bin * n_guide / (4.0 * math.pi)
    return dx, dy, dz, c / (math.pi * pdf)


#: the fractional part of the golden ratio: the second coordinate of a rank-1 lattice of any size
_LATTICE = 0.6180339887498949


@njit(cache=True)
def stratified_directions(state, n, groups, share, lattice, cosine):
    """The first directions' uniforms of a side's ``n`` rays (ray j in group j mod ``groups``): within each
    group, ``round(share · m)`` of its m rays draw from the cosine, the others from the guide (``share`` 1 or 0:
    one kind), each kind's rays at the points of a rank-1 lattice (i / m', frac(i · φ)) shifted at random
    (Cranley–Patterson) and dealt to the rays in a random order: stratified in the square, independent between
    groups.  Fills ``lattice`` (n, 2) and ``cosine`` (n,) bool."""
    m = n // groups
    n_cos = int(round(share * m))
    order = np.empty(m, np.int64)
    for g in range(groups):
        for i in range(m):
            order[i] = i
        for i in range(m - 1, 0, -1):                      # Fisher–Yates
            r = int(uniform(state) * (i + 1))
            order[i], order[r] = order[r], order[i]
        s1, s2, t1, t2 = uniform(state), uniform(state), uniform(state), uniform(state)
        for i in range(m):
            j = g + groups * i
            rank = order[i]
            if rank < n_cos:
                x = (rank + s1) / n_cos
                y = rank * _LATTICE + s2
                cosine[j] = True
            else:
                rank -= n_cos
                x = (rank + t1) / (m - n_cos)
                y = rank * _LATTICE + t2
                cosine[j] = False
            lattice[j, 0] = x - math.floor(x)
            lattice[j, 1] = y - math.floor(y)


@njit(nogil=True, cache=True)
def cast_rays(region, sides, bins, guides, first, last, seed, bounces, groups, scratch, ends):
    """Rays from the element sides ``first .. last − 1`` of the ``region`` (:class:`~kernel.records.Region`):
    ``sides.rays[s]`` from side s (:class:`~kernel.records.RaySides`), written at ``ends.out[ray_start[s]:]``
    (:class:`~kernel.records.RayEnds`): ≥ 0, the triangle side (2 t + 0 front, + 1 back, t a region triangle)
    where the ray's path ends on a surface, whose outgoing light it reads; < 0, −1 − the field's bin (``bins``:
    :class:`~kernel.records.FieldBins`) it left the region by (:data:`NOTHING`: it reads nothing); the triangle
    side it left from into ``ray_tri``, and its path's throughput per band into ``through`` (n, B).  ``scratch``:
    this thread's Embree block (:func:`kernel.embree.new_scratch`'s address).

    Side s's points are drawn on its element's (e = s // 2) triangles ``tris[tri_start[e]:tri_start[e + 1]]`` by
    area (``tri_cdf``: their cumulative share, ending at 1), stratified (ray j in [j, j + 1) / n of the cumulative
    area).  Its directions (:func:`draw_direction`), about the triangle's normal turned to the side (front: along
    the normal): cosine-weighted where ``guide_of[s]`` < 0, else ``cosine_share`` of them cosine-weighted and the
    rest from guide row ``guide_of[s]`` of ``guide`` (:func:`guide_tables`; ``n_phi`` sectors), the path's
    throughput starting at (cos θ / π) / density; stratified within each of the ``groups`` groups of the side's
    rays (:func:`stratified_directions`).  Where a ray meets a surface, its path goes on ``bounces`` times
    (reflected or transmitted, drawn by the band-mean shares of ``reflect`` and ``transmit`` (element sides, B),
    the throughput carrying each band's share over that probability; its direction drawn as above from the side
    it leaves, at random) before it reads the surface's outgoing light: the light
    near the point it met, not the mean of that triangle, is what a surface inside another (a leaf through a bud)
    sends.  Side s's rays use the random stream (seed, s): the same on any number of threads.  ``tri_side``
    (T, 2): the element side a ray meets on triangle t from its front (column 0: the ray against the normal) and
    from its back (column 1); −1, not met from there (one-sided chamber pieces are skipped by Embree itself)."""
    scene, intersect, geom_offset, verts, normal, offset_rel, tri_side = region
    tri_start, tris, tri_cdf, side_rays, ray_start, reflect, transmit, guide_of = sides
    box, grid, face0, rings, sectors = bins
    guide, cosine_share, n_phi = guides
    out, ray_tri, through = ends
    state = np.zeros(1, np.uint64)
    rh = scratch + RAYHIT
    n_b = reflect.shape[1]
    lattice = np.empty((0, 2))
    cosine = np.empty(0, np.bool_)
    for s in range(first, last):
        n = side_rays[s]
        lo, hi = tri_start[s // 2], tri_start[s // 2 + 1]
        if n <= 0 or hi <= lo:
            continue
        sign = 1.0 if s % 2 == 0 else -1.0
        seed_stream(state, seed, s)
        if lattice.shape[0] < n:
            lattice = np.empty((n, 2))
            cosine = np.empty(n, np.bool_)
        gi = guide_of[s]
        stratified_directions(state, n, groups, cosine_share if gi >= 0 else 1.0, lattice, cosine)
        for j in range(n):
            k = ray_start[s] + j
            u = (j + uniform(state)) / n
            t = tris[search_cdf(tri_cdf, lo, hi - 1, u)]
            ray_tri[k] = 2 * t + (s % 2)
            a = verts[t]
            u1, u2 = uniform(state), uniform(state)
            if u1 + u2 > 1.0:
                u1, u2 = 1.0 - u1, 1.0 - u2
            px = a[0, 0] + u1 * (a[1, 0] - a[0, 0]) + u2 * (a[2, 0] - a[0, 0])
            py = a[0, 1] + u1 * (a[1, 1] - a[0, 1]) + u2 * (a[2, 1] - a[0, 1])
            pz = a[0, 2] + u1 * (a[1, 2] - a[0, 2]) + u2 * (a[2, 2] - a[0, 2])
            nx, ny, nz = sign * normal[t, 0], sign * normal[t, 1], sign * normal[t, 2]
            dx, dy, dz, w = draw_direction(guide, gi, cosine_share, n_phi, nx, ny, nz, cosine[j], lattice[j, 0],
                                           lattice[j, 1], uniform(state))
            for b in range(n_b):
                through[k, b] = w
            if w == 0.0:
                out[k] = NOTHING
                continue
            eps = _offset(a, offset_rel)
            ox, oy, oz = px + eps * nx, py + eps * ny, pz + eps * nz
            code = NOTHING
            for bounce in range(bounces + 1):
                set_ray(scratch, ox, oy, oz, dx, dy, dz, _TFAR_MAX)
                cast(intersect, scene, scratch, RAY_FIELD)
                gid = load_u32(rh + GEOM_ID)
                if gid == INVALID_ID:
                    code = -1 - exit_bin(box, grid, face0, rings, sectors, ox, oy, oz, dx, dy, dz)
                    break
                tri = np.int64(load_u32(rh + PRIM_ID)) + geom_offset[gid]
                hnx, hny, hnz = normal[tri, 0], normal[tri, 1], normal[tri, 2]
                back = dx * hnx + dy * hny + dz * hnz > 0.0
                es = tri_side[tri, 1 if back else 0]
                if es < 0:
                    break
                if bounce == bounces:
                    code = 2 * tri + (1 if back else 0)
                    break
                # the path goes on from the point met: reflected to the side it came from, or through
                r_mean, t_mean = 0.0, 0.0
                for b in range(n_b):
                    r_mean += reflect[es, b]
                    t_mean += transmit[es, b]
                if not r_mean + t_mean > 0.0:
                    break
                tt = _plane_t(verts[tri], ox, oy, oz, dx, dy, dz)
                if not math.isfinite(tt):
                    break
                hx, hy, hz = ox + tt * dx, oy + tt * dy, oz + tt * dz
                p_r = r_mean / (r_mean + t_mean)
                side = -1.0 if back else 1.0          # the hit side's normal: towards where the ray came from
                on = es                               # the element side the path leaves from
                if uniform(state) < p_r:
                    for b in range(n_b):
                        through[k, b] *= reflect[es, b] / p_r
                else:
                    side = -side
                    on = es ^ 1
                    for b in range(n_b):
                        through[k, b] *= transmit[es, b] / (1.0 - p_r)
                mx, my, mz = side * hnx, side * hny, side * hnz
                dx, dy, dz, w = draw_direction(guide, guide_of[on], cosine_share, n_phi, mx, my, mz,
                                               uniform(state) < cosine_share, uniform(state), uniform(state),
                                               uniform(state))
                if w == 0.0:
                    break
                for b in range(n_b):
                    through[k, b] *= w
                eps = _offset(verts[tri], offset_rel)
                ox, oy, oz = hx + eps * mx, hy + eps * my, hz + eps * mz
            out[k] = code


@njit(nogil=True, cache=True)
def read_field(out, ray_tri, through, by_bin, field_total, bins_per_cell, ts_side, n_sides):
    """What the rays read, per triangle side (2 t + 0 front, + 1 back) of the region: returns ``rays`` (1 + S,
    n_ts) how many rays left each (all, then each group g: the rays j ≡ g mod S of their side, ``ray_tri``
    order), ``direct`` (1 + S, n_ts, B) the sums of what those that left the region read there (``bins_per_cell``
    × the whole field × the ray's throughput: all rays, then group g's); ``batch`` (S, sides, B) the same sums of
    all the rays against S × batch g of the field alone, by element side (``ts_side``: each triangle side's; the
    field's own spread; ``by_bin`` (bins, S, B): the field bin by bin, each bin's batches side by side in memory,
    where a ray reads them all); and the links: for each ray whose path ended on a surface, its triangle side ``src``, the
    one it ended on ``dst`` and its throughput ``weight`` (links, B), by group: group g's links are
    ``start[g]:start[g + 1]``.  A ray's group is its index mod S (each side's rays start at a multiple of S:
    :func:`lpy_light.estimators.field.side_budget`).  On one thread: :func:`read_rays` over all the rays, then
    :func:`field_links` (``field_step`` reads each part of the rays on the thread that cast it)."""
    S, n_b, n, n_ts = by_bin.shape[1], by_bin.shape[2], out.shape[0], ts_side.shape[0]
    rays = np.zeros((1 + S, n_ts))
    direct = np.zeros((1 + S, n_ts, n_b))
    batch = np.zeros((S, n_sides, n_b))
    met = np.empty(n, np.int64)
    n_met = read_rays(out, ray_tri, through, by_bin, field_total, bins_per_cell, ts_side, 0, n, (rays, direct, batch),
                      met)
    src, dst, weight, start = field_links(out, ray_tri, through, met[:n_met], S)
    return rays, direct, batch, src, dst, weight, start


@njit(nogil=True, cache=True)
def read_rays(out, ray_tri, through, by_bin, field_total, bins_per_cell, ts_side, k0, k1, sums, met):
    """:func:`read_field`'s sums for rays ``k0 .. k1 - 1``, added into ``sums`` = (rays, direct, batch); the rays
    whose path ended on a surface are written, in order, to ``met[k0:]``; returns how many.  Rays of different
    element sides add to different rows: parts of the rays cut between sides can be read on threads of their own,
    each sum in the same order as on one (the same bits)."""
    rays, direct, batch = sums
    S, n_b = by_bin.shape[1], by_bin.shape[2]
    n_met = 0
    for k in range(k0, k1):
        ts = ray_tri[k]
        g = k % S
        rays[0, ts] += 1.0
        rays[1 + g, ts] += 1.0
        code = out[k]
        if code >= 0:
            met[k0 + n_met] = k
            n_met += 1
        elif code != NOTHING:
            j = -1 - code
            for b in range(n_b):
                v = bins_per_cell * through[k, b] * field_total[j, b]
                direct[0, ts, b] += v
                direct[1 + g, ts, b] += v
            es = ts_side[ts]
            if es >= 0:
                for h in range(S):
                    for b in range(n_b):
                        batch[h, es, b] += bins_per_cell * S * through[k, b] * by_bin[j, h, b]
    return n_met


@njit(nogil=True, cache=True)
def field_links(out, ray_tri, through, met, S):
    """The links of :func:`read_field` from ``met``, the rays that ended on a surface in ray order: ``(src, dst,
    weight, start)``, by group (a counting sort): group g's are ``start[g]:start[g + 1]``."""
    n_met, n_b = met.shape[0], through.shape[1]
    start = np.zeros(S + 1, np.int64)
    for i in range(n_met):
        start[met[i] % S + 1] += 1
    for g in range(S):
        start[g + 1] += start[g]
    fill = start[:S].copy()
    src = np.empty(n_met, np.int64)
    dst = np.empty(n_met, np.int64)
    weight = np.empty((n_met, n_b))
    for i in range(n_met):
        k = met[i]
        g = k % S
        p = fill[g]
        fill[g] += 1
        src[p], dst[p] = ray_tri[k], out[k]
        for b in range(n_b):
            weight[p, b] = through[k, b]
    return src, dst, weight, start


@njit(nogil=True, cache=True)
def solve_passes(rays, direct, src, dst, link_w, ts_side, n_sides, reflect, transmit, tol, max_passes, start=None):
    """The irradiance of every element side, (sides, B): what its rays read of the field (``direct``, sums per
    triangle side, ``rays`` their counts: one column of :func:`read_field`'s, with its links) plus the light the triangles send
    each other, passes until the largest change is below ``tol`` × the largest irradiance (or ``max_passes``);
    returns (E of the sides, passes, E of the triangle sides).  ``start`` (triangle sides, B): where the passes
    start (a solve of the same region from other rays; default: what the rays read of the field).

    A triangle side's irradiance is the mean of what its own rays read (the side's mean where it has none); its
    outgoing radiance (E_s · reflect_s + E_s' · transmit_s') / π (s' the other side of the triangle; ``reflect``,
    ``transmit`` (sides, B) by element side, ``ts_side`` (triangle sides,) each one's element side, −1: none): a
    ray that met it reads that.  An element side's irradiance is the mean over its rays."""
    n_ts = ts_side.shape[0]
    n_b = direct.shape[1]
    side_rays = np.zeros(n_sides)
    base = np.zeros((n_sides, n_b))
    for t in range(n_ts):
        s = ts_side[t]
        if s >= 0:
            side_rays[s] += rays[t]
            for b in range(n_b):
                base[s, b] += direct[t, b]
    E_side = np.zeros((n_sides, n_b))
    for s in range(n_sides):
        if side_rays[s] > 0:
            for b in range(n_b):
                E_side[s, b] = base[s, b] / side_rays[s]
    E = np.zeros((n_ts, n_b))
    top = 0.0
    for t in range(n_ts):
        s = ts_side[t]
        if s < 0:
            continue
        for b in range(n_b):
            E[t, b] = direct[t, b] / rays[t] if rays[t] > 0 else E_side[s, b]
            top = max(top, E[t, b])
            if start is not None:
                E[t, b] = start[t, b]
    out = np.zeros((n_ts, n_b))
    acc = np.empty((n_ts, n_b))
    passes = 0
    for it in range(max_passes):
        passes = it + 1
        for t in range(n_ts):
            s, o = ts_side[t], ts_side[t ^ 1]
            for b in range(n_b):
                v = 0.0
                if s >= 0:
                    v = E[t, b] * reflect[s, b]
                if o >= 0:
                    v += E[t ^ 1, b] * transmit[o, b]
                out[t, b] = v
        acc[:, :] = direct
        for p in range(src.shape[0]):
            for b in range(n_b):
                acc[src[p], b] += link_w[p, b] * out[dst[p], b]
        side_sum = np.zeros((n_sides, n_b))
        for t in range(n_ts):
            s = ts_side[t]
            if s >= 0:
                for b in range(n_b):
                    side_sum[s, b] += acc[t, b]
        for s in range(n_sides):
            if side_rays[s] > 0:
                for b in range(n_b):
                    E_side[s, b] = side_sum[s, b] / side_rays[s]
        done = True
        for t in range(n_ts):
            s = ts_side[t]
            if s < 0:
                continue
            for b in range(n_b):
                v = acc[t, b] / rays[t] if rays[t] > 0 else E_side[s, b]
                if abs(v - E[t, b]) > tol * (abs(v) + 1e-3 * top):
                    done = False
                E[t, b] = v
        if done:
            break
    return E_side, passes, E


@njit(nogil=True, cache=True)
def side_links(src, dst, weight, ts_side, n_sides):
    """The links between element sides: each triangle-side link (src, dst, weight (links, B)) summed by the
    element sides (``ts_side``) of its ends; returns (src, dst, weight) of the distinct pairs, by src."""
    n = src.shape[0]
    n_b = weight.shape[1]
    key = np.empty(n, np.int64)
    for p in range(n):
        a, b = ts_side[src[p]], ts_side[dst[p]]
        key[p] = a * n_sides + b if a >= 0 and b >= 0 else -1
    order = np.argsort(key)
    out_src = np.empty(n, np.int64)
    out_dst = np.empty(n, np.int64)
    out_w = np.zeros((n, n_b))
    m = -1
    last = -2
    for i in range(n):
        p = order[i]
        k = key[p]
        if k < 0:
            continue
        if k != last:
            m += 1
            out_src[m], out_dst[m] = k // n_sides, k % n_sides
            last = k
        for b in range(n_b):
            out_w[m, b] += weight[p, b]
    return out_src[:m + 1], out_dst[:m + 1], out_w[:m + 1]


@njit(nogil=True, cache=True)
def side_sums(rays, direct, ts_side, n_sides):
    """The rays and the field's direct sums of each element side, (sides,) and (sides, B), from those of its
    triangle sides."""
    n_b = direct.shape[1]
    r = np.zeros(n_sides)
    d = np.zeros((n_sides, n_b))
    for t in range(ts_side.shape[0]):
        s = ts_side[t]
        if s >= 0:
            r[s] += rays[t]
            for b in range(n_b):
                d[s, b] += direct[t, b]
    return r, d
