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
bounded however near v is.  Meshes too: from a vertex within :data:`NEAR`
bounding radii of a mesh, a triangle is drawn in proportion to the solid angle it
subtends (all of them computed, for meshes of up to :data:`EXACT_TRIANGLES`) and a
direction uniformly within it (:func:`kernel.sampling.spherical_triangle`): the
estimate Ω_total · p(ω) · V is at most 4π · max p per layer of the mesh.  (Larger
meshes: the triangle drawn by area, sampled by solid angle if v is within
:data:`MESH_NEAR` of its radii: Ω_g · A / A_g · p(ω), bounded.)  So no vertex is
too near a mesh, and the light that neighbouring leaves, the stem beside a bud,
the wall behind a leaf scatter to it is estimated at every such vertex instead
of waiting for a photon to cross it: those crossings, counted, held nearly all
of a rose leaf's and bud's variance (a bud's PAR spread 10-29 % over seeds at 1e6
photons with a reported σ of 1-2 %; now 2-6 %, as reported).
Organ targets (the receivers a plant's rules read) are picked in proportion to their importance seen from
the vertex, ~1 / max(d², a²) (:mod:`kernel.importance`), not uniformly: a bud then gets its picks from the leaf
above it rather than from across the chamber.  An organ's own events (from vertices within its near radius)
are each the mean of :data:`OWN_SAMPLES`, and those at vertices on other organs reached straight from a
next-event vertex are replaced by two-step events from every vertex (:mod:`kernel.organ_zones`).
For quads, a vertex closer than :data:`NEAR` times the quad's bounding radius
makes no next event for it, and the segment's real crossing is counted instead
— a fixed split of the path space, so still unbiased.

A disc right beside a wall gets much of its light through the few photons
that land on the wall next to it; :func:`kernel.zones.near_zones` marks those
patches, and :func:`kernel.zones.zone_event` reaches them from every vertex
instead (a two-step next event), the photons that do land there skipping what
it covered.  Next events through a mirror are :mod:`kernel.images`; the targets'
arrays are built by :mod:`kernel.targets`.

Deposits are in photons of weight (a photon leaves its lamp with weight 1 per
band), lengths in scene units, solid angles in steradians.
"""
import math

import numpy as np

from .importance import cluster_cdf, draw, near_cluster
from .jit import helper
from .rays import seen_share
from .records import (ABSORB, DIFFUSE_R, DIFFUSE_T, T_DISC, T_MESH1, T_MESH2, T_QUAD, V_ISOTROPIC,  # noqa: F401
                      V_LAMBERT, V_SURFACE)
from .rng import n_draws, uniform
from .sampling import frame, search_cdf, spherical_triangle, triangle_solid_angle
from .tallies import C_PICK_SHARE, C_PICK_VERTICES, C_SHADOW

# Embree intersects a triangle in float32 from the ray's origin: on a thin sliver (a leaf fan) the plane it
# finds is off by ~1e-5 of the distance (measured: 0.75-1e-5 · d on a 96-triangle disc), so a shadow ray
# to a point ON a mesh target must stop that much short or it is blocked by the target itself.
END_REL = 2.0 ** -13
NEAR = 3.0       # exclusion radius around a quad target (and image events' around a mesh), in bounding radii
EXACT_TRIANGLES = 256   # near a mesh of at most this many triangles, one is drawn by solid angle (all computed)
MESH_NEAR = 4.0  # near a larger mesh, the triangle drawn by area is sampled by solid angle within this · its radius
FAR = 10.0      # discs farther than FAR radii: points drawn by area
NEAR_PICKED = 1.0    # discs nearer than this · radius · √(targets) get their own next event (kernel.targets.near_discs)
NEAR_FLOOR = 2.0     # ... and always those nearer than this · radius (kernel.targets.near_discs)
MESH_OWN = 2.0       # organs always get their own next event from within this · their bounding radius (kernel.targets)
OWN_SAMPLES = 2      # an organ's own next event is the mean of this many: the near light of a bud (the stem and
                     # leaf it touches) varies much over the bud's surface (rose at step 14, 1e6 photons, before
                     # organ zones: buds' far-red spread over seeds 29 % with 1, 17 % with 8; with them, 2 ≈ 8)
ZONE_HEIGHT = 4.0    # a disc whose centre is nearer to a plane than this · its radius gets a zone on it
INV_4PI = 1.0 / (4.0 * math.pi)
#: Picks to organs follow what a vertex can bring them: ``picks`` × min(PICK_CAP, S / S̄) at a vertex of pick
#: share S (:func:`pick_share`), S̄ its mean over a pilot's vertices
# (:meth:`lpy_light.estimators.kernel_scene.KernelScene.records`).
#: Procedural rose, last step, 1.15e6 photons (twentieth session): σ²·CPU of the p90 leaf 34 → 25-28 %²·s, of the
#: median bud 54 → 38-43, for 5 % more shadow rays (``docs/performance.md``, "Picks where the light is").
PICK_CAP = 4.0
SHARE_SCALE = 1024.0    # S / pick_unit is counted in stats.counters[C_PICK_SHARE] in steps of 1 / SHARE_SCALE,
SHARE_CLAMP = 1.0e9     # at most SHARE_CLAMP a vertex: whole numbers, so the sum is the same in any order


@helper
def tri_point(a, u1, u2):
    """A point uniform on triangle ``a`` (3, 3) from two uniforms: ``(x, y, z)``."""
    su = math.sqrt(u1)
    b0, b1 = 1.0 - su, u2 * su
    b2 = 1.0 - b0 - b1
    return (b0 * a[0, 0] + b1 * a[1, 0] + b2 * a[2, 0],
            b0 * a[0, 1] + b1 * a[1, 1] + b2 * a[2, 1],
            b0 * a[0, 2] + b1 * a[1, 2] + b2 * a[2, 2])


@helper
def point_by_solid_angle(ox, oy, oz, a, mx, my, mz, u1, u2):
    """The point of triangle ``a`` (3, 3) of unit normal m met in a direction from o uniform in the triangle's
    solid angle (:func:`kernel.sampling.spherical_triangle`): ``(x, y, z, Ω)``, Ω = 0 where there is none
    (the triangle seen edge-on)."""
    sx, sy, sz, om = spherical_triangle(ox, oy, oz, a[0], a[1], a[2], u1, u2)
    den = sx * mx + sy * my + sz * mz
    if om == 0.0 or den == 0.0:
        return ox, oy, oz, 0.0
    tt = ((a[0, 0] - ox) * mx + (a[0, 1] - oy) * my + (a[0, 2] - oz) * mz) / den
    if not tt > 0.0:
        return ox, oy, oz, 0.0
    return ox + tt * sx, oy + tt * sy, oz + tt * sz, om


@helper
def mesh_point(t, u1, u2, u3, tgt, geo):
    """A point uniform on mesh target t (by area) from three uniforms: ``(triangle, x, y, z)``; u3 picks the
    triangle from t's cumulative areas ``tgt.tri_cdf[tgt.first[t] : tgt.first[t] + tgt.count[t]]``."""
    g = tgt.tri[search_cdf(tgt.tri_cdf, tgt.first[t], tgt.first[t] + tgt.count[t] - 1, u3)]
    px, py, pz = tri_point(geo.verts[g], u1, u2)
    return g, px, py, pz


@helper
def _faces_plane(vx, vy, vz, plane, i):
    """Does the front (its normal's side) of the triangle of row i of ``plane`` (rows of ``Targets.tri_plane``:
    first vertex, unit normal) face point v?"""
    return ((plane[i, 0] - vx) * plane[i, 3] + (plane[i, 1] - vy) * plane[i, 4]
            + (plane[i, 2] - vz) * plane[i, 5]) < 0.0


@helper
def facing_triangle(vx, vy, vz, t, u, tgt, geo):
    """A triangle of mesh target t whose front faces v, drawn by area among those from a uniform ``u``, and their
    total area (scene units²); (-1, 0) if none faces v.  Two passes over t's triangles (a dot product each; the
    areas are the targets' cumulative ones; over views from t's first triangle, indexed from 0: no wraparound
    tests in a loop that buds, 80 triangles each, make ~6 % of a 16-rose step; the facing tests on ``tgt.tri_plane``,
    t's triangles' planes side by side, not gathered from the chamber's arrays: the tests are ~9 % of a rose step by
    perf, the layout did not measurably change it)."""
    first, count = tgt.first[t], tgt.count[t]
    tri, cum = tgt.tri[first:first + count], tgt.tri_cdf[first:first + count]
    plane = tgt.tri_plane[first:first + count]
    share, prev = 0.0, 0.0
    for i in range(count):       # without a branch on the facing test (half of a bud's triangles face v, at
        c = cum[i]               # random: a mispredicted branch each time): a triangle that does not face v adds
        share += (c - prev) * _faces_plane(vx, vy, vz, plane, i)  # (its area) × 0 -- the same sum, bit for bit
        prev = c
    if not share > 0.0:
        return -1, 0.0
    goal, run, last, prev = u * share, 0.0, -1, 0.0
    for i in range(count):
        g, c = tri[i], cum[i]
        f = _faces_plane(vx, vy, vz, plane, i)
        run += (c - prev) * f
        last = g if f else last
        prev = c
        if f & (run >= goal):
            break
    return last, share * tgt.area[t]


@helper
def _triangle_by_solid_angle(vx, vy, vz, t, u, tgt, geo):
    """A triangle of mesh target t drawn in proportion to the solid angle it subtends from v, and the sum of
    those solid angles (sr); (-1, 0) if t is seen edge-on.  Two passes over t's triangles."""
    first, count = tgt.first[t], tgt.count[t]
    total = 0.0
    for i in range(first, first + count):
        total += triangle_solid_angle(vx, vy, vz, geo.verts[tgt.tri[i], 0], geo.verts[tgt.tri[i], 1],
                                      geo.verts[tgt.tri[i], 2])
    if not total > 0.0:
        return -1, 0.0
    goal, run = u * total, 0.0
    for i in range(first, first + count):
        om = triangle_solid_angle(vx, vy, vz, geo.verts[tgt.tri[i], 0], geo.verts[tgt.tri[i], 1],
                                  geo.verts[tgt.tri[i], 2])
        run += om
        if run > goal and om > 0.0:
            return tgt.tri[i], total
    for i in range(first + count - 1, first - 1, -1):      # rounding: the last triangle with an angle
        g = tgt.tri[i]
        if triangle_solid_angle(vx, vy, vz, geo.verts[g, 0], geo.verts[g, 1], geo.verts[g, 2]) > 0.0:
            return g, total
    return -1, 0.0


@helper
def _near_triangle(vx, vy, vz, a):
    """Is v within :data:`MESH_NEAR` bounding radii (about its centroid) of triangle ``a`` (3, 3)?  There a point
    drawn by area would give a next event ∝ A / d², unbounded as v nears the triangle."""
    cx, cy, cz = (a[0, 0] + a[1, 0] + a[2, 0]) / 3.0, (a[0, 1] + a[1, 1] + a[2, 1]) / 3.0, (a[0, 2] + a[1, 2] + a[2, 2]) / 3.0
    r2 = 0.0
    for i in range(3):
        ex, ey, ez = a[i, 0] - cx, a[i, 1] - cy, a[i, 2] - cz
        r2 = max(r2, ex * ex + ey * ey + ez * ez)
    ex, ey, ez = vx - cx, vy - cy, vz - cz
    return ex * ex + ey * ey + ez * ez < MESH_NEAR * MESH_NEAR * r2


@helper
def _tri_area(c, i, j, k):
    ax, ay, az = c[j, 0] - c[i, 0], c[j, 1] - c[i, 1], c[j, 2] - c[i, 2]
    bx, by, bz = c[k, 0] - c[i, 0], c[k, 1] - c[i, 1], c[k, 2] - c[i, 2]
    cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    return 0.5 * math.sqrt(cx * cx + cy * cy + cz * cz)


@helper
def sensor_point(kind, s, u1, u2, u3, sens):
    """A point uniform on transparent sensor s (a disc, kind T_DISC, or a planar quad) from three uniforms."""
    center = sens.center
    if kind == T_DISC:
        tb, bb = frame(sens.normal[s, 0], sens.normal[s, 1], sens.normal[s, 2])
        r = sens.radius[s] * math.sqrt(u1)
        c, sn = r * math.cos(2.0 * math.pi * u2), r * math.sin(2.0 * math.pi * u2)
        return (center[s, 0] + c * tb[0] + sn * bb[0], center[s, 1] + c * tb[1] + sn * bb[1],
                center[s, 2] + c * tb[2] + sn * bb[2])
    cq = sens.corners[s]
    a0 = _tri_area(cq, 0, 1, 2)
    a1 = _tri_area(cq, 0, 2, 3)
    su = math.sqrt(u1)
    b0, b1 = 1.0 - su, u2 * su
    b2 = 1.0 - b0 - b1
    k1, k2 = (1, 2) if u3 * (a0 + a1) < a0 else (2, 3)
    return (b0 * cq[0, 0] + b1 * cq[k1, 0] + b2 * cq[k2, 0], b0 * cq[0, 1] + b1 * cq[k1, 1] + b2 * cq[k2, 1],
            b0 * cq[0, 2] + b1 * cq[k1, 2] + b2 * cq[k2, 2])


@helper
def disc_point_by_solid_angle(vx, vy, vz, s, u1, u2, sens):
    """A point x on disc s drawn as seen from v, and the estimator's factor ``|cos θ_x| / |x − v|² / pdf_A(x)``
    (steradians), whose mean is the disc's solid angle seen from v.

    Polar coordinates (ρ, φ) about v's foot F on the disc's plane, v at height h in front of it: φ uniform
    over the directions in which rays from F meet the disc (all of them when F is on the disc), then along
    that ray the cosine of the angle at v uniform between its values at the disc's near and far edges
    (exact solid-angle sampling along each ray).  The factor is Δφ · (cos_near − cos_far) ≤ 2π: bounded
    however near v is to the disc, where uniform points on the disc give A·h/d³, heavy-tailed as d → 0.
    Returns ``(x, y, z, factor)``; factor 0 when v is not in front of the disc.
    """
    cx, cy, cz = sens.center[s, 0], sens.center[s, 1], sens.center[s, 2]
    mx, my, mz = sens.normal[s, 0], sens.normal[s, 1], sens.normal[s, 2]
    a = sens.radius[s]
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


@helper
def view_factors(mode):
    """(c0, c1): the pdf of leaving a vertex of this mode towards direction ω is c0 + c1 · |cos| (for a
    surface, times the band's diffuse probability on that side)."""
    if mode == V_ISOTROPIC:
        return INV_4PI, 0.0
    return 0.0, 1.0 / math.pi


ZERO32 = np.float32(0.0)
_ONE32 = np.float32(1.0)
_TINY32 = np.float32(1e-30)


@helper
def gamma32(v, n, c0, c1, c, m, area):
    """γ of a sensor of centre c, unit normal m and area A seen from v (unit normal n), in float32:
    A · cos θ_c / d² · (c0 + c1 |cos θ_v|), or ≤ 0 when v is behind the sensor's plane (all arguments
    float32, points and vectors as 3-tuples: the same arithmetic in :func:`point_view` and the vectorised
    loop of :func:`kernel.control.control_deposits`, so both get the same bits)."""
    vx, vy, vz = v
    nx, ny, nz = n
    cx, cy, cz = c
    mx, my, mz = m
    ex, ey, ez = cx - vx, cy - vy, cz - vz
    d2 = max(ex * ex + ey * ey + ez * ez, _TINY32)
    hd = -(ex * mx + ey * my + ez * mz)                    # h · d
    inv_d = _ONE32 / math.sqrt(d2)
    cos_v = (ex * nx + ey * ny + ez * nz) * inv_d
    return area * hd * (inv_d * inv_d * inv_d) * (c0 + c1 * math.fabs(cos_v))


@helper
def point_view(t, v, tgt, sens):
    """Sensor target t's next event from vertex v as if t were a point at its centre: ``(γ, cos_v)``.

    γ = A · cos θ_c / d_c² · p(ω_c), without the band factor of a surface vertex (its ``P_dR,b`` for
    cos_v > 0, ``P_dT,b`` below); 0 where v is behind the sensor's plane (so is the true value).  The
    control variate of :func:`next_event`: deposited to every sensor at every vertex
    (:func:`kernel.control.control_deposits`), and subtracted from each pick, so that a pick only carries
    the difference between the true, occluded value and γ.  Computed in float32 (:func:`gamma32`) from
    the float32 values of the same arrays as the deposits, so that the two cancel exactly on average."""
    s = tgt.ref[t]
    c0, c1 = view_factors(v.mode)
    f32 = np.float32
    x32, y32, z32 = f32(v.x), f32(v.y), f32(v.z)
    n32x, n32y, n32z = f32(v.nx), f32(v.ny), f32(v.nz)
    cx, cy, cz = f32(tgt.center[t, 0]), f32(tgt.center[t, 1]), f32(tgt.center[t, 2])
    g = gamma32((x32, y32, z32), (n32x, n32y, n32z), f32(c0), f32(c1), (cx, cy, cz),
                (f32(sens.normal[s, 0]), f32(sens.normal[s, 1]), f32(sens.normal[s, 2])), f32(tgt.area[t]))
    if not g > ZERO32:
        return 0.0, 0.0
    ex, ey, ez = cx - x32, cy - y32, cz - z32
    up = ex * n32x + ey * n32y + ez * n32z > ZERO32
    if v.mode == V_LAMBERT and not up:
        return 0.0, -1.0
    return float(g), (1.0 if up else -1.0)


@helper
def _zone_of(t, pid, zones):
    """Has disc target t a zone (:func:`kernel.zones.near_zones`) on plane ``pid``?"""
    for z in range(zones.start[t], zones.start[t + 1]):
        if zones.target_plane[z, 1] == pid:
            return True
    return False


@helper
def next_event(v, stat, cover, control, geo, mat, sens, tgt, zones, organs, photon, stats):
    """Expected deposits of the segment leaving vertex ``v`` (:class:`~kernel.records.Vertex`) on every target;
    returns how many were written.

    v (scene units) with unit normal n (for Lambertian emission: the emitter's normal; for a surface: the
    side the photon arrived from), its mode (V_ISOTROPIC, V_LAMBERT or V_SURFACE of material m) and its
    round-off scale: shadow rays start and stop ``geo.offset_rel`` · max(|v|, scale) off surfaces.  The
    photon's weights are ``photon.w`` (B,).  Deposits go to ``photon.out_k[i]`` (tally row) and
    ``photon.out_w[i, :]`` for i < the returned count.  ``stats.nee_stats[stat]``
    counts shadow rays cast and found unblocked, and sums the weight they deposit (to switch off vertices
    that never see a target: see :func:`lpy_light.estimators.kernel_scene.KernelScene.prune_next_events`).
    ``tgt.picks`` > 0: only that many targets, drawn uniformly (with replacement), each deposit scaled by
    n_targets / picks — unbiased, and a vertex then costs ``picks`` shadow rays instead of one per target.
    With picks, a target nearer to v than √``tgt.near_r2[t]`` gets a next event of its own, unscaled (a
    mesh: :data:`OWN_SAMPLES` of them, each weighted 1 / OWN_SAMPLES), and is skipped by the picks: a random
    pick would deposit n_targets / picks times its large expected value, rarely (see
    :func:`kernel.targets.near_discs`).  Its candidates are
    ``tgt.near_list[tgt.near_start[v.tri] : tgt.near_start[v.tri + 1]]``.  ``control``: the control variate
    is on (:mod:`kernel.control`): each pick of a sensor subtracts its γ.
    ``cover`` = (cover_pid, n_chain).  ``cover_pid`` ≥ 0: v is a vertex on plane ``cover_pid`` reached
    straight from a next-event vertex, whose zone events (:func:`kernel.zones.zone_event`) already served the
    near discs that have a zone on this plane: their own events are skipped here.  ``n_chain`` > 0: v is the last
    of the organ vertices ``photon.chain[:n_chain]``, each reached straight from the one before, a next-event
    vertex; the own events of the organ targets near v (all but v's own organ) that organ zone events served
    (:func:`zone_served`) are skipped here.  ``organs``
    (:class:`~kernel.records.OrganEvents`, or None: sensors, drawn uniformly): picks drawn by importance
    (:mod:`kernel.importance`), and where ``organs.pick_mean`` > 0 as many as the vertex's pick share asks
    (:data:`PICK_CAP`): a whole number of mean ``picks`` × min(PICK_CAP, S / pick_mean), drawn before the
    picks, each deposit divided by that mean (unbiased); the share S is counted in ``stats.counters``.
    A point on a mesh target is seen when the first surface met on the way is the target's, at x
    (:func:`kernel.rays.reaches`); a sensor's, when nothing is in the way (a shadow ray).
    """
    vx, vy, vz, nx, ny, nz, mode, m, vscale, vtri = v
    cover_pid, n_chain = cover
    w, out_k, out_w, state = photon.w, photon.out_k, photon.out_w, photon.state
    picks = tgt.picks
    near_start, near_r2 = tgt.near_start, tgt.near_r2
    n_bands = w.shape[0]
    n_out = 0
    n_tgt = tgt.kind.shape[0]
    if picks > 0 and picks < n_tgt:
        n_iter, scale = picks, n_tgt / picks
    else:
        n_iter, scale = n_tgt, 1.0
    n_near = near_start[vtri + 1] - near_start[vtri] if scale != 1.0 and vtri >= 0 else 0
    total = 0.0
    mean = float(n_iter)      # picks at this vertex, on average
    if organs is not None and scale != 1.0:   # importances of the targets not served by an own event here
        how = (organs.near_weight, organs.cluster_weight, tgt.img_near2, NEAR * NEAR, n_near > 0,
               organs.far_weight)
        total = cluster_cdf((vx, vy, vz), how, organs.clusters, tgt, photon.cdf, photon.exact)
        if not total > 0.0:
            n_iter = 0
        else:                 # as many picks as the vertex can bring light (PICK_CAP), drawn before any pick
            share = pick_share(w, total, mode, m, organs)
            stats.counters[C_PICK_SHARE] += np.int64(min(share / organs.pick_unit, SHARE_CLAMP) * SHARE_SCALE)
            stats.counters[C_PICK_VERTICES] += 1
            if organs.pick_mean > 0.0:
                mean = picks * min(PICK_CAP, share / organs.pick_mean)
                n_iter = n_draws(mean, state)
    for j in range(n_near + n_iter):
        if j < n_near:            # a near target: its own next event
            t = tgt.near_list[near_start[vtri] + j]
            tscale = 1.0
        elif organs is not None:  # a pick in proportion to the target's importance seen from v
            t, p_t = draw(uniform(state), uniform(state), total, (vx, vy, vz), how, organs.clusters, tgt,
                          photon.cdf, photon.exact)
            if t < 0:
                continue
            tscale = 1.0 / (mean * p_t)
        else:
            t = j - n_near if scale == 1.0 else min(int(uniform(state) * n_tgt), n_tgt - 1)
            tscale = scale
        ex, ey, ez = vx - tgt.center[t, 0], vy - tgt.center[t, 1], vz - tgt.center[t, 2]
        d2c = ex * ex + ey * ey + ez * ez
        if n_near > 0 and (d2c < near_r2[t]) != (j < n_near):
            continue          # a near target is served by its own event only; a listed one that is not near, by picks
        if j < n_near and cover_pid >= 0 and _zone_of(t, cover_pid, zones):
            continue          # served by the zone events of the vertex this photon came from
        if (j < n_near and organs is not None and organs.near_weight[t] == 0.0
                and near_cluster(t, vx, vy, vz, organs)):
            continue          # a large target of a cluster v is near: served by local rays (kernel.cones)
        kind = tgt.kind[t]
        if j < n_near and kind >= T_MESH2 and n_chain > 0 and organs is not None:
            oz = organs.zones     # t has organ zone events (buds), and v is on its zone:
            if oz.weight[t] > 0.0 and (geo.receiver[vtri] != tgt.ref[t] or oz.own[t] != 0):
                if zone_served(t, n_chain, photon.chain, geo, tgt, organs):
                    continue  # served by the organ zone events of a vertex this photon came from
        reps = OWN_SAMPLES if j < n_near and kind >= T_MESH2 else 1    # a mesh's own events: their mean
        for r in range(reps):
            u1, u2, u3 = uniform(state), uniform(state), uniform(state)
            if d2c < tgt.near2[t]:
                break         # too close: 1/d² would be heavy-tailed; this segment's crossings are counted
            if (control and r == 0 and scale != 1.0 and j >= n_near and kind <= T_QUAD   # a pick, not an own event,
                    and not (kind == T_DISC and d2c < (NEAR_FLOOR * sens.radius[tgt.ref[t]]) ** 2)):  # γ a fair guess
                gam, cg = point_view(t, v, tgt, sens)
                if gam > 0.0:
                    out_k[n_out] = tgt.row[t]
                    for b in range(n_bands):
                        f = 1.0 if mode != V_SURFACE else mat.prob[m, DIFFUSE_R if cg > 0.0 else DIFFUSE_T, b]
                        out_w[n_out, b] = -w[b] * gam * f * tscale
                    n_out += 1
            n_out = target_event(v, (t, d2c, tscale / reps), w, (u1, u2, u3), stat, geo, mat, sens, tgt, photon,
                                 stats, n_out)
    return n_out


@helper
def mean_weight(w):
    """The mean over the bands of a photon's weights ``w`` (B,)."""
    s = 0.0
    for b in range(w.shape[0]):
        s += w[b]
    return s / w.shape[0]


@helper
def pick_share(w, total, mode, m, organs):
    """A vertex's pick share S: its photon's mean weight over the bands (``w`` (B,)) × the larger of its
    material's diffuse reflectance and transmittance, band mean (``organs.pick_side[m]``; 1 at a lamp) × the sum
    ``total`` of the targets' importances seen from it (:func:`kernel.importance.cluster_cdf`, ∝ 1 / d²): about
    the light its next events to organs can bring them.  The deposit of a pick is ∝ S / (picks drawn), so picks
    ∝ S leave every pick about the same deposit (:data:`PICK_CAP`)."""
    side = organs.pick_side[m] if mode == V_SURFACE else 1.0
    return mean_weight(w) * side * total


@helper
def zone_served(t, n_chain, chain, geo, tgt, organs):
    """Did the organ zone events of an earlier vertex serve the own event for organ target t (one with a zone) at
    this vertex, the last of ``chain[:n_chain]`` (:class:`~kernel.records.Photon`: the organ vertices met one
    straight after the other, each reached from a next-event vertex)?  Yes if it was reached by a leg at least
    t's near radius long (:func:`kernel.organ_zones.organ_zone_event`), or by short legs on t's zone after such a
    one, ``organs.zones.walk`` at most (:func:`kernel.organ_zones.zone_walk`)."""
    near_r2 = tgt.near_r2[t]
    cx, cy, cz = tgt.center[t, 0], tgt.center[t, 1], tgt.center[t, 2]
    last = n_chain - 1
    for i in range(last, max(last - organs.zones.walk, 0) - 1, -1):
        tri = np.int64(chain[i, 3])
        if i < last:          # an earlier vertex of the walk: within t's near radius too (on t itself or not)
            ex, ey, ez = chain[i, 0] - cx, chain[i, 1] - cy, chain[i, 2] - cz
            if not (ex * ex + ey * ey + ez * ez < near_r2 and near_listed(t, tri, tgt)):
                return False
        if chain[i, 4] >= near_r2:   # reached by a long leg: a zone event served it (on t's zone), and the walk
            return geo.receiver[tri] != tgt.ref[t] or organs.zones.own[t] != 0    # the short legs after
    return False


@helper
def near_listed(t, tri, tgt):
    """Is target t in triangle ``tri``'s near list (a vertex there within its near radius makes its own event)?"""
    for i in range(tgt.near_start[tri], tgt.near_start[tri + 1]):
        if tgt.near_list[i] == t:
            return True
    return False


@helper
def target_event(v, pick, w, u, stat, geo, mat, sens, tgt, photon, stats, n_out):
    """One next event from vertex ``v`` to a target, ``pick`` = (t, |v − t's centre|², weight), for a photon of
    weights ``w`` (B,), from three uniforms ``u``: a point x on t (a disc's by solid angle, a mesh's triangle
    by solid angle near it, else by area), the leaving pdf towards x, and one ray for what is in the way.
    Writes t's deposit (and, for a mesh with an absorbed row, what the side met absorbs) from
    ``photon.out_k[n_out]`` / ``photon.out_w[n_out]`` on; returns the new count."""
    vx, vy, vz, nx, ny, nz, mode, m, vscale, vtri = v
    t, d2c, tscale = pick
    u1, u2, u3 = u
    vmag = max(abs(vx), abs(vy), abs(vz), vscale)
    contrib = photon.contrib
    counters, nee_stats = stats.counters, stats.nee_stats
    n_bands = w.shape[0]
    kind = tgt.kind[t]
    g = -1
    omega = 0.0
    area_t = tgt.area[t]
    if kind == T_DISC:
        s = tgt.ref[t]
        mx, my, mz = sens.normal[s, 0], sens.normal[s, 1], sens.normal[s, 2]
        if d2c > (FAR * sens.radius[s]) ** 2:    # far: uniform on the disc, A |cos θ_x| / d² nearly constant
            if (vx - sens.center[s, 0]) * mx + (vy - sens.center[s, 1]) * my + (vz - sens.center[s, 2]) * mz <= 0.0:
                return n_out
            px, py, pz = sensor_point(kind, s, u1, u2, u3, sens)
            kind = T_QUAD      # from here on: a point drawn by area
        else:
            px, py, pz, omega = disc_point_by_solid_angle(vx, vy, vz, s, u1, u2, sens)
            if omega == 0.0:
                return n_out     # behind the sensor's plane: cannot cross it from the front
    elif kind == T_QUAD:
        s = tgt.ref[t]
        mx, my, mz = sens.normal[s, 0], sens.normal[s, 1], sens.normal[s, 2]
        if (vx - sens.center[s, 0]) * mx + (vy - sens.center[s, 1]) * my + (vz - sens.center[s, 2]) * mz <= 0.0:
            return n_out
        px, py, pz = sensor_point(kind, s, u1, u2, u3, sens)
    else:
        near = d2c < tgt.img_near2[t]          # within NEAR bounding radii of the mesh
        if near and tgt.count[t] <= EXACT_TRIANGLES:
            # a triangle drawn in proportion to the solid angle it subtends: Ω_total · p(ω) · V, at most
            # 4π · max p per layer of the mesh however near v is, and no lottery among its triangles
            g, om_total = _triangle_by_solid_angle(vx, vy, vz, t, u3, tgt, geo)
            if g < 0:
                return n_out
        elif tgt.facing[t] != 0 and not near:
            # from beyond NEAR radii only the triangles facing v can be seen (a closed mesh's far side is behind
            # its near side; a one-sided mesh's back receives nothing): a triangle drawn by area among those,
            # A_facing · |cos θ_x| / d² · p(ω) · V -- not half the points, on a bud, on its hidden side
            g, area_t = facing_triangle(vx, vy, vz, t, u3, tgt, geo)
            if g < 0:
                return n_out
            px, py, pz = tri_point(geo.verts[g], u1, u2)
            om_total = 0.0
        else:
            # a triangle drawn by area: where v is near it (a large mesh), Ω_g · A / A_g · p(ω) · V, bounded
            g, px, py, pz = mesh_point(t, u1, u2, u3, tgt, geo)
            om_total = tgt.area[t] / _tri_area(geo.verts[g], 0, 1, 2) if near and _near_triangle(
                vx, vy, vz, geo.verts[g]) else 0.0
        mx, my, mz = geo.normal[g, 0], geo.normal[g, 1], geo.normal[g, 2]
        if om_total > 0.0:                     # a direction uniform in the triangle's solid angle
            px, py, pz, om = point_by_solid_angle(vx, vy, vz, geo.verts[g], mx, my, mz, u1, u2)
            if om == 0.0:
                return n_out
            omega = om_total if near and tgt.count[t] <= EXACT_TRIANGLES else om * om_total
    dx, dy, dz = px - vx, py - vy, pz - vz
    dist2 = dx * dx + dy * dy + dz * dz
    if not dist2 > 0.0:
        return n_out
    dist = math.sqrt(dist2)
    dx, dy, dz = dx / dist, dy / dist, dz / dist
    cos_x = dx * mx + dy * my + dz * mz
    if kind != T_MESH2 and cos_x >= 0.0:
        return n_out          # sensors and one-sided receivers are met from the front only
    geom = tscale * (omega if omega > 0.0 else area_t * abs(cos_x) / dist2)
    cos_v = dx * nx + dy * ny + dz * nz
    if mode == V_ISOTROPIC:
        for b in range(n_bands):
            contrib[b] = w[b] * INV_4PI * geom
        side = 0.0
    elif mode == V_LAMBERT:
        if cos_v <= 0.0:
            return n_out
        for b in range(n_bands):
            contrib[b] = w[b] * cos_v / math.pi * geom
        side = 1.0
    else:
        ev = DIFFUSE_R if cos_v > 0.0 else DIFFUSE_T
        any_light = False
        for b in range(n_bands):
            contrib[b] = w[b] * mat.prob[m, ev, b] * abs(cos_v) / math.pi * geom
            any_light = any_light or contrib[b] > 0.0
        if not any_light:
            return n_out
        side = 1.0 if cos_v > 0.0 else -1.0
    pmag = max(abs(px), abs(py), abs(pz))
    if g >= 0:      # a mesh target is a surface: its triangle's round-off
        for i in range(3):
            for k in range(3):
                pmag = max(pmag, abs(geo.verts[g, i, k]))
    eps = geo.offset_rel * (vmag + pmag)
    tol = 2.0 * eps
    if g >= 0:      # a mesh target's plane has a float32 error seen from v (END_REL · d)
        tol += END_REL * dist
    if dist - tol <= 0.0:
        return n_out
    counters[C_SHADOW] += 1
    nee_stats[stat, 0] += 1
    ox, oy, oz = vx + side * eps * nx, vy + side * eps * ny, vz + side * eps * nz
    # the shadow ray aimed from its offset origin at x: parallel to v -> x it would meet x's plane eps·(n·m)/cos_x
    # away from x, outside reaches()' window of 2·eps + END_REL·dist wherever x is met at a grazing angle from a
    # vertex a few mm away -- own events inside and beside buds, between leaves: in far red, where organs hardly
    # absorb and much of their light comes by such short legs, nee was 7 % low on the rose's buds (weighted and
    # analog agreed with each other; docs/physics.md, next-event tallies)
    sx, sy, sz = px - ox, py - oy, pz - oz
    dist = math.sqrt(sx * sx + sy * sy + sz * sz)
    dx, dy, dz = sx / dist, sy / dist, sz / dist
    leg = photon.leg
    leg[0], leg[1], leg[2], leg[3], leg[4], leg[5] = ox, oy, oz, dx, dy, dz
    return seen_deposit(t, g, cos_x, ((ox, oy, oz), (dx, dy, dz), (px, py, pz), dist, tol), (stat, stat), geo, mat,
                        tgt, photon, stats, n_out)


@helper
def seen_deposit(t, g, cos_x, leg, rows, geo, mat, tgt, photon, stats, n_out):
    """The last leg of a next event to target t: ``leg`` = (origin, unit direction, x, its length, tolerance);
    ``photon.contrib`` (B,) times the share of x that is seen (:func:`kernel.rays.seen_share`), deposited by
    :func:`deposit` (triangle g, cosine ``cos_x``, ``rows``) unless nothing is.  Returns the new count."""
    origin, direction, point, dist, tol = leg
    share = seen_share(g, geo, photon.scratch, origin, direction, dist - tol, dist + tol, tgt.ref[t], point)
    if share == 0.0:
        return n_out
    contrib = photon.contrib
    for b in range(contrib.shape[0]):
        contrib[b] *= share
    return deposit(t, g, cos_x, rows, geo, mat, tgt, photon, stats, n_out)


@helper
def deposit(t, g, cos_x, rows, geo, mat, tgt, photon, stats, n_out):
    """Write a next event's deposit ``photon.contrib`` (B,) on target t's row from ``photon.out_k[n_out]`` on,
    and, for a mesh (triangle g, met at cosine ``cos_x``) with an absorbed row, what the side met absorbs; count
    it in ``stats.nee_stats`` at ``rows`` = (r1, r2) (found, weight; once where r1 == r2).  Returns the new
    count."""
    contrib, out_k, out_w, nee_stats = photon.contrib, photon.out_k, photon.out_w, stats.nee_stats
    r1, r2 = rows
    nee_stats[r1, 1] += 1
    if r2 != r1:
        nee_stats[r2, 1] += 1
    out_k[n_out] = tgt.row[t]
    weight = 0.0
    for b in range(contrib.shape[0]):
        out_w[n_out, b] = contrib[b]
        weight += contrib[b]
    nee_stats[r1, 2] += weight
    if r2 != r1:
        nee_stats[r2, 2] += weight
    n_out += 1
    if g >= 0 and tgt.abs_row[t] >= 0:
        mm = geo.material[g, 0] if cos_x < 0.0 else geo.material[g, 1]
        out_k[n_out] = tgt.abs_row[t]
        for b in range(contrib.shape[0]):
            out_w[n_out, b] = contrib[b] * mat.prob[mm, ABSORB, b]
        n_out += 1
    return n_out
