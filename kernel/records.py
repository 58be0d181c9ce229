"""What the photon kernel reads and writes, as named records of arrays.

Every kernel function takes the few records it reads instead of dozens of loose arrays: a record is a
named tuple of numpy arrays and numbers, which numba compiles to plain loads (``geo.verts[tri, 0, 0]`` costs
what a loose ``tri_verts[tri, 0, 0]`` did).  A record's fields are one concept each, named from the
physics; two arrays of the same shape cannot be swapped by position.  ``lpy_light.estimators.kernel_scene.KernelScene``
builds the scene's records once per run (``KernelScene.records``), the kernel allocates one thread's work
arrays per chunk (:class:`Photon`, :class:`Accumulator`, :class:`ControlWork`), and the caller owns the
:class:`Tallies` and :class:`Stats` a chunk adds to.

Sizes: T triangles, M materials, B bands, P paths per photon (1, or B for ``analog``), S transparent
sensors, R receivers (solid sensors and organs), E emitter elements, n next-event targets, Q mirror
planes, Z zones, K tally rows.  Lengths in scene units (Angers: mm), directions unit vectors, weights in
photons (a photon leaves its lamp with weight 1 in each band).
"""
from collections import namedtuple

import numpy as np

# scattering events, in the order their probabilities are accumulated (materials' event tables)
DIFFUSE_R, SPECULAR_R, DIFFUSE_T, SPECULAR_T, ABSORB = 0, 1, 2, 3, 4
N_EVENTS = 5

# transparent sensor kinds (lpy_light.chamber.sensors)
SENSOR_DISC, SENSOR_QUAD = 0, 1

# next-event target kinds (MESH2: a two-sided mesh, an organ; MESH1: one-sided, a solid sensor)
T_DISC, T_QUAD, T_MESH2, T_MESH1 = 0, 1, 2, 3

# how the light leaves a next-event vertex: an isotropic line or point lamp, a Lambertian emitter, a surface
V_ISOTROPIC, V_LAMBERT, V_SURFACE = 0, 1, 2


Geometry = namedtuple("Geometry", [
    "scene",         # int: the Embree scene's handle (kernel.embree.EmbreeScene.handle)
    "intersect",     # int: address of rtcIntersect1 (closest hit; the filters record sensor crossings)
    "occluded",      # int: address of rtcOccluded1 (shadow rays)
    "offset_rel",    # float: a new ray starts offset_rel · (max(|v_i|, |p|) + |o|) off the surface it leaves
                     # (v_i the triangle's vertices, p the hit, o the ray's origin; ∞-norms): Embree's float32
                     # round-off a few ulps deep (docs/stability.md)
    "geom_offset",   # (4,) int64: kernel triangle = Embree primID + geom_offset[geomID]
    "verts",         # (T, 3, 3) float64: vertices
    "normal",        # (T, 3) float64: unit right-hand-rule normals
    "material",      # (T, 2) int32: material seen from the front, from the back
    "receiver",      # (T,) int32: receiver of each triangle, or -1
    "two_sided",     # (T,) uint8: seen from both sides
    "mirror_plane",  # (T,) int32: the flat perfect mirror (Mirrors) each triangle belongs to, or -1
    "plane_id",      # (T,) int32: each chamber triangle's plane (lpy_light.chamber.geometry.plane_ids), -1 for organs
    "cop_start",     # (T + 1,) int64, and
    "cop_list",      # int32: the coplanar partners of triangle j, cop_list[cop_start[j]:cop_start[j + 1]]
                     # (lpy_light.chamber.geometry.coplanar_partners); none: no random pick between coincident surfaces
    "cop_box",       # (T, 2, 3) float64: each triangle's bounding box, slightly widened (quick rejects)
    "cop_free",      # (T, 2, 3) float64: a box where none of the triangle's partners reaches
    "n_receivers",   # int: R
])

Materials = namedtuple("Materials", [
    "prob",          # (M, 5, B) float64: probability of each scattering event per band
    "cum",           # (M, 5, P) float64: cumulative probabilities q of the event drawn on each path
                     # (lpy_light.chamber.materials.sampling_tables)
    "band_pass",     # (B,) int64: the path that carries each band (its weight starts at 1 there, 0 elsewhere)
    "phong",         # (M,) float64: Phong exponent of the specular lobe (inf: a perfect mirror)
    "expected_absorption",   # bool: estimators weighted and nee deposit w·P_abs at each hit; analog draws it
    "max_depth",     # int: scattering events before a photon is cut
])

Emitters = namedtuple("Emitters", [
    "kind",          # (E,) int32: kernel.emission.EMIT_* (each kind one sampling function there)
    "data",          # (E, 3, 3) float64: the element (end points and radius, a triangle, a centre and radius)
    "cdf",           # (E,) float64: cumulative share of the emitted power
    "weight",        # (E, B) float64: a photon's weight per band as it leaves element e (1: the .rad's lamp)
])

Sensors = namedtuple("Sensors", [
    "kind",          # (S,) int32: SENSOR_DISC or SENSOR_QUAD
    "center",        # (S, 3) float64
    "normal",        # (S, 3) float64: unit; a sensor counts crossings from its front (against the normal)
    "radius",        # (S,) float64: discs' radii
    "corners",       # (S, 4, 3) float64: quads' corners, counter-clockwise seen from the front
    "flush_start",   # (T + 1,) int64, and
    "flush_list",    # int64: the sensors lying on each triangle's plane (Sensors.flush_with), tested at every
                     # hit on it (Embree's float32 would report them or not as its rounding falls)
])

Targets = namedtuple("Targets", [
    "on_sensors",    # bool: sensors are next-event targets (their counted crossings then skip what is covered)
    "on_receivers",  # bool: receivers are
    "picks",         # int: targets drawn per next event (0: every target at every vertex)
    "from_material",  # (M,) uint8: next events from this material's surfaces (0: its segments are counted)
    "from_emitter",  # (E,) uint8: next events from this emitter element
    "kind",          # (n,) int32: T_DISC, T_QUAD, T_MESH2, T_MESH1; sensor targets first
    "row",           # (n,) int64: tally row of the light it gets (a sensor's, or a receiver's incident row)
    "abs_row",       # (n,) int64: tally row of what it absorbs (receivers), or -1
    "ref",           # (n,) int64: the sensor or receiver it stands for
    "first",         # (n,) int64: a mesh target's triangles are tri[first : first + count]
    "count",         # (n,) int64
    "area",          # (n,) float64: area (one side)
    "center",        # (n, 3) float64: centre (meshes: of the bounding box)
    "near2",         # (n,) float64: exclusion radius² of next events (0 for discs: drawn by solid angle)
    "img_near2",     # (n,) float64: the same for next events through a mirror
    "tri",           # int64: mesh targets' triangles, and
    "tri_cdf",       # float64: their cumulative areas within each target (points drawn by area)
    "tri_plane",     # (len(tri), 6) float64: each of those triangles' first vertex and unit normal, side by side in
                     # target order (kernel.nee.facing_triangle reads a bud's 80 in one stretch, not scattered)
    "near_start",    # (T + 1,) int64, and
    "near_list",     # int64: the discs near each triangle, which get an event of their own (kernel.nee.near_discs)
    "near_r2",       # (n,) float64: their near radius²
    "sensor_target",  # (S,) int64: each sensor's target, or -1
    "receiver_target",  # (R,) int64: each receiver's target, or -1
    "facing",        # (n,) uint8: 1 where only the triangles facing a vertex beyond NEAR radii can be seen from it
                     # (a one-sided mesh, or a closed one: its far side is hidden by its near side), so that
                     # a point for a next event is drawn among those (kernel.nee.facing_triangle)
])

Mirrors = namedtuple("Mirrors", [
    "picks",         # float: next events through a mirror per next-event vertex, on average (0: none)
    "picks2",        # float: next events through two mirrors per next-event vertex, on average (0: none)
    "plane",         # int32: the planes in use, drawn at each vertex in proportion to spec · an upper bound of the
                     # solid angle they subtend there (kernel.images.plane_importance)
    "spec",          # (Q,) float64: the largest specular reflectance of each plane's sides (over bands)
    "area",          # (Q,) float64: its area (scene units²)
    "on",            # (Q,) uint8: the planes in use, as flags
    "point",         # (Q, 3) float64: a point of each plane
    "normal",        # (Q, 3) float64: its unit normal
    "box",           # (Q, 2, 3) float64: the bounds of its triangles, slightly widened
    "one_sided",     # (Q,) uint8: reflects from its front only
])

Zones = namedtuple("Zones", [
    "picks",         # float: two-step next events through a zone per next-event vertex, on average (0: none)
    "frame",         # (Z, 14) float64: foot c' of the disc's centre on the plane (3), the plane's unit normal
                     # (3), two unit tangents e1, e2 (6), h_s², L = ln(1 + ρ²/h_s²) (kernel.nee.near_zones)
    "target_plane",  # (Z, 2) int64: the disc target and the plane id of each zone
    "start",         # (n + 1,) int64: zones of target t are start[t] : start[t + 1]
])

OrganZones = namedtuple("OrganZones", [
    "picks",         # float: two-step next events through an organ's zone per next-event vertex, on average
    "target",        # (Z,) int64: the mesh targets that have a zone (the organ surface within their near radius)
    "start",         # (Z + 1,) int64: zone z's triangles are tri[start[z] : start[z + 1]]
    "tri",           # int64: the zones' triangles (organs' triangles, none of the target's own), drawn by
    "cdf_area",      # float64: their cumulative areas within each zone (ending at 1), or by
    "cdf_angle",     # float64: their cumulative solid angles seen from the target's centre (ending at 1)
    "total",         # (Z, 2) float64: each zone's area and solid angle (sr) seen from its target's centre
    "zone_of",       # (n,) int64: each target's zone, or -1
    "weight",        # (n,) float64: 1 for the targets that have a zone, 0 for the others
    "cluster_weight",  # (K,) float64: the number of zones in each cluster of targets (Clusters)
    "own",           # (n,) uint8: 1 where the target's own surface is in its zone (an open organ: it lights itself)
    "walk",          # int: the short legs a zone event's vertex walks on inside the zone, at most, an own event at
                     # each landing (kernel.organ_zones.zone_walk); 0: those landings are left to the photons
])

Clusters = namedtuple("Clusters", [
    "start",         # (K + 1,) int64: the targets grouped in space (kernel.targets.target_clusters): cluster k's
    "member",        # (n,) int64: are member[start[k] : start[k + 1]]
    "center",        # (K, 3) float64: a cluster's centre and
    "radius",        # (K,) float64: the radius of a sphere holding its targets' bounding spheres
])

# next events to organs (LightModel: organs are the targets; None for sensors, and none of their code compiled)
OrganEvents = namedtuple("OrganEvents", [
    "clusters",      # Clusters of the targets
    "weight",        # (n,) float64: picks drawn ∝ weight[t] / max(d², a²) (kernel.importance)
    "far_weight",    # (n,) float64: ... as seen from a vertex far from its cluster; 0: served by kernel.cones there
    "cluster_weight",  # (K,) float64: the sum of each cluster's far weights
    "cluster_of",    # (n,) int64: the cluster of each target
    "cones",         # float: rays per vertex into the cones of the clusters v is far from (kernel.cones; 0: none)
    "near_weight",   # (n,) float64: ... as seen from a vertex near its cluster; 0: served by local rays there
    "local",         # float: local rays per vertex near a cluster (kernel.cones.local_events; 0: none)
    "zones",         # OrganZones: two-step next events through the organ surface beside an organ
    "pick_mean",     # float: the mean pick share S over a vertex (kernel.nee.pick_mean); picks per vertex follow
                     # S / pick_mean (0: ``picks`` at every vertex)
    "pick_unit",     # float: the unit of S counted in stats.counters[C_PICK_SHARE] (scene units⁻²)
    "pick_side",     # (M,) float64: per material, the band mean of its larger diffuse reflectance or transmittance
])

Control = namedtuple("Control", [
    "on",            # bool: the control variate (nee with sensor targets and random picks)
    "batch",         # int: photons per batch of its products between bands (1: per photon)
    "row",           # (c,) int64: tally rows of the c sensor targets it covers (the first c targets)
    "center",        # (3, c) float32: their centres (float32: γ's loop runs 16 wide)
    "normal",        # (3, c) float32: their unit normals
    "area",          # (c,) float32
    "thr",           # (2, c) float32: radius² within which a vertex makes no control deposit for a target
                     # (row 0: elsewhere, row 1: on a triangle with near discs)
    "runs",          # (r, 2) int64: runs of targets on one plane with one normal: first, end
    "plane",         # (r,) float32: each run's plane offset n·c
])

# the chamber's light stored once and replayed into each step's plant (kernel.gather, lpy_light.estimators.reuse)
REPLAY_STORE, REPLAY_CONTINUE = 1, 2
# columns of a stored vertex (Replay.vpl): x, y, z, normal (3), mode, material, scale, triangle, nee_stats row,
# then the photon's weights (B)
VPL_W = 11
# columns of a start or stored segment (Replay.starts, Replay.seg): origin (3), unit direction (3), the vertex
# the segment leaves (3), covered (1: next events from that vertex cover its crossings of organs), the mirror plane
# it leaves after a next-event vertex (1, or -1) and that vertex (3: image events from there cover its crossings),
# then weights (B)
START_W = 14

Replay = namedtuple("Replay", [
    "mode",          # REPLAY_STORE: log the chamber's light; REPLAY_CONTINUE: trace from ``starts``
    "organ0",        # the first receiver that is an organ: a receiver below it (or none) is the chamber's
    "starts",        # (n, START_W + B) float64: where the paths of REPLAY_CONTINUE start, indexed by photon
    "vpl",           # (cap, VPL_W + B) float64: REPLAY_STORE's log of the chamber's next-event vertices
    "seg",           # (cap2, START_W + B) float64: ... and of the segments from the chamber not covered by next
                     # events that cross ``box``
    "count",         # (2,) int64: vertices and segments logged (counted past the capacity too)
    "box",           # (6,) float64: the plant's region, lo (3) and hi (3)
])

# what every run traces through
Scene = namedtuple("Scene", ["geometry", "materials", "emitters", "sensors"])
# next events (estimator nee; None where there is no target: their code is then not compiled); organs: OrganEvents
# or None
NextEvents = namedtuple("NextEvents", ["targets", "mirrors", "zones", "control", "organs"])

Tallies = namedtuple("Tallies", [
    "tally",         # (K, B) float64: sums of per-photon contributions; rows (kernel.tallies): S sensor
                     # crossings, R receivers' incident, R receivers' absorbed, then the fates: absorbed per
                     # material (M), escaped, cut at max_depth, lost, and each photon's total deposit
    "tally_sq",      # (K, B, B) float64: sums of products between bands of per-photon contributions
])

Stats = namedtuple("Stats", [
    "counters",      # (N_COUNTERS,) int64: rays, candidate overflows, scratch flushes, lost, shadow rays,
                     # control-variate batches (kernel.tallies)
    "nee_stats",     # (M + E + Q, 3) float64: shadow rays cast, unblocked, weight deposited, per material,
                     # emitter element, then mirror plane (image events)
])

# one thread's work arrays, allocated per chunk by kernel.trace.trace_chunk
Photon = namedtuple("Photon", [
    "scratch",       # int: address of this thread's Embree block (kernel.embree.new_scratch)
    "state",         # (1,) uint64: the photon's random stream (kernel.rng)
    "w",             # (B,) float64: the photon's weights
    "dep",           # (B,) float64: what it deposits at a hit
    "contrib",       # (B,) float64: one next event's deposit
    "w2",            # (B,) float64: the weights a two-step next event carries to its second vertex
    "out_k",         # int64: tally rows of a vertex's next-event deposits, and
    "out_w",         # (., B) float64: the deposits
    "seen",          # int64: sensors already tested on the current segment
    "cdf",           # (n + (2 + CONE_DATA) K,) float64: cumulative importances at a vertex: of the targets within each cluster
                     # (by position in Targets.cluster_member), then of the K clusters (kernel.nee.pick_by_importance),
                     # then the weights of the clusters' cones and their data (kernel.cones)
    "exact",         # (K,) uint8: the clusters whose targets' importances were summed at this vertex
    "plane_cdf",     # (2P,) float64: cumulative importances of the mirror planes in use at a vertex, then (second
                     # half) at a target (kernel.images)
    "chain",         # (D + 1, 5) float64: the organ vertices the photon met one after the other, each straight from
                     # the one before, a next-event vertex: x, y, z, triangle, length² of the leg that reached it
                     # (kernel.nee.zone_served; D the scene's max_depth)
    "leg",           # (6,) float64: the last shadow ray of a next event to a target: origin, unit direction
                     # (kernel.nee.target_event; a gather's arrival continues from there: kernel.gather)
])

Accumulator = namedtuple("Accumulator", [
    "acc",           # (K, B) float64: this photon's sum per tally row
    "touched",       # (K,) uint8: rows it touched, as flags, and
    "rows",          # (K,) int64: in order
    "tot",           # (B,) float64: its total deposit
])

ControlWork = namedtuple("ControlWork", [
    "batch",         # (B, c) float64: a batch's deposits on the control variate's sensor targets,
    "tally",         # (B, c) float64: the chunk's sums of them,
    "sq",            # (B, B, c) float64: and of their products between bands (b <= b2)
    "g_r",           # (c,) float32: γ towards the side a vertex reflects to, and
    "g_t",           # (c,) float32: transmits to (scratch of kernel.control.control_deposits)
])

Vertex = namedtuple("Vertex", [
    "x", "y", "z",   # where the photon leaves (a lamp or a surface hit)
    "nx", "ny", "nz",  # unit normal: the emitter's, or the surface's on the side the photon arrived from
    "mode",          # V_ISOTROPIC, V_LAMBERT or V_SURFACE
    "material",      # the surface's material (V_SURFACE), else 0
    "scale",         # round-off scale: shadow rays start and stop offset_rel · max(|v|, scale) off surfaces
    "tri",           # its triangle, -1 on a lamp
])

# the gather of the ``reuse`` estimator (kernel.gather.gather_batch): what one batch draws, and where it writes
GatherDraws = namedtuple("GatherDraws", [
    "targets",       # (J,) int64: the targets gathered (indices into NextEvents.targets)
    "samples",       # (J,) int64: next events from the batch's stored vertices to each
    "zone_samples",  # (J,) int64: two-step events through each one's organ zone (buds; ignored elsewhere)
    "image_draws",   # int64: next events through a mirror from the batch's vertices
    "seed",          # int64: target j's draws use the random stream (seed, batch · T + j)
])

GatherOut = namedtuple("GatherOut", [
    "tally",         # (K, B) float64: the deposits, added to
    "starts",        # (n, START_W + B) float64: each draw that reached its target, to continue from there
])

# a step of the ``field`` estimator (kernel.field.cast_rays).  Sizes: T region triangles, E region elements (an
# organ, a chamber piece inside the region) with 2E sides, n rays, B bands.
Region = namedtuple("Region", [
    "scene",         # int: the region's Embree scene handle (the plant and the chamber's pieces inside the box)
    "intersect",     # int: address of rtcIntersect1
    "geom_offset",   # (4,) int64: region triangle = Embree primID + geom_offset[geomID]
    "verts",         # (T, 3, 3) float64: vertices
    "normal",        # (T, 3) float64: unit right-hand-rule normals
    "offset_rel",    # float: a ray starts offset_rel · (max |v_i| + |o|) off the triangle it leaves (Geometry)
    "tri_side",      # (T, 2) int64: the element side a ray meets on each triangle from its front, from its back;
                     # −1: not met from there
])

RaySides = namedtuple("RaySides", [
    "tri_start",     # (E + 1,) int64: element e's triangles are tris[tri_start[e] : tri_start[e + 1]]
    "tris",          # int64: the elements' triangles, and
    "tri_cdf",       # float64: their cumulative areas within each element (ending at 1)
    "rays",          # (2E,) int64: rays from each side
    "ray_start",     # (2E + 1,) int64: side s's rays are written at ray_start[s]:
    "reflect",       # (2E, B) float64: each side's reflectance, and
    "transmit",      # (2E, B) float64: transmittance (a path that bounces on there)
    "guide_of",      # (2E,) int64: each side's row of the guide, or −1 (cosine-weighted rays only)
])

FieldBins = namedtuple("FieldBins", [
    "box",           # (6,) float64: the region, lo (3) and hi (3)
    "grid",          # (6, 2) int64: cells along each face's two axes
    "face0",         # (6,) int64: each face's first cell
    "rings",         # int: direction rings (equal projected solid angle)
    "sectors",       # int: direction sectors
])

Guide = namedtuple("Guide", [
    "table",         # (G, n_z · n_phi) float64: each guided side's cumulative weights over the sphere's bins
    "cosine_share",  # float: share of a guided side's rays drawn cosine-weighted
    "n_phi",         # int: the sphere's sectors (kernel.field.sphere_bin)
])

RayEnds = namedtuple("RayEnds", [
    "out",           # (n,) int64: ≥ 0, the triangle side a ray's path ended on; < 0, −1 − the field's bin it
                     # left the region by (kernel.field.NOTHING: it reads nothing)
    "ray_tri",       # (n,) int64: the triangle side it left from
    "through",       # (n, B) float64: its path's throughput per band
])


def i32(a):
    return np.ascontiguousarray(a, dtype=np.int32)


def i64(a):
    return np.ascontiguousarray(a, dtype=np.int64)


def u8(a):
    return np.ascontiguousarray(a, dtype=np.uint8)


def f32(a):
    return np.ascontiguousarray(a, dtype=np.float32)


def f64(a):
    return np.ascontiguousarray(a, dtype=np.float64)


def new_tallies(n_rows: int, n_bands: int, n_stats: int, n_counters: int):
    """Zeroed :class:`Tallies` and :class:`Stats` for one chunk."""
    return (Tallies(np.zeros((n_rows, n_bands)), np.zeros((n_rows, n_bands, n_bands))),
            Stats(np.zeros(n_counters, np.int64), np.zeros((n_stats, 3))))
