"""The hot loop: trace a chunk of photons from the lamps until absorbed, escaped or cut.

One call traces photons ``first .. first + count - 1`` of a run through the scene's records
(:class:`kernel.records.Scene`: geometry, materials, emitters, sensors, next-event targets, mirrors, zones,
control variate).  Everything the loop finds is *added* to the chunk's :class:`~kernel.records.Tallies`
(photons of weight per row and band, :mod:`kernel.tallies`), so a caller can reduce chunks in a fixed order
and get the same sums on any number of threads.

Physics (SEC2's model, see ``docs/physics.md``):

* at a surface hit one event is drawn: diffuse reflection, specular reflection,
  diffuse transmission, specular transmission or absorption;
* all spectral bands travel together: the event e is drawn with a probability
  q_e shared by the bands and each band's weight is multiplied by P_e,b / q_e,
  which is unbiased for every band.  Two estimators choose q (see
  :func:`lpy_light.chamber.materials.sampling_tables`):

  - ``analog`` (SEC2's counting): q_e = P_e,b of each band, one path per band,
    absorption deposits the photon's weight where it ends — exactly analog;
  - ``weighted`` (and ``nee``): at every hit the expected absorbed weight
    w_b·P_abs,b is deposited; then a scattering event is drawn with
    q_e = max_b P_e,b (the photon ends with the remaining probability), so no
    band's weight ever grows — bands as different as a 20% and an 80% wall
    stay as precise as their own analog runs;
* where surfaces coincide (same plane, overlapping), a hit picks one of those
  containing the point and facing the ray, uniformly at random, rather than
  whichever Embree's float32 arithmetic happens to find (:func:`kernel.rays.pick_coplanar`);
* transparent sensors record each crossing from their front side at the
  photon's current weight; receivers (solid sensors, organs) record each hit
  (incident) and the weight absorbed on them;
* with ``nee``, every vertex where the photon leaves diffusely makes next events
  (:mod:`kernel.nee`, through mirrors :mod:`kernel.images`, through zones beside
  discs :mod:`kernel.zones` and beside organs :mod:`kernel.organ_zones`, with the
  control variate :mod:`kernel.control`), and the crossings, hits and own events
  those cover are not counted.

Positions in scene units; a new ray starts ``geo.offset_rel`` · (its round-off scale) off the surface it
leaves (``docs/stability.md``).
"""
import math

import numpy as np
from numba import njit

from .cones import CONE_DATA, cone_events, local_events
from .control import add_control, control_deposits, control_products, fold_control
from .embree import CAND, CAND_CAP, CAND_COUNT, GEOM_ID, INVALID_ID, PRIM_ID, RAYHIT
from .emission import emit, pick_element
from .images import double_image_counted, double_image_event, image_counted, image_event
from .jit import helper
from .nee import OWN_SAMPLES, next_event
from .organ_zones import organ_zone_event
from .ptr import load_f32, load_i64, load_u32
from .raylog import RAY_PHOTON
from .rays import cast, hit_point, magnitude, pick_coplanar, set_ray
from .records import (ABSORB, DIFFUSE_R, DIFFUSE_T, REPLAY_CONTINUE, REPLAY_STORE, SENSOR_DISC, SPECULAR_R, START_W,
                      V_SURFACE, VPL_W, Accumulator, ControlWork, Photon, Vertex)
from .rng import n_draws, seed_stream, uniform
from .sampling import cosine_hemisphere, mirror, phong_lobe
from .tallies import (C_BATCHES, C_CAND_OVERFLOW, C_LOST, C_RAYS, N_COUNTERS, fate_rows, flush,  # noqa: F401
                      record, record_all)
from .warm import share_compile
from .zones import zone_event

_TFAR_MAX = 3.0e38


@helper
def _inside(s, px, py, pz, sens):
    """Is the point p (on the sensor's plane) inside sensor s?  Exact for discs and quads."""
    center, corners, normal = sens.center, sens.corners, sens.normal
    if sens.kind[s] == SENSOR_DISC:
        ex, ey, ez = px - center[s, 0], py - center[s, 1], pz - center[s, 2]
        return ex * ex + ey * ey + ez * ez <= sens.radius[s] * sens.radius[s]
    # convex quad: p must lie left of every edge, seen along the normal
    for i in range(4):
        j = (i + 1) % 4
        ax, ay, az = corners[s, j, 0] - corners[s, i, 0], corners[s, j, 1] - corners[s, i, 1], corners[s, j, 2] - corners[s, i, 2]
        bx, by, bz = px - corners[s, i, 0], py - corners[s, i, 1], pz - corners[s, i, 2]
        cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
        if cx * normal[s, 0] + cy * normal[s, 1] + cz * normal[s, 2] < 0.0:
            return False
    return True


@helper
def _crosses(box, ox, oy, oz, dx, dy, dz, t_end):
    """Does the segment o + s·d, 0 < s < ``t_end``, cross the box ``box`` (lo (3), hi (3))?"""
    lo, hi = 0.0, t_end
    for a in range(3):
        o = ox if a == 0 else (oy if a == 1 else oz)
        d = dx if a == 0 else (dy if a == 1 else dz)
        if d == 0.0:
            if o < box[a] or o > box[3 + a]:
                return False
        else:
            s1, s2 = (box[a] - o) / d, (box[3 + a] - o) / d
            if s1 > s2:
                s1, s2 = s2, s1
            lo, hi = max(lo, s1), min(hi, s2)
            if lo > hi:
                return False
    return True


@helper
def _counted(skip, t, x, y, z, tgt):
    """Is a crossing of target t counted on a segment that starts at vertex (x, y, z)?

    Always when the segment is not covered by next events (``skip`` False),
    else only when the vertex was too near target t for a next event."""
    if not skip or t < 0:
        return True
    ex, ey, ez = x - tgt.center[t, 0], y - tgt.center[t, 1], z - tgt.center[t, 2]
    return ex * ex + ey * ey + ez * ez < tgt.near2[t]


def trace_chunk(scene, nee, scratch, seed, first, count, tallies, stats, replay=None):
    """Trace photons ``first .. first+count-1`` of the run of ``seed`` through ``scene``
    (:class:`~kernel.records.Scene`) with next events ``nee`` (:class:`~kernel.records.NextEvents`, or None:
    none, and none of their code is compiled); add what they do to ``tallies`` and ``stats``
    (:class:`~kernel.records.Tallies`, :class:`~kernel.records.Stats`).

    ``scratch``: the address of this thread's Embree block (:func:`kernel.embree.new_scratch`).  Photon i's
    random stream is a function of ``(seed, i)`` only.  Allocates this chunk's work arrays
    (:func:`work_arrays`) and runs :func:`trace_photons`, the one compiled function Python calls (compiled on
    the first call with each kind of records, its helpers on two cores where numba's cache lacks it:
    :mod:`kernel.warm`).

    ``replay`` (:class:`~kernel.records.Replay`, or None: none of its code is compiled): the chamber's light
    stored once and replayed into a step's plant (:mod:`kernel.gather`).  ``REPLAY_STORE``: the photons make no
    next events; each vertex on the chamber (or a lamp) that would make them is logged in ``replay.vpl`` with the
    photon's weights, and each segment from the chamber that next events would not cover and that crosses
    ``replay.box`` in ``replay.seg``.  ``REPLAY_CONTINUE``: path i starts as ``replay.starts[i]`` says
    (no lamp) and ends where it meets the chamber, whose light from there on the store holds.
    """
    photon, accum, cvw = work_arrays(scene, nee, scratch, tallies)
    args = (scene, nee, None if nee is None else nee.organs, seed, first, count, tallies, stats, photon, accum, cvw,
            replay)
    kinds = (nee is None, nee is None or nee.organs is None, replay is None)   # what sets the types
    if kinds not in _CALLED:                # a first call of these types: a compile uses two cores
        share_compile(trace_photons, args)
        _CALLED.add(kinds)
    trace_photons(*args)


#: the kinds of records (next events or not, organs or not) :func:`trace_chunk` has been called with
_CALLED = set()


def work_arrays(scene, nee, scratch, tallies):
    """A chunk's work arrays (:class:`~kernel.records.Photon`, :class:`~kernel.records.Accumulator`,
    :class:`~kernel.records.ControlWork`), sized for ``scene``, ``nee`` and ``tallies``.  Allocated here in
    numpy, not in the compiled loop: it is compiled without reference counting (no allocation there), and
    numba's compile of these allocations took seconds of a first run."""
    mat = scene.materials
    n_bands = mat.prob.shape[2]
    n_rows = tallies.tally.shape[0]
    n_slots, n_cv, n_cdf, n_clusters, n_planes = 1, 0, 0, 0, 0
    if nee is not None:
        tgt = nee.targets
        n_tgt = tgt.kind.shape[0]
        n_near = int(np.max(np.diff(tgt.near_start))) if tgt.near_start.shape[0] > 1 else 0
        organ_picks = 0.0
        if nee.organs is not None:
            n_cdf, n_clusters, organ_picks = n_tgt, nee.organs.clusters.radius.shape[0], nee.organs.zones.picks
        n_planes = nee.mirrors.plane.shape[0]
        n_draw = 1 + int(max(nee.mirrors.picks, nee.mirrors.picks2, nee.zones.picks, organ_picks,
                             nee.organs.cones if nee.organs is not None else 0.0))
        walk = min(int(nee.organs.zones.walk), int(mat.max_depth)) if nee.organs is not None else 0
        n_slots = 3 * (n_tgt + tgt.picks) + 2 * OWN_SAMPLES * n_near + 2 * (1 + walk) * n_draw   # own events and
        n_cv = nee.control.row.shape[0]          # picks (up to 3 deposits each, a mesh's own events 2 each), or
                                                 # image / zone events (2 each, and 2 per leg of an organ zone's walk)
    flush_start = scene.sensors.flush_start
    n_flush = int(np.max(np.diff(flush_start))) if flush_start.shape[0] > 1 else 0   # most sensors on a triangle
    photon = Photon(scratch, np.zeros(1, dtype=np.uint64), np.empty(n_bands), np.empty(n_bands), np.empty(n_bands),
                    np.empty(n_bands), np.empty(n_slots, dtype=np.int64), np.empty((n_slots, n_bands)),
                    np.empty(CAND_CAP + n_flush, dtype=np.int64), np.empty(max(1, n_cdf + (2 + CONE_DATA) * n_clusters)),
                    np.zeros(max(1, n_clusters), dtype=np.uint8), np.empty(max(1, 2 * n_planes)),
                    np.empty((mat.max_depth + 2, 5)), np.empty(6))
    accum = Accumulator(np.zeros((n_rows, n_bands)), np.zeros(n_rows, dtype=np.uint8), np.empty(n_rows, dtype=np.int64),
                        np.empty(n_bands))
    cvw = ControlWork(np.zeros((n_bands, n_cv)), np.zeros((n_bands, n_cv)), np.zeros((n_bands, n_bands, n_cv)),
                      np.empty(n_cv, dtype=np.float32), np.empty(n_cv, dtype=np.float32))
    return photon, accum, cvw


@njit(nogil=True, no_cfunc_wrapper=True, cache=True, _nrt=False)
def trace_photons(scene, nee, organs, seed, first, count, tallies, stats, photon, accum, cvw, replay):
    """The photon loop of :func:`trace_chunk` (its arguments, ``nee.organs`` as ``organs``, then its work
    arrays), compiled without
    reference counting: array views and inlined helpers here would otherwise cost an atomic
    increment and decrement each (~20 % of a rose step's CPU time, more with two threads).

    Every helper is inlined (``forceinline=True``: LLVM inlines each helper, compiled once by numba, at each
    call; numba's own ``inline="always"`` re-processed the whole loop's IR per call site, 3x the compile
    time for the same machine code), next events from one place in the loop (a vertex's events open the
    iteration that then scatters from it): a call to a separate compiled function passes each of its
    records' arrays as ~9 machine arguments, 300-500 per call, which cost more than the next events' own
    arithmetic (``docs/performance.md``).  What next events need is under ``if nee is not None``:
    numba drops those branches when ``nee`` is None, so that ``weighted`` and ``analog`` compile a loop
    without them; and what next events to organs need under ``if organs is not None``
    (:class:`~kernel.records.OrganEvents`: a plant's organs are the targets), so that runs on sensors compile
    none of it; and what the replay of a stored chamber needs under ``if replay is not None``."""
    geo, mat, emitters, sens = scene
    counters = stats.counters
    scratch, state, w, dep, seen = photon.scratch, photon.state, photon.w, photon.dep, photon.seen
    verts, tri_normal, cop_start = geo.verts, geo.normal, geo.cop_start
    flush_start, flush_list = sens.flush_start, sens.flush_list
    n_bands = mat.prob.shape[2]
    n_mat = mat.prob.shape[0]
    n_sens = sens.center.shape[0]
    fate0, f_escaped, f_cut, f_lost = fate_rows(tallies, n_mat)
    absorbed0 = n_sens + geo.n_receivers
    max_depth = mat.max_depth
    in_batch = 0         # photons in the current batch of the control variate
    rh = scratch + RAYHIT
    cand_count = scratch + CAND_COUNT
    if nee is not None:
        tgt, mir, zones, cv, _ = nee
        sensor_target, receiver_target = tgt.sensor_target, tgt.receiver_target
        n_tgt = tgt.kind.shape[0]
        control = cv.on
        img_on = mir.picks > 0.0 and (tgt.on_sensors or tgt.on_receivers) and n_tgt > 0 and mir.plane.shape[0] > 0
        img2_on = img_on and mir.picks2 > 0.0 and mir.plane.shape[0] > 1
        zone_on = zones.picks > 0.0 and tgt.on_sensors and zones.target_plane.shape[0] > 0 and 0 < tgt.picks < n_tgt
        organ_on = cone_on = local_on = False
        if organs is not None:
            cone_on = organs.cones > 0.0 and tgt.on_receivers and 0 < tgt.picks < n_tgt
            local_on = organs.local > 0.0 and tgt.on_receivers and 0 < tgt.picks < n_tgt
            organ_on = (organs.zones.picks > 0.0 and tgt.on_receivers and organs.zones.target.shape[0] > 0
                        and 0 < tgt.picks < n_tgt)
        stat_planes = n_mat + tgt.from_emitter.shape[0]

    n_pass = mat.cum.shape[2]      # paths per photon: 1 (all bands on one), n_bands (analog), or band groups
    nh = np.int64(0)   # int64 from the start: a literal 0 would compile record() for Literal[int] too
    for path in range(count * n_pass):
        i = path // n_pass           # the photon
        pb = path - i * n_pass       # its band (n_pass > 1) or 0
        if pb == 0:
            seed_stream(state, seed, first + i)
        resumed = False              # a path from a stored start (a replay), not from a lamp
        st = photon.leg
        if replay is not None:
            if replay.mode == REPLAY_CONTINUE:
                resumed = True
                st = replay.starts[i]
        if resumed:
            e = 0
            ox, oy, oz, dx, dy, dz = st[0], st[1], st[2], st[3], st[4], st[5]
            enx, eny, enz, emode, oscale = 0.0, 0.0, 1.0, np.int64(V_SURFACE), 0.0
            for b in range(n_bands):
                w[b] = st[START_W + b]
        else:
            e = pick_element(emitters, i, count, state)
            ox, oy, oz, dx, dy, dz, enx, eny, enz, emode, oscale = emit(e, emitters, state, geo.offset_rel)
            if n_pass == 1:
                for b in range(n_bands):
                    w[b] = emitters.weight[e, b]
            else:                        # this path carries its bands only
                for b in range(n_bands):
                    w[b] = emitters.weight[e, b] if mat.band_pass[b] == pb else 0.0
        depth = 0
        vx0, vy0, vz0 = ox, oy, oz   # the vertex the current segment starts at
        on_chamber = True            # ... and it is on the chamber or a lamp (a replay's store logs those)
        seg_plane = -1          # the current segment leaves this mirror plane, reflected, after a next-event vertex
        seg_plane2 = -1         # or leaves this one after seg_plane (two reflections after that vertex)
        wx, wy, wz = ox, oy, oz  # that next-event vertex
        # the lamp is the photon's first vertex; from there on, each surface hit (one iteration each)
        events = False           # does the vertex make next events?
        if nee is not None:
            events = n_tgt > 0 and tgt.from_emitter[e] != 0
        after_diffuse = events   # does the current segment start at a next-event vertex?
        if resumed:              # a stored segment: covered by the gather (kernel.gather) or to be counted
            events = False
            after_diffuse = st[9] != 0.0
            vx0, vy0, vz0 = st[6], st[7], st[8]
            seg_plane = np.int64(st[10])
            wx, wy, wz = st[11], st[12], st[13]
        vertex = Vertex(ox, oy, oz, enx, eny, enz, emode, np.int64(0), oscale, np.int64(-1))
        stat = np.int64(n_mat + e)   # the vertex's row of nee_stats
        cover = np.int64(-1)         # the plane whose near discs zone events served (next_event's cover_pid)
        organ_cover = -1.0           # the length² of the segment to an organ vertex whose own events organ zone
                                     # events served (those of targets whose near radius is at most that long)
        n_chain = np.int64(0)        # organ vertices in photon.chain: the last ones met, each straight after a
                                     # next-event vertex (next_event's zone_served)
        left = max_depth + 1         # the k-th surface met from here on may make next events if k < left
        near = np.int64(0)           # its triangle has near discs (control_deposits)
        room = max_depth > 0         # a further bounce is allowed (events through a mirror or a zone need one)
        room2 = max_depth > 1        # two more (events through two mirrors)
        on_surface = False
        m, tri, rec, rec_analog = np.int64(0), np.int64(-1), np.int32(-1), False    # the hit (set below)
        px = py = pz = nx = ny = nz = pscale = 0.0
        while True:
            if replay is not None and events and replay.mode == REPLAY_STORE:   # log, not next events
                if on_chamber:
                    k = replay.count[0]
                    replay.count[0] += 1
                    if k < replay.vpl.shape[0]:
                        row = replay.vpl[k]
                        row[0], row[1], row[2] = vertex.x, vertex.y, vertex.z
                        row[3], row[4], row[5] = vertex.nx, vertex.ny, vertex.nz
                        row[6], row[7], row[8], row[9], row[10] = vertex.mode, vertex.material, vertex.scale, vertex.tri, stat
                        for b in range(n_bands):
                            row[VPL_W + b] = w[b]
            elif nee is not None and events:   # expected light of the segment leaving the vertex, if diffusely
                if control:
                    control_deposits(vertex, w, near, mat, cv, cvw)
                n_out = next_event(vertex, stat, (cover, n_chain), control, geo, mat, sens, tgt, zones, organs,
                                   photon, stats)
                nh = record_all(n_out, nh, photon, accum)
                # and through a mirror (if not cut at that mirror); the call itself is not free: only if drawn
                n_img = n_draws(mir.picks, state) if img_on and room else 0
                if n_img > 0:
                    n_out = image_event(vertex, n_img, stat_planes, geo, mat, sens, tgt, mir, organs, photon, stats)
                    nh = record_all(n_out, nh, photon, accum)
                n_img = n_draws(mir.picks2, state) if img2_on and room2 else 0
                if n_img > 0:      # and through two mirrors
                    n_out = double_image_event(vertex, n_img, stat_planes, geo, mat, sens, tgt, mir, photon, stats)
                    nh = record_all(n_out, nh, photon, accum)
                n_zone = n_draws(zones.picks, state) if zone_on and room else 0
                if n_zone > 0:     # and through one diffuse vertex beside a disc
                    n_out = zone_event(vertex, n_zone, geo, mat, sens, tgt, zones, photon, stats)
                    nh = record_all(n_out, nh, photon, accum)
                if organs is not None:
                    if cone_on:     # and into the cones of the organ clusters the vertex is far from
                        n_out = cone_events(vertex, stat, geo, mat, tgt, organs, photon, stats, 0)
                        nh = record_all(n_out, nh, photon, accum)
                    if local_on:    # and as the photon leaves, to the large targets of the clusters it is near
                        n_out = local_events(vertex, stat, geo, mat, tgt, organs, photon, stats, 0)
                        nh = record_all(n_out, nh, photon, accum)
                    n_oz = n_draws(organs.zones.picks, state) if organ_on and room else 0
                    if n_oz > 0:   # and through one diffuse vertex on the organ surface beside an organ
                        n_out = organ_zone_event(vertex, n_oz, left, stat, geo, mat, sens, tgt, organs, photon, stats)
                        nh = record_all(n_out, nh, photon, accum)
            if on_surface:
                # one event, drawn with probabilities q shared by the bands; weights carry the rest
                u = uniform(state)
                ev = 0
                while ev < ABSORB and u >= mat.cum[m, ev, pb]:
                    ev += 1
                if ev == ABSORB and mat.expected_absorption:   # ends here: its absorption is already deposited
                    break
                q = mat.cum[m, ev, pb] - (mat.cum[m, ev - 1, pb] if ev > 0 else 0.0)
                for b in range(n_bands):
                    w[b] *= mat.prob[m, ev, b] / q
                if ev == ABSORB:
                    if rec_analog:
                        nh = record(absorbed0 + rec, w, nh, accum)
                    nh = record(fate0 + m, w, nh, accum)
                    break
                depth += 1
                first_plane = seg_plane if seg_plane2 < 0 else -1    # the segment ending here had one reflection
                seg_plane = seg_plane2 = -1
                if nee is not None:
                    pl = geo.mirror_plane[tri]
                    if img_on and ev == SPECULAR_R and pl >= 0 and mir.on[pl] != 0 and math.isinf(mat.phong[m]):
                        if after_diffuse:
                            seg_plane = pl              # a mirror right after a next-event vertex (vx0)
                            wx, wy, wz = vx0, vy0, vz0
                        elif img2_on and first_plane >= 0 and first_plane != pl:
                            seg_plane, seg_plane2 = first_plane, pl     # a second mirror after it
                    after_diffuse = n_tgt > 0 and tgt.from_material[m] != 0 and (ev == DIFFUSE_R or ev == DIFFUSE_T)
                vx0, vy0, vz0 = px, py, pz
                u1, u2 = uniform(state), uniform(state)
                if ev == DIFFUSE_R:
                    dx, dy, dz = cosine_hemisphere(nx, ny, nz, u1, u2)
                    side = 1.0
                elif ev == SPECULAR_R:
                    rx, ry, rz = mirror(dx, dy, dz, nx, ny, nz)
                    if math.isinf(mat.phong[m]):
                        dx, dy, dz = rx, ry, rz
                    else:
                        dx, dy, dz = phong_lobe(rx, ry, rz, mat.phong[m], u1, u2)
                        if dx * nx + dy * ny + dz * nz <= 0.0:   # lobe below the surface: absorbed there
                            if rec >= 0:
                                nh = record(absorbed0 + rec, w, nh, accum)
                            nh = record(fate0 + m, w, nh, accum)
                            break
                    side = 1.0
                elif ev == DIFFUSE_T:
                    dx, dy, dz = cosine_hemisphere(-nx, -ny, -nz, u1, u2)
                    side = -1.0
                else:   # SPECULAR_T: straight through a thin surface
                    side = -1.0
                inv = 1.0 / math.sqrt(dx * dx + dy * dy + dz * dz)
                dx, dy, dz = dx * inv, dy * inv, dz * inv
                eps = side * geo.offset_rel * (pscale + oscale)
                ox, oy, oz = px + eps * nx, py + eps * ny, pz + eps * nz
            skip_sensors = skip_receivers = False
            if nee is not None:
                skip_sensors = after_diffuse and tgt.on_sensors
                skip_receivers = after_diffuse and tgt.on_receivers
            set_ray(scratch, ox, oy, oz, dx, dy, dz, _TFAR_MAX)
            cast(geo.intersect, geo.scene, scratch, RAY_PHOTON)
            counters[C_RAYS] += 1
            gid = load_u32(rh + GEOM_ID)
            tri = -1 if gid == INVALID_ID else load_u32(rh + PRIM_ID) + geo.geom_offset[gid]
            # where: on our float64 triangle (hit_point), not from Embree's float32 t and barycentrics, whose
            # last bits depend on the processor
            t, px, py, pz = (math.inf, ox, oy, oz) if tri < 0 else hit_point(geo, scratch, tri)
            if replay is not None:
                if resumed and (tri < 0 or geo.receiver[tri] < replay.organ0):
                    break        # the chamber again: its light from here on is the store's
                if replay.mode == REPLAY_STORE and on_chamber and not after_diffuse:
                    hit_organ = tri >= 0 and geo.receiver[tri] >= replay.organ0
                    if _crosses(replay.box, ox, oy, oz, dx, dy, dz, math.inf if hit_organ else t):
                        k = replay.count[1]
                        replay.count[1] += 1
                        if k < replay.seg.shape[0]:
                            row = replay.seg[k]
                            row[0], row[1], row[2], row[3], row[4], row[5] = ox, oy, oz, dx, dy, dz
                            row[6], row[7], row[8], row[9] = vx0, vy0, vz0, 0.0
                            row[10], row[11], row[12], row[13] = seg_plane, wx, wy, wz
                            for b in range(n_bands):
                                row[START_W + b] = w[b]

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
                    t = ((verts[tri, 0, 0] - ox) * tri_normal[tri, 0] + (verts[tri, 0, 1] - oy) * tri_normal[tri, 1]
                         + (verts[tri, 0, 2] - oz) * tri_normal[tri, 2]) / dn
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
                snx, sny, snz = sens.normal[s, 0], sens.normal[s, 1], sens.normal[s, 2]
                den = dx * snx + dy * sny + dz * snz
                if den >= 0.0:
                    continue
                ts = ((sens.center[s, 0] - ox) * snx + (sens.center[s, 1] - oy) * sny
                      + (sens.center[s, 2] - oz) * snz) / den
                if ts <= 0.0 or ts >= t:
                    continue
                counted = True
                if nee is not None:
                    counted = _counted(skip_sensors, sensor_target[s] if skip_sensors else -1, vx0, vy0, vz0, tgt)
                    if counted and seg_plane >= 0 and sensor_target[s] >= 0:     # covered by image events?
                        if seg_plane2 < 0:
                            counted = image_counted(sensor_target[s], wx, wy, wz, seg_plane, mir, tgt)
                        else:
                            counted = double_image_counted(sensor_target[s], wx, wy, wz, seg_plane, seg_plane2,
                                                           mir, tgt)
                if counted and _inside(s, ox + ts * dx, oy + ts * dy, oz + ts * dz, sens):
                    nh = record(s, w, nh, accum)

            if gid == INVALID_ID:
                nh = record(f_escaped, w, nh, accum)
                break
            if not (math.isfinite(px) and math.isfinite(py) and math.isfinite(pz)):
                counters[C_LOST] += 1
                nh = record(f_lost, w, nh, accum)
                break
            if cop_start[tri + 1] > cop_start[tri]:   # coincident surfaces: a fair choice, not float rounding
                tri = pick_coplanar(tri, px, py, pz, dx, dy, dz, geo, state)
            nx, ny, nz = tri_normal[tri, 0], tri_normal[tri, 1], tri_normal[tri, 2]
            if dx * nx + dy * ny + dz * nz > 0.0:      # back side of a two-sided surface
                nx, ny, nz = -nx, -ny, -nz
                m = np.int64(geo.material[tri, 1])
            else:
                m = np.int64(geo.material[tri, 0])
            # round-off scale of this hit: Embree works in float32 on the triangle's vertices and the ray's
            # origin, and returns t in float32, so the hit point's error is a few ulps of the largest of |v_i|
            # and |o| (pbrt's error bounds) -- not of |p|, which is ~0 on a large triangle through the origin
            pscale = max(magnitude(verts[tri]), abs(px), abs(py), abs(pz))
            oscale = max(abs(ox), abs(oy), abs(oz))
            rec = geo.receiver[tri]
            # counted unless the next-event tallies cover this hit
            rec_analog = rec >= 0
            if nee is not None:
                rec_analog = rec >= 0 and _counted(skip_receivers, receiver_target[rec] if skip_receivers else -1,
                                                   vx0, vy0, vz0, tgt)
                if rec_analog and seg_plane >= 0 and receiver_target[rec] >= 0:      # covered by image events?
                    if seg_plane2 < 0:
                        rec_analog = image_counted(receiver_target[rec], wx, wy, wz, seg_plane, mir, tgt)
                    else:
                        rec_analog = double_image_counted(receiver_target[rec], wx, wy, wz, seg_plane, seg_plane2,
                                                          mir, tgt)
            if rec_analog:
                nh = record(n_sens + rec, w, nh, accum)
            if depth >= max_depth:
                nh = record(f_cut, w, nh, accum)
                break
            if mat.expected_absorption:   # deposit what this surface absorbs on average
                for b in range(n_bands):
                    dep[b] = w[b] * mat.prob[m, ABSORB, b]
                nh = record(fate0 + m, dep, nh, accum)
                if rec_analog:
                    nh = record(absorbed0 + rec, dep, nh, accum)
            if nee is not None:
                events = n_tgt > 0 and tgt.from_material[m] != 0
            if replay is not None:
                on_chamber = rec < replay.organ0
            if nee is not None and events:
                cover = np.int64(geo.plane_id[tri]) if zone_on and after_diffuse else np.int64(-1)
                organ_cover = -1.0
                if resumed and depth == 0:    # reached from a stored vertex, which made no zone events by discs
                    cover = np.int64(-1)      # (its organ zone events: the gather's, kernel.gather)
                if organs is not None:
                    if organ_on and after_diffuse and geo.plane_id[tri] < 0 and rec >= 0:
                        organ_cover = (px - vx0) ** 2 + (py - vy0) ** 2 + (pz - vz0) ** 2
                if organ_cover >= 0.0:       # one more organ vertex straight after a next-event vertex
                    chain = photon.chain
                    chain[n_chain, 0], chain[n_chain, 1], chain[n_chain, 2] = px, py, pz
                    chain[n_chain, 3], chain[n_chain, 4] = tri, organ_cover
                    n_chain += 1
                else:
                    n_chain = np.int64(0)
                vertex = Vertex(px, py, pz, nx, ny, nz, V_SURFACE, m, pscale + oscale, tri)
                stat = m
                near = 1 if tgt.near_start[tri + 1] > tgt.near_start[tri] else 0
                room = depth + 1 < max_depth
                room2 = depth + 2 < max_depth
                left = max_depth - depth
            on_surface = True
        if pb < n_pass - 1:
            continue         # the photon's other bands' paths still to come: one flush for all
        if nee is not None and control:     # the control variate's batches of cv.batch photons, by photon
            fold_control(nh, accum, cvw, sensor_target, n_sens)
            in_batch += 1                   # index: the same on any number of threads
            if (first + i + 1) % cv.batch == 0 or i == count - 1:
                control_products(in_batch, cvw)
                counters[C_BATCHES] += 1
                in_batch = 0
        flush(nh, fate0, accum, tallies)
        nh = np.int64(0)
    if nee is not None:
        add_control(cv, cvw, tallies)
