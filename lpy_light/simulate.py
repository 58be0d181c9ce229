"""Run the photon kernel over a chamber: chunks, threads, reduction, standard errors.

Photons are traced in chunks of :data:`CHUNK` photons.  Chunk c holds photons
``c·CHUNK ..`` whose random streams depend on ``(seed, photon index)`` only, and
chunk results are summed in chunk order — so a run's numbers depend on the seed
and the photon count, never on the number of threads.
"""
from __future__ import annotations

import math
import os
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from .errors import InputError, ResourceError
from .kernel import embree
from .kernel.control import build_control
from .kernel.records import (DIFFUSE_R, DIFFUSE_T, Emitters, Geometry, Materials, Mirrors, NextEvents, OrganEvents,
                             Scene, Sensors, Zones, f64, i32, i64, new_tallies, u8)
from .kernel.nee import NEAR, SHARE_SCALE
from .kernel.organ_zones import ZONE_WALK, organ_zones
from .kernel.tallies import C_BATCHES, C_PICK_SHARE, C_PICK_VERTICES, N_COUNTERS
from .kernel.targets import build_targets, cluster_sums, cone_served, target_clusters
from .kernel.trace import trace_chunk
from .kernel.zones import near_zones
from .materials import SPECULAR_R, sampling_tables
from .geometry import coplanar_partners, mirror_planes, partner_free_boxes, plane_ids, triangle_areas, triangle_normals

CHUNK = 1 << 15
ESTIMATORS = ("weighted", "analog", "nee")
MAX_THREADS = 1024
MAX_SEED = 2 ** 63 - 1

# ------------------------------------------------------------------------------------------
# Memory: a run that cannot fit is refused before it allocates anything large.
#: bytes per triangle the kernel scene allocates: Embree's BVH and float32 copy (~150), the kernel's
#: vertex, normal, material, receiver and next-event arrays (~150), their chamber-side copies (~110)
BYTES_PER_TRIANGLE = 512
#: bytes per transparent sensor besides its tallies: bounding triangles, kernel and target arrays
BYTES_PER_SENSOR = 1024
#: share of the available memory a run may plan to use
MEMORY_SHARE = 0.9


def available_memory() -> int | None:
    """Bytes of memory available to a new allocation (Linux MemAvailable, else free pages), or None."""
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (AttributeError, ValueError, OSError):
        return None


def tally_bytes(n_rows: int, n_bands: int, n_stats: int = 0) -> int:
    """Bytes of one set of tallies: ``tally`` (rows, B), ``tally_prod`` (rows, B, B), counters, next-event stats."""
    return 8 * (n_rows * n_bands * (n_bands + 1) + 3 * n_stats + N_COUNTERS)


def memory_estimate(n_rows: int, n_bands: int, threads: int, triangles: int = 0, sensors: int = 0,
                    n_stats: int = 0) -> dict:
    """Bytes a run needs, by item: ``tallies`` — each thread holds up to two chunks' tallies in flight
    (2·threads), plus the running sum and the next sum (2), plus ~3 copies for the results'
    covariances; ``geometry`` — the kernel scene; ``total``."""
    one = tally_bytes(n_rows, n_bands, n_stats)
    copies = 2 * threads + 2 + 3
    out = {"tally_set": one, "tally_copies": copies, "tallies": one * copies,
           "geometry": BYTES_PER_TRIANGLE * triangles + BYTES_PER_SENSOR * sensors}
    out["total"] = out["tallies"] + out["geometry"]
    return out


def _gib(n) -> str:
    return "%.3g GiB" % (n / 2 ** 30)


def check_memory(n_rows: int, n_bands: int, threads: int, triangles: int = 0, sensors: int = 0,
                 n_stats: int = 0, what: str = "this run"):
    """Raise :class:`ResourceError` when :func:`memory_estimate` exceeds the available memory."""
    need = memory_estimate(n_rows, n_bands, threads, triangles, sensors, n_stats)
    free = available_memory()
    if free is None or need["total"] <= MEMORY_SHARE * free:
        return need
    raise ResourceError(
        "%s needs about %s of memory, more than the %s available: tallies %d rows x %d band(s) x %d band(s) "
        "x 8 bytes = %s, held %d times (2 per thread for %d thread(s), the sum, the covariances) = %s; "
        "geometry %d triangles, %d sensors = %s. Use fewer bands, sensors or threads"
        % (what, _gib(need["total"]), _gib(free), n_rows, n_bands, n_bands, _gib(need["tally_set"]),
           need["tally_copies"], threads, _gib(need["tallies"]), triangles, sensors, _gib(need["geometry"])))


@dataclass
class Result:
    """Sums over N traced photons.

    ``tally`` (K + M + 4, B): expected photon hits per row and band for the N
    photons emitted — rows: S sensors, R receiver incident, R receiver
    absorbed, then the fates: M materials (absorbed), escaped, cut at max
    depth, lost, and the per-photon total (closure: N in expectation);
    ``tally_prod`` (rows, B, B) the sums of products between bands of
    per-photon contributions (covariances: a sum of bands or a ratio of two
    gets an honest σ from :meth:`combination`) -- per batch of photons for the
    sensor rows of a run with the control variate (:func:`effective_samples`).
    """

    photons: int
    tally: np.ndarray
    tally_prod: np.ndarray
    counters: np.ndarray         # rays, candidate overflows, scratch flushes, lost, shadow rays
    seconds: float
    threads: int
    seed: int
    n_sensors: int
    n_receivers: int
    estimator: str = "weighted"
    materials: list = field(default_factory=list)   # names of the fate rows' materials
    nee_stats: np.ndarray | None = None   # (M + E + P, 3) rays cast, paths found, weight deposited (materials, lamp elements, mirror planes)
    partial: bool = False
    interrupted: bool = False     # stopped by KeyboardInterrupt (Ctrl-C), not by ``stop()``
    extra: dict = field(default_factory=dict)

    @property
    def _fate0(self) -> int:
        return self.n_sensors + 2 * self.n_receivers

    @property
    def fate(self) -> np.ndarray:
        """(M + 3, B) weight absorbed per material, escaped, cut at max depth, lost."""
        return self.tally[self._fate0:-1]

    @property
    def fate_std(self) -> np.ndarray:
        return self.tally_std[self._fate0:-1]

    @property
    def closure(self):
        """(accounted, std): per band, the photons' total deposits (N in expectation), each (B,)."""
        return self.tally[-1], self.tally_std[-1]

    @property
    def samples(self) -> np.ndarray:
        """Independent samples behind each row's sums of products, (rows,): see :func:`effective_samples`."""
        return effective_samples(self.photons, self.counters, len(self.tally), self.n_sensors)

    @property
    def tally_std(self) -> np.ndarray:
        """Standard error of each tally, (K, B)."""
        return _std(self.tally, self.tally_sq, self.photons, self.samples)

    @property
    def tally_sq(self) -> np.ndarray:
        """Sums of squared contributions, (rows, B): the diagonal of ``tally_prod``."""
        return np.diagonal(self.tally_prod, axis1=1, axis2=2)

    def covariance(self, rows) -> np.ndarray:
        """Covariance matrix between bands of the estimated totals of ``rows``, (len(rows), B, B)."""
        n = self.photons
        t = self.tally[rows]
        m = self.samples[rows][:, None, None]
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(m >= 2, n / (m - 1.0), np.nan) * (self.tally_prod[rows] - t[:, :, None] * t[:, None, :] / n)

    def combination(self, rows, weights):
        """Σ_b weights[b] · tally[row, b] and its standard error (bands' covariances included), each (len(rows),)."""
        w = np.asarray(weights, dtype=float)
        t = self.tally[rows]
        value = np.zeros(len(t))
        for b, wb in enumerate(w):      # not t @ w: BLAS's rounding depends on the machine's kernel, this does not
            value += t[:, b] * wb
        var = np.einsum("b,rbc,c->r", w, self.covariance(rows), w)
        return value, np.sqrt(np.maximum(var, 0.0))

    def sensors(self):
        """(photons, photons_std) for the transparent sensors, each (S, B)."""
        s = self.n_sensors
        return self.tally[:s], self.tally_std[:s]

    def receivers_incident(self):
        s, r = self.n_sensors, self.n_receivers
        return self.tally[s:s + r], self.tally_std[s:s + r]

    def receivers_absorbed(self):
        s, r = self.n_sensors, self.n_receivers
        return self.tally[s + r:s + 2 * r], self.tally_std[s + r:s + 2 * r]

    @property
    def rays(self) -> int:
        return int(self.counters[0])


class KernelScene:
    """A chamber turned into kernel arrays and an Embree scene (built once, reused by runs).

    Organs (:meth:`set_organs`) are a separate Embree geometry, replaced
    between growth steps while the chamber's geometry and arrays stay built.
    Receiver rows: the chamber's solid sensors first, then the organs in the
    order given.
    """

    def __init__(self, chamber, estimator: str = "weighted"):
        if estimator not in ESTIMATORS:
            raise ValueError("estimator must be one of %s, not %r" % (", ".join(ESTIMATORS), estimator))
        # refuse up front what cannot fit (one thread here; run() checks its own thread count)
        check_memory(len(chamber.sensors) + 2 * len(chamber.receivers) + len(chamber.materials) + 4,
                     chamber.n_bands, 1, triangles=len(chamber.triangles), sensors=len(chamber.sensors),
                     what="this scene")
        self.chamber = chamber
        self.estimator = estimator
        # next-event tallies (estimator "nee"): which targets get expected values instead of counts
        self.nee_sensors = self.nee_receivers = estimator == "nee"
        self.nee_picks = 1          # targets per next event, drawn at random (0: all of them)
        self.nee_control = True     # with picks: γ of every sensor at every vertex, picks carry the rest
        self.nee_batch = 8          # photons per batch of the control variate's products between bands
        self.nee_receiver_mask = None   # (R,) bool: receivers that are next-event targets (None: all)
        self.nee_images = 0.5       # next events through a perfect mirror per vertex, on average (0: none)
        self.nee_images2 = 0.25     # next events through two perfect mirrors per vertex, on average (0: none)
        self.nee_zones = 0.3        # two-step next events through the surface beside a disc, per vertex (0: none)
        self.nee_importance = True  # next events to organs: picks by importance (kernel.importance), organ zones
        self.nee_organ_zones = None  # two-step next events through the organ surface beside a bud, per vertex
                                     # (None: organ_zone_rate, 0.25 for closed buds up to 1 where all are open)
        self.nee_zone_walk = ZONE_WALK  # ... each walking on that many short legs inside the bud's zone at most
        self.nee_open_zones = True  # an open bud's own surface in its zone (set before set_organs)
        self.nee_pick_share = True  # picks to organs follow each vertex's pick share (kernel.nee.PICK_CAP; False:
                                    # nee_picks at every vertex); its mean from a pilot of PICK_PILOT photons
        self._pick_mean = {}        # that mean, per organs and settings (records())
        self.compile_seconds = 0.0  # seconds spent compiling the kernel for this scene (:func:`compile_kernel`)
        self.nee_cones = None       # rays into the cones of the organ clusters a vertex is far from, per vertex at most
                                    # (kernel.cones; 0: picks among all clusters instead; None: cones_for(targets))
        self.nee_local = None       # local rays per vertex near a cluster, to its large targets (kernel.cones.local_events;
                                    # 0: picks serve them; None: local_for(targets))
        tris = chamber.triangles
        area = 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)
        keep = np.isfinite(tris).all(axis=(1, 2)) & (area > 0)
        two = chamber.tri_two_sided & keep
        one = ~chamber.tri_two_sided & keep
        order = np.concatenate([np.flatnonzero(one), np.flatnonzero(two)])
        self.dropped = int((~keep).sum())
        self.order = order
        self.n_chamber_triangles = len(order)
        self.geom_offset = np.array([0, one.sum(), 0, len(order)], dtype=np.int64)
        self._chamber_normal = triangle_normals(tris[order])
        self._chamber_verts = tris[order].astype(np.float64)
        self._chamber_two_sided = chamber.tri_two_sided[order]
        self._chamber_mat = chamber.tri_material[order].astype(np.int32)
        self._chamber_receiver = chamber.tri_receiver[order].astype(np.int32)
        self._chamber_pid = plane_ids(tris[order])
        if getattr(chamber.physics, "coplanar", "random") == "random":
            self._chamber_cop = coplanar_partners(tris[order], np.asarray(chamber.tri_source)[order],
                                                  chamber.tri_two_sided[order])
        else:
            self._chamber_cop = (np.zeros(len(order) + 1, np.int64), np.zeros(0, np.int32))
        self._cop_pad = 1e-5 * max(float(np.abs(tris).max()) if len(tris) else 1.0, 1e-30)
        self._chamber_free = partner_free_boxes(tris[order], *self._chamber_cop, self._cop_pad)
        # planar perfect mirrors, for next events through one specular reflection (image method)
        spec = np.array([m.events[SPECULAR_R].max() > 0 for m in chamber.materials] + [False], bool)
        mats = chamber.tri_material[order]
        specular = (spec[mats[:, 0]] | (chamber.tri_two_sided[order] & spec[mats[:, 1]])) \
            if chamber.physics.specular == "mirror" and len(order) else np.zeros(len(order), bool)
        self._chamber_plane, self.mir_point, self.mir_normal, box, one_sided = mirror_planes(
            tris[order], np.asarray(chamber.tri_source)[order], specular, chamber.tri_two_sided[order])
        self.mir_box = np.ascontiguousarray(box + np.array([-1.0, 1.0])[None, :, None] * self._cop_pad)
        self.mir_one_sided = one_sided.astype(np.uint8)
        self.mir_on = np.ones(len(self.mir_point), np.uint8)
        # each plane's largest specular reflectance (its sides', over bands) and its area: with the distance
        # from a vertex, how often the plane is drawn there (kernel.images.plane_importance)
        spec_b = np.array([m.events[SPECULAR_R].max() for m in chamber.materials] + [0.0])
        side_spec = np.maximum(spec_b[mats[:, 0]], np.where(chamber.tri_two_sided[order], spec_b[mats[:, 1]], 0.0)) \
            if len(order) else np.zeros(0)
        on_plane = self._chamber_plane >= 0
        self.mir_spec = np.zeros(len(self.mir_point))
        np.maximum.at(self.mir_spec, self._chamber_plane[on_plane], side_spec[on_plane])
        self.mir_area = np.bincount(self._chamber_plane[on_plane], weights=triangle_areas(tris[order][on_plane]),
                                    minlength=len(self.mir_point)).astype(np.float64)
        sensors = chamber.sensors
        self.scene = embree.EmbreeScene(one_sided=tris[one], two_sided=tris[two],
                                        sensors=sensors.bounding_triangles() if len(sensors) else None)
        self.materials = list(chamber.materials)
        self._chamber_flush = sensors.flush_with(self._chamber_verts, self._chamber_normal)
        # the kernel's records of the sensors (their flush lists follow the organs: _assemble) and lamps
        self.sens = Sensors(i32(sensors.kind), f64(sensors.center), f64(sensors.normal), f64(sensors.radius),
                            f64(np.reshape(sensors.corners, (-1, 4, 3))), np.zeros(1, np.int64), np.zeros(1, np.int64))
        em = chamber.emitters
        self.emit = Emitters(i32(em.kind), f64(np.reshape(em.data, (-1, 3, 3))), f64(em.cdf))
        self.n_sensors = len(sensors)
        self.n_chamber_receivers = len(chamber.receivers)
        self.n_bands = chamber.n_bands
        self.intersect = embree.intersect1_address()
        self.occluded = embree.occluded1_address()
        self.emit_nee = np.ones(len(em.kind), np.uint8)
        self.mat_nee = np.ones(0, np.uint8)
        self.organs = []
        # organs seen from their front only, as one-sided surfaces: a photon meets no back face (it passes
        # through).  An ablation, to compare with engines that cull back faces (the seed's photon mapping,
        # benchmarks/seed_plant.py), not physics: a leaf has two faces.  Takes effect at set_organs().
        self.one_sided_organs = False
        self._assemble(np.zeros((0, 3, 3)), np.zeros((0, 2), np.int32), np.zeros(0, np.int32))

    # A KernelScene pickles without its Embree scene and the C function addresses (a ctypes handle and
    # this process's pointers): unpickling rebuilds them from the same triangles, so a copy on another
    # process or machine (a Dask worker: lpy_light.cluster) traces bitwise what this one traces, with
    # every setting and the pruning outcome as they are here.
    _NOT_PICKLED = ("scene", "intersect", "occluded")

    def __getstate__(self):
        return {k: v for k, v in self.__dict__.items() if k not in self._NOT_PICKLED}

    def __setstate__(self, state):
        self.__dict__.update(state)
        self.intersect = embree.intersect1_address()
        self.occluded = embree.occluded1_address()
        n_one, n = int(self.geom_offset[1]), self.n_chamber_triangles
        sensors = self.chamber.sensors
        self.scene = embree.EmbreeScene(one_sided=self._chamber_verts[:n_one], two_sided=self._chamber_verts[n_one:n],
                                        sensors=sensors.bounding_triangles() if len(sensors) else None)
        if self.organs:
            self.scene.set_organs(self.tri_verts[n:], one_sided=getattr(self, "one_sided_organs", False))

    def _assemble(self, verts, mat, receiver):
        self.tri_verts = np.ascontiguousarray(np.concatenate([self._chamber_verts, verts]))
        normal = triangle_normals(verts) if len(verts) else np.zeros((0, 3))
        self.two_sided = np.concatenate([self._chamber_two_sided, np.full(len(verts), not self.one_sided_organs)])
        self.tri_normal = np.ascontiguousarray(np.concatenate([self._chamber_normal, normal]))
        self.tri_mat = np.ascontiguousarray(np.concatenate([self._chamber_mat, mat]).astype(np.int32))
        self.tri_receiver = np.ascontiguousarray(np.concatenate([self._chamber_receiver, receiver]).astype(np.int32))
        self.tri_plane = np.ascontiguousarray(np.concatenate([self._chamber_plane, np.full(len(verts), -1, np.int32)]))
        self.tri_pid = np.ascontiguousarray(np.concatenate([self._chamber_pid, np.full(len(verts), -1, np.int32)]),
                                            dtype=np.int32)
        start, partners = self._chamber_cop
        self.cop_start = np.ascontiguousarray(np.concatenate([start, np.full(len(verts), start[-1], np.int64)]))
        self.cop_list = np.ascontiguousarray(partners if len(partners) else np.zeros(1, np.int32))
        start, flush = self._chamber_flush            # sensors lying on chamber triangles (none on organs)
        self.sens = self.sens._replace(flush_start=i64(np.concatenate([start, np.full(len(verts), start[-1], np.int64)])),
                                       flush_list=i64(flush if len(flush) else np.zeros(1, np.int64)))
        self.tri_two_sided = np.ascontiguousarray(self.two_sided.astype(np.uint8))
        tv = self.tri_verts
        pad = self._cop_pad
        self.cop_box = np.ascontiguousarray(np.stack([tv.min(axis=1) - pad, tv.max(axis=1) + pad], axis=1)
                                            if len(tv) else np.zeros((0, 2, 3)))
        empty = np.tile(np.array([[1.0, 1.0, 1.0], [-1.0, -1.0, -1.0]]), (len(verts), 1, 1))
        self.cop_free = np.ascontiguousarray(np.concatenate([self._chamber_free.reshape(-1, 2, 3), empty]))
        self.mat_prob, self.mat_cum, self.band_pass, self.mat_phong = sampling_tables(
            self.materials, self.chamber.physics.specular, "analog" if self.estimator == "analog" else "weighted")
        self.n_receivers = self.n_chamber_receivers + len(self.organs)
        self.n_rows = self.n_sensors + 2 * self.n_receivers + len(self.materials) + 4
        if len(self.mat_nee) < len(self.materials):     # new materials start with next events on
            self.mat_nee = np.concatenate([self.mat_nee, np.ones(len(self.materials) - len(self.mat_nee), np.uint8)])
        self.retarget()

    def retarget(self):
        """Rebuild the next-event target arrays after a change of organs or of ``nee_*`` flags."""
        mask = self.nee_receiver_mask
        key = (id(self.tri_verts), self.tri_verts.shape, id(self.tri_receiver), id(self.sens), bool(self.nee_sensors), bool(self.nee_receivers),
               int(self.nee_picks), bool(self.nee_importance), None if mask is None else np.asarray(mask).tobytes())
        if getattr(self, "_targets_key", None) == key:
            return                   # the same organs and flags: the arrays built last time still hold
        self._targets_key = key
        sensors = self.chamber.sensors
        if len(sensors):
            half_diag = np.linalg.norm(sensors.corners - sensors.center[:, None, :], axis=2).max(axis=1)
            bound = np.where(sensors.kind == 0, sensors.radius, half_diag)
        else:
            bound = np.zeros(0)
        # a Targets record; its settings (picks, sources switched on) are filled in by records()
        self.targets = tgt = build_targets(
            self.sens, sensors.area, bound, self.n_receivers, self.tri_receiver, self.tri_verts, self.two_sided,
            sensors=self.nee_sensors, receivers=self.nee_receivers, receiver_mask=self.nee_receiver_mask)
        # zones beside discs for two-step next events (only with random picks, where discs have own events)
        n_tgt = len(tgt.kind)
        disc_radius = np.zeros(n_tgt)
        on = tgt.sensor_target >= 0
        disc_radius[tgt.sensor_target[on]] = np.where(self.sens.kind[on] == 0, self.sens.radius[on], 0.0)
        disc_normal = np.zeros((n_tgt, 3))
        disc_normal[tgt.sensor_target[on]] = self.sens.normal[on]
        if self.nee_sensors and 0 < self.nee_picks < n_tgt:
            self.zones = near_zones(self.tri_verts, self.tri_pid, self.n_chamber_triangles, tgt.near_start,
                                    tgt.near_list, tgt.near_r2, tgt.center, disc_radius, disc_normal)
        else:
            self.zones = Zones(0.0, np.zeros((0, 14)), np.zeros((0, 2), np.int64), np.zeros(n_tgt + 1, np.int64))
        # next events to organs (the plant's organs are the targets, with random picks): picks by importance over
        # clusters of targets, two-step events through the organ surface beside an organ
        self.organ_events = None
        if self.nee_importance and self.nee_receivers and not self.nee_sensors and 0 < self.nee_picks < n_tgt:
            clusters = target_clusters(tgt.center, np.sqrt(tgt.img_near2) / NEAR)
            weight = np.ones(n_tgt)
            zones = organ_zones(self.tri_verts, self.tri_receiver, self.tri_pid, tgt.near_start, tgt.near_list,
                                tgt.near_r2, tgt.kind, tgt.ref, tgt.center, clusters,
                                (tgt.facing == 0) & bool(self.nee_open_zones))
            cluster_of = np.zeros(n_tgt, np.int64)
            cluster_of[clusters.member] = np.repeat(np.arange(len(clusters.radius)), np.diff(clusters.start))
            self.organ_events = OrganEvents(clusters, weight, weight, cluster_sums(weight, clusters), cluster_of,
                                            0.0, weight, 0.0, zones, 0.0, 1.0, np.ones(0))
            self._pick_mean = {}

    def prune_next_events(self, photons: int = 8192, max_share: float = 0.0, seed: int = 987654321,
                          threads=None, min_rays: int = 256, keep=()) -> dict:
        """Switch off next events from vertices whose shadow rays bring (almost) nothing.

        A pilot run sums, per material and per emitter element, the shadow rays
        cast and the weight they deposit on targets.  Sources are switched off
        (their segments counted instead), cheapest-to-lose first, while the
        weight they carry stays within ``max_share`` of the total: by default 0,
        i.e. only sources none of whose pilot shadow rays reached a target —
        e.g. lamps and mirrors inside a lamp box behind a diffuser, whose shadow
        rays are all blocked (Angers: the same sources as with 1e-3).  Either
        choice is unbiased; this only saves shadow rays.  (A share of the total,
        1e-3 before the eighth session, switched off a table whose light was
        most of a 3 mm sensor's above it: that sensor then waited for photons
        to cross it, and read 3e-9 ± 9e-9 for 3.7e-6.)  A source is switched
        off only on evidence: at least ``min_rays`` pilot shadow rays, none of
        which found a target (the floor below the Angers table cast ~40 rays in
        the pilot; switched off, the light it sends up to the rose's buds was
        counted, and held most of their variance: PAR spread 10-25 % over seeds
        against 1-7 % with it on); a source with fewer rays costs next to nothing
        anyway.  Materials named in ``keep`` (the plant's organs) stay on.
        Mirror planes are switched off only when the pilot brought no light
        through them (not by ``max_share``: a plane's light is then counted,
        rarely and with a photon's whole weight, while its events cost only
        when drawn, and they are drawn by their importance at each vertex).
        Switching off the planes that brought under 1 % of it, as before the
        twelfth session, left the aluminium strips under the Angers ceiling to
        counting: most of the median sensor's variance.
        Returns ``{name: (share of shadow rays, share of deposit)}`` of the pilot
        and the names switched off under ``"off"``.
        """
        if not (self.nee_sensors or self.nee_receivers):
            return {}
        self.mat_nee[:] = 1
        self.emit_nee[:] = 1
        self.mir_on[:] = 1
        pilot = run(self, photons, seed=seed, threads=threads)
        if pilot.interrupted:
            raise KeyboardInterrupt      # Ctrl-C during the pilot: stop, do not trace on with half a pilot
        stats = pilot.nee_stats
        M = len(self.materials)
        cast, weight = stats[:, 0], stats[:, 2]
        total_w, total_c = max(weight.sum(), 1e-300), max(cast.sum(), 1.0)
        on = np.ones(len(stats), bool)
        lost = 0.0
        E = len(self.emit_nee)
        kept = {i for i, m in enumerate(self.materials) if m.name in set(keep)}
        for i in np.argsort(weight / np.maximum(cast, 1.0)):    # least weight per ray first
            if cast[i] < max(min_rays, 1) or i >= M + E or i in kept:
                continue          # (mirror planes: by their share below -- a plane's light lost is counted,
                                  # rarely and at a high price, while its events cost only when drawn)
            if lost + weight[i] > max_share * total_w:
                break
            on[i] = False
            lost += weight[i]
        self.mat_nee = np.ascontiguousarray(on[:M], dtype=np.uint8)
        self.emit_nee = np.ascontiguousarray(on[M:M + E], dtype=np.uint8)
        # mirror planes: off when the pilot drew none or brought nothing through them (each plane is drawn at
        # a vertex by its importance there, so one the pilot never drew is one no vertex faces)
        on[M + E:] &= weight[M + E:] > 0.0
        self.mir_on = np.ascontiguousarray(on[M + E:], dtype=np.uint8)
        names = ([m.name for m in self.materials] + ["lamp element %d" % e for e in range(E)]
                 + ["mirror plane %d" % k for k in range(len(self.mir_on))])
        report = {names[i]: (float(cast[i] / total_c), float(weight[i] / total_w)) for i in range(len(stats))
                  if cast[i] > 0}
        report["off"] = [names[i] for i in range(len(stats)) if not on[i] and cast[i] > 0]
        return report

    def material_index(self, material) -> int:
        """Index of ``material`` (a :class:`~lpy_light.materials.Material`), added if new (by name)."""
        for i, m in enumerate(self.materials):
            if m.name == material.name and m.type == material.type:
                return i
        self.materials.append(material)
        return len(self.materials) - 1

    def set_organs(self, organs, materials: dict, targets=None):
        """Put ``organs`` (list of :class:`~lpy_light.organs.Organ`) in the chamber, replacing the previous ones.

        ``materials`` maps each front/back name to its Material.  Organ i is
        receiver ``n_chamber_receivers + i``.  ``targets`` (len(organs),) bool or
        None: which organs next events aim at (None: all).
        """
        self.organs = list(organs)
        self.nee_receiver_mask = None if targets is None else np.concatenate(
            [np.ones(self.n_chamber_receivers, bool), np.asarray(targets, bool).reshape(len(self.organs))])
        R0 = self.n_chamber_receivers
        tris = [o.triangles for o in self.organs]
        mats, recv = [], []
        for i, o in enumerate(self.organs):
            front, back = self.material_index(materials[o.front]), self.material_index(materials[o.back])
            mats.append(np.tile(np.int32([front, back]), (len(o.triangles), 1)))
            recv.append(np.full(len(o.triangles), R0 + i, np.int32))
        if tris:
            tris = np.concatenate(tris).astype(np.float64)
            self._assemble(tris, np.concatenate(mats), np.concatenate(recv))
        else:
            tris = None
            self._assemble(np.zeros((0, 3, 3)), np.zeros((0, 2), np.int32), np.zeros(0, np.int32))
        self.scene.set_organs(tris, one_sided=self.one_sided_organs)

    def records(self, note=None):
        """The kernel's records of this scene as it stands (:mod:`lpy_light.kernel.records`), with the current
        settings (``nee_*``, the sources and mirror planes switched on): ``(Scene, NextEvents or None)``, None
        where next events have no target (``weighted``, ``analog``).  Built once per run.  With organs as
        targets and ``nee_pick_share``, the vertices' mean pick share comes from a pilot of :data:`PICK_PILOT`
        photons (one chunk, a fixed seed: the same for the same organs and settings, on any number of threads),
        once per organs and settings; ``note`` as :func:`compile_kernel`'s, if the kernel compiles for it."""
        phys = self.chamber.physics
        nee = self.nee_sensors or self.nee_receivers
        geometry = Geometry(self.scene.handle, self.intersect, self.occluded, float(phys.offset), i64(self.geom_offset),
                            f64(self.tri_verts), f64(self.tri_normal), i32(self.tri_mat), i32(self.tri_receiver),
                            self.tri_two_sided, i32(self.tri_plane), i32(self.tri_pid), i64(self.cop_start),
                            i32(self.cop_list), f64(self.cop_box), f64(self.cop_free), int(self.n_receivers))
        materials = Materials(f64(self.mat_prob), f64(self.mat_cum), i64(self.band_pass), f64(self.mat_phong),
                              self.estimator != "analog", int(phys.max_depth))
        targets = self.targets._replace(on_sensors=bool(self.nee_sensors), on_receivers=bool(self.nee_receivers),
                                        picks=int(self.nee_picks), from_material=u8(self.mat_nee),
                                        from_emitter=u8(self.emit_nee))
        plane = np.flatnonzero(self.mir_on).astype(np.int32)
        mirrors = Mirrors(float(self.nee_images) if nee else 0.0, float(self.nee_images2) if nee else 0.0, i32(plane), f64(self.mir_spec), f64(self.mir_area),
                          u8(self.mir_on),
                          f64(self.mir_point), f64(self.mir_normal), f64(self.mir_box), u8(self.mir_one_sided))
        zones = self.zones._replace(picks=float(self.nee_zones) if self.nee_sensors else 0.0)
        scene = Scene(geometry, materials, self.emit, self.sens)
        if len(targets.kind) == 0:
            return scene, None
        control = build_control(targets, self.sens, bool(self.nee_control), int(self.nee_batch))
        organs = None
        if self.organ_events is not None:      # a plant's organs are the targets (LightModel)
            ev = self.organ_events
            far = ev.weight
            cones = cones_for(len(self.targets.kind)) if self.nee_cones is None else float(self.nee_cones)
            large = cone_served(self.targets.area, ev.clusters)
            if cones > 0:        # large targets served by cone rays from vertices far from their cluster
                far = np.where(large, 0.0, ev.weight)
            local = local_for(len(self.targets.kind)) if self.nee_local is None else float(self.nee_local)
            near = np.where(large, 0.0, ev.weight) if local > 0 else ev.weight    # ... by local rays from near ones
            # organ zone events for the small targets only (buds): a leaf's near light comes well enough from its
            # own events, and the zone events' own noise was the largest part of some leaves' variance (a 16-rose
            # canopy's p90 leaf: 49 % of σ² for 4 % of its light)
            zw = np.where(large, 0.0, ev.zones.weight)
            rate = organ_zone_rate(zw, ev.zones.own) if self.nee_organ_zones is None else float(self.nee_organ_zones)
            organs = ev._replace(weight=f64(ev.weight), far_weight=f64(far), cluster_weight=cluster_sums(far, ev.clusters),
                                 cones=cones, near_weight=f64(near), local=local,
                                 zones=ev.zones._replace(picks=rate, weight=f64(zw), walk=int(self.nee_zone_walk),
                                                         cluster_weight=cluster_sums(zw, ev.clusters)),
                                 pick_unit=self._pick_unit(), pick_side=self._pick_side())
        recs = scene, NextEvents(targets, mirrors, zones, control, organs)
        if organs is not None and self.nee_pick_share:
            recs = self._with_pick_mean(recs, note)
        return recs

    def _pick_unit(self) -> float:
        """The unit of the pick shares counted by the kernel: (targets) / (the chamber's diagonal)²."""
        span = self.tri_verts[:self.n_chamber_triangles].reshape(-1, 3)
        diag2 = float(np.sum((span.max(axis=0) - span.min(axis=0)) ** 2)) if len(span) else 1.0
        return len(self.targets.kind) / max(diag2, 1e-300)

    def _pick_side(self) -> np.ndarray:
        """Per material, the band mean of its larger diffuse reflectance or transmittance, (M,)."""
        return f64(np.maximum(self.mat_prob[:, DIFFUSE_R, :], self.mat_prob[:, DIFFUSE_T, :]).mean(axis=1))

    def _with_pick_mean(self, recs, note=None):
        """``recs`` with ``organs.pick_mean`` set: the vertices' mean pick share in a pilot that draws
        ``nee_picks`` at every vertex (cached per organs and settings)."""
        scene, nee = recs
        org = nee.organs
        key = (self.nee_picks, org.cones, org.local, org.zones.picks, nee.mirrors.picks, nee.mirrors.picks2,
               bytes(self.mat_nee), bytes(self.emit_nee), bytes(self.mir_on), self.estimator)
        if key not in self._pick_mean:
            compile_kernel(self, recs, note)
            _, _, counters, _ = self.trace(PICK_SEED, 0, PICK_PILOT, recs)
            n = int(counters[C_PICK_VERTICES])
            self._pick_mean[key] = (float(counters[C_PICK_SHARE]) / SHARE_SCALE / n * org.pick_unit) if n else 0.0
        return scene, nee._replace(organs=org._replace(pick_mean=self._pick_mean[key]))

    def trace(self, seed: int, first: int, count: int, records=None):
        """Trace one chunk through ``records`` (default: :meth:`records` now); returns (tally, tally_sq,
        counters, nee_stats)."""
        scene, nee = self.records() if records is None else records
        tallies, stats = new_tallies(self.n_rows, self.n_bands,
                                     len(self.materials) + len(self.emit_nee) + len(self.mir_point), N_COUNTERS)
        scratch = embree.new_scratch()
        trace_chunk(scene, nee, scratch.ctypes.data, seed, first, count, tallies, stats)
        return tallies.tally, tallies.tally_sq, stats.counters, stats.nee_stats


#: a kernel not ready after this many seconds is being compiled (loading numba's cache takes well under it)
COMPILE_NOTE_AFTER = 1.0
#: photons of the pilot that finds the vertices' mean pick share for a plant's organs (KernelScene.records), its seed
PICK_PILOT = 8192
PICK_SEED = 271828


#: cone rays per vertex (:mod:`kernel.cones`) by default, for scenes of at least :data:`CONE_TARGETS` organ targets:
#: 12 since the mirror's light comes by cone rays too (kernel.images.image_cones) and organ zone events serve the
#: buds only, which left the direct cone rays' own noise 98 % of the p90 leaf's variance on 16 roses
#: (``benchmarks/canopy.py``, cost to leaves' p90 3 %, one seed: 16 roses 6 rays 100.7 CPU s, 8 90.1, 12 79.1,
#: 16 80.2; 4 roses 8 rays 12.0, 12 10.6; with 4 rays, before the organ zones' change, 16 roses cost 131).
#: 24 since local rays serve the near clusters' leaves (eighteenth session), which left the cone rays most of the
#: variance: 16 roses 12 rays 48.1, 24 40.9; 4 roses 7.0 either way.
#: 10 since the rays follow each vertex's weight × cone share, a quarter of that near a cluster
#: (:data:`lpy_light.kernel.cones.W_FULL`; nineteenth session): 16 roses 6 rays 32.4, 8 28.1-29.9, 12 29.4
CONE_RAYS = 10.0
#: below this many targets, picks alone serve the organs by default: a plant's few hundred targets are each drawn
#: often enough from far vertices that the rays cost more than they save (the rose of ``lsystems/rose.lpy`` in
#: L-Py at step 29, 1e6 photons: the step 2.6 → 6.3 s, leaves' σ 1.6 → 1.2 %, buds' 3.8 → 3.7 %; the
#: procedural rose of ``benchmarks/rose.py``, 344 targets: leaves' σ² × time 2x lower, buds' 1.15x); a canopy of
#: 4 roses (1,376 targets) and more gains (``benchmarks/canopy.py``: 16 roses' cost to leaves 3 % 3.5x lower)
CONE_TARGETS = 1000


ZONES_CLOSED = 0.25     # organ zone events per vertex where every bud with a zone is closed (rose.lpy's icospheres)
ZONES_OPEN = 1.0        # ... where every one is open (rose-simple4's F() Sphere() tubes)


def organ_zone_rate(weight, own) -> float:
    """The default organ zone events per vertex (``KernelScene.nee_organ_zones`` None), for the zone weights
    ``weight`` (n,) (> 0: the target has zone events) and ``own`` (n,) (its own surface is in its zone: an open
    organ): from :data:`ZONES_CLOSED` to :data:`ZONES_OPEN` with the share of open ones.  An open bud's far red
    comes mostly through its zone events (entries into the tube, then walks), so more of them pay there: on
    rose-simple4 at lit step 15, 1 event per vertex against 0.25 gave the R:FR's spread over eight seeds 0.063
    → 0.028 for +44 % CPU (its variance 2.2x lower per CPU second), 2 per vertex 0.030 for +91 %; a closed bud's
    light comes mostly from picks and own events (the procedural rose: no rate from 0 to 1.5 moved its σ²·CPU
    by more than ~10 %)."""
    zoned = np.asarray(weight) > 0
    share = float(np.mean(np.asarray(own)[zoned] != 0)) if zoned.any() else 0.0
    return ZONES_CLOSED + (ZONES_OPEN - ZONES_CLOSED) * share


#: local rays per vertex near a cluster of organ targets (:func:`lpy_light.kernel.cones.local_events`; at a vertex whose
#: photon has mean weight :data:`~lpy_light.kernel.cones.W_FULL`, more or fewer with it) by default,
#: serving the large targets (leaves) of the clusters the vertex is near in place of their own events and picks,
#: for scenes of at least :data:`CONE_TARGETS` organ targets (a canopy: 16 roses' cost to leaves' p90 3 % 67 → 48
#: CPU s with 12 cone rays).  A single plant keeps its own events and picks: on the rose of ``lsystems/rose.lpy``
#: (step 14, 1e6 photons, seeds 20-25) 8 local rays gave leaves' median σ 0.98 → 1.10 % and buds' 1.93 → 2.15 %
#: for the same CPU (a leaf's own events serve the few leaves around it well; on the procedural rose of
#: ``benchmarks/rose.py`` leaves' p90 went 2.7 → 2.5 %: no gain worth a second behaviour)
LOCAL_RAYS = 8.0


def local_for(n_targets: int) -> float:
    """The default number of local rays per vertex near a cluster for a scene of ``n_targets`` organ targets (see
    above)."""
    return LOCAL_RAYS if n_targets >= CONE_TARGETS else 0.0


def cones_for(n_targets: int) -> float:
    """The default number of cone rays per vertex for a scene of ``n_targets`` organ targets (see above)."""
    return CONE_RAYS if n_targets >= CONE_TARGETS else 0.0


def compile_kernel(kscene: KernelScene, records=None, note=None) -> float:
    """Make the kernel ready for ``records`` (default: ``kscene.records()``) by tracing no photon: numba
    compiles :func:`~lpy_light.kernel.trace.trace_photons` for their types on the first run (~14 s for
    ``nee`` on 2 cores, its helpers shared with a child process: :mod:`lpy_light.kernel.warm`; ~3 s for
    ``weighted`` and ``analog``; then cached on disk, :func:`lpy_light.kernel.numba_cache_dir`) or loads it
    from its cache (< 1 s), or finds it compiled in this process.

    ``note(text)`` is called once, from another thread, if that takes longer than
    :data:`COMPILE_NOTE_AFTER` seconds: a compile, which a progress line should name rather than count as
    tracing (and which is added to ``kscene.compile_seconds``).  Returns the seconds it took."""
    start = time.perf_counter()
    done = threading.Event()

    def tell():
        if not done.wait(COMPILE_NOTE_AFTER) and note is not None:
            note("compiling the kernel, first run only (cached for the next runs) ...")

    watcher = threading.Thread(target=tell, daemon=True)
    watcher.start()
    try:
        kscene.trace(0, 0, 0, records)
    finally:
        done.set()
        watcher.join()
    seconds = time.perf_counter() - start
    if seconds > COMPILE_NOTE_AFTER:            # a compile: counted on the scene, for a growth step to report
        kscene.compile_seconds = getattr(kscene, "compile_seconds", 0.0) + seconds
    return seconds


def default_threads() -> int:
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1))


def effective_samples(n, counters, n_rows, n_sensors) -> np.ndarray:
    """Independent samples behind each tally row's sums of products, (n_rows,) float.

    Every row sums per-photon products, so N photons are N samples -- except the sensor rows of a
    ``nee`` run with the control variate, whose products are taken per batch of photons
    (:func:`lpy_light.kernel.control.control_products`): ``counters[C_BATCHES]`` samples there.
    """
    m = np.full(n_rows, float(n))
    batches = int(counters[C_BATCHES]) if len(counters) > C_BATCHES else 0
    if batches:
        m[:n_sensors] = batches
    return m


def _std(total, sq, n, samples):
    """Standard error of totals of n photons from their sums of squares, (rows, B); ``samples`` (rows,):
    N / (m − 1) · (Σ x² − T² / N) with m the row's independent samples (N, or its batches)."""
    m = np.asarray(samples, dtype=float).reshape(-1, *([1] * (np.ndim(total) - 1)))
    with np.errstate(divide="ignore", invalid="ignore"):
        var = np.where(m >= 2, n / (m - 1.0), np.nan) * np.maximum(sq - total * total / max(n, 1), 0.0)
    return np.sqrt(var)


def relative_sigma(tally, tally_prod, n, rows, samples=None) -> np.ndarray:
    """σ / value of the given tally rows (all bands), for rows with a value > 0; shape (k,).
    ``samples`` (all rows,): :func:`effective_samples` (default: n for every row)."""
    t, sq = tally[rows], np.diagonal(tally_prod[rows], axis1=1, axis2=2)
    if n < 2:
        return np.full(t.size, np.inf)
    m = np.full(len(tally), float(n)) if samples is None else np.asarray(samples, dtype=float)
    std = _std(t, sq, n, m[rows])
    keep = t > 0
    with np.errstate(invalid="ignore"):
        rel = np.where(np.isfinite(std), std, np.inf)[keep] / t[keep]
    return rel.ravel()


class LocalThreads:
    """Chunks traced by a pool of threads in this process: :func:`run`'s default executor.

    An executor of :func:`run` is where chunks are traced, and only that; the merge in chunk
    order, ``precision``, ``progress`` and interrupts are :func:`run`'s, whatever the executor.
    Its methods:

    * ``open(kscene, n_chunks) -> slots``: get ready to trace ``kscene``; ``slots`` is how many
      tasks it runs at once (:func:`run` keeps ``2 · slots`` submitted).  Here it also makes the kernel
      ready (:func:`compile_kernel`, telling ``progress.note`` if it compiles), so that :func:`run`'s
      rate and seconds are of tracing only;
    * ``chunks_per_task`` (read after ``open``): consecutive chunks in one task (1 here);
    * ``submit(seed, chunks) -> future``: ``[kscene.trace(seed, first, count) for first, count in
      chunks]`` somewhere, a future with ``result()`` and ``cancel()`` (:func:`run` sums each chunk's
      tallies alone, in chunk order, and cancels the tasks it will not sum);
    * ``close()``: release what ``open`` took;
    * ``describe() -> dict``: where the run was traced, for ``summary.json`` (empty here).

    ``threads``: the chunks traced at once, known before ``open`` (memory check).
    :class:`lpy_light.cluster.DaskChunks` is the other one: chunks as tasks on a Dask cluster.
    """

    def __init__(self, threads: int | None = None):
        threads = threads or default_threads()
        if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or not 1 <= threads <= MAX_THREADS:
            raise InputError("threads must be in 1..%d, got %r" % (MAX_THREADS, threads))
        self.threads = int(threads)
        self._pool = self._kscene = self._records = None

    def open(self, kscene, n_chunks: int, note=None) -> int:
        self._kscene = kscene
        self._records = kscene.records(note)             # the kernel's records, once for the run
        compile_kernel(kscene, self._records, note)      # here, so that a first run's compile is not tracing
        self.threads = min(self.threads, n_chunks)      # more threads than chunks would only wait
        self._pool = ThreadPoolExecutor(max_workers=self.threads)
        return self.threads

    chunks_per_task = 1

    def submit(self, seed: int, chunks):
        (first, count), = chunks
        return self._pool.submit(lambda: [self._kscene.trace(seed, first, count, self._records)])

    def close(self):
        if self._pool is not None:
            self._pool.shutdown(wait=True)      # chunks already running finish (and are not summed)
            self._pool = self._kscene = self._records = None

    def describe(self) -> dict:
        return {}


def run(kscene: KernelScene, photons: int, seed: int = 1, threads: int | None = None, progress=None,
        stop=None, precision: float | None = None, precision_rows=None, min_photons: int = 4 * CHUNK,
        precision_of=None, executor=None) -> Result:
    """Trace ``photons`` photons over ``threads`` threads (or on ``executor``).

    ``progress(done, total, seconds)`` is called as chunks finish;  ``stop()``
    returning True ends the run early: the result then holds the chunks finished
    so far (a prefix of the run, correctly normalised) and ``partial`` is True.
    A KeyboardInterrupt (Ctrl-C) does the same, and also sets ``interrupted``.

    Refused up front (:class:`~lpy_light.errors.ResourceError`) when the tallies
    of ``threads`` threads would not fit in the available memory
    (:func:`check_memory`).

    ``precision``: stop as soon as every tally in ``precision_rows`` (default:
    the sensors, else the receivers' incident rows) that has a value has a
    relative σ ≤ ``precision`` (checked in chunk order after ``min_photons``,
    so the stopping point depends on the seed only); ``photons`` is then a cap.
    ``precision_of(result)``, if given, replaces that rule: it gets a :class:`Result` of the photons so
    far and returns the largest relative σ of what the caller reads (e.g. organs' PAR and R:FR).
    ``extra["precision_reached"]`` says whether it was met.  ``progress`` then
    gets, as its total, the photons that the largest σ so far says are needed.

    ``executor``: where the chunks are traced (see :class:`LocalThreads`, the
    default, with ``threads``; :class:`lpy_light.cluster.DaskChunks` on a Dask
    cluster).  Chunk c's photons and random streams are the same wherever it runs
    and chunks are summed here in chunk order, so the numbers do not depend on it.
    """
    if photons < 1:
        raise ValueError("photons must be >= 1")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed <= MAX_SEED:
        raise InputError("the seed must be a whole number in 0..2^63-1, got %r" % (seed,))
    executor = executor if executor is not None else LocalThreads(threads)
    n_chunks = math.ceil(photons / CHUNK)
    n_stats = len(kscene.materials) + len(kscene.emit_nee) + len(getattr(kscene, "mir_point", ()))
    check_memory(kscene.n_rows, kscene.n_bands, min(getattr(executor, "threads", 1), n_chunks), n_stats=n_stats)
    acc = [np.zeros((kscene.n_rows, kscene.n_bands)), np.zeros((kscene.n_rows, kscene.n_bands, kscene.n_bands)),
           np.zeros(N_COUNTERS, np.int64), np.zeros((n_stats, 3))]

    def chunk(c):
        return c * CHUNK, min(CHUNK, photons - c * CHUNK)

    done = 0
    partial = interrupted = False
    start = time.perf_counter()
    reached = None
    if precision is not None:
        if precision_rows is None:
            precision_rows = (np.arange(kscene.n_sensors) if kscene.n_sensors else
                              kscene.n_sensors + np.arange(kscene.n_receivers))
        precision_rows = np.asarray(precision_rows, dtype=np.int64)
        reached = False

    def largest_sigma(acc, done) -> float:
        """The largest relative σ the precision goal is about (inf while nothing is tallied)."""
        if precision_of is not None:
            return float(precision_of(Result(done, acc[0], acc[1], acc[2], 0.0, threads, seed, kscene.n_sensors,
                                             kscene.n_receivers, estimator=kscene.estimator)))
        rel = relative_sigma(acc[0], acc[1], done, precision_rows,
                             effective_samples(done, acc[2], kscene.n_rows, kscene.n_sensors))
        return float(rel.max()) if rel.size else float("inf")

    # (sums, photons) change together in one assignment, so that an interrupt (KeyboardInterrupt)
    # arriving anywhere leaves the sums of exactly ``done`` photons: a correctly normalised prefix
    state = (acc, 0)
    # the control variate's products are taken per batch of nee_batch photons (kernel.control.control_products);
    # a run too short for 64 batches takes them per photon, so that its σ rests on enough samples
    batch = getattr(kscene, "nee_batch", None)
    if batch is not None and photons < 64 * batch:
        kscene.nee_batch = 1
    slots = 1
    pending = []
    try:
        try:
            # after nee_batch: an executor may copy the scene; LocalThreads compiles the kernel (first run only)
            note = getattr(progress, "note", None)
            slots = (executor.open(kscene, n_chunks, note) if isinstance(executor, LocalThreads)
                     else executor.open(kscene, n_chunks))
            start = time.perf_counter()                    # the rate is of tracing, not of numba's compile
            per_task = max(1, int(getattr(executor, "chunks_per_task", 1)))
            window = 2 * slots                                # tasks submitted ahead
            next_chunk = 0
            ended = False
            while not ended and (next_chunk < n_chunks or pending):
                while next_chunk < n_chunks and len(pending) < window:
                    group = [chunk(c) for c in range(next_chunk, min(next_chunk + per_task, n_chunks))]
                    pending.append((group, executor.submit(seed, group)))
                    next_chunk += len(group)
                group, fut = pending[0]
                parts = fut.result()
                pending.pop(0)
                for (first, count), part in zip(group, parts):     # one chunk at a time, in chunk order
                    state = ([a + p for a, p in zip(state[0], part)], state[1] + count)
                    acc, done = state
                    worst = None         # with ``precision``: the largest relative σ so far
                    if precision is not None and done >= min(min_photons, photons) and done < photons:
                        worst = largest_sigma(acc, done)
                    if progress:
                        # with ``precision``, the photons it should take (σ ∝ 1/√N), capped at ``photons``
                        total = photons if not worst or not np.isfinite(worst) else \
                            int(min(photons, max(done, done * (worst / precision) ** 2)))
                        if hasattr(progress, "estimating"):     # no σ yet: the cap is no estimate of the end
                            progress.estimating = precision is not None and not (worst and np.isfinite(worst))
                        progress(done, total, time.perf_counter() - start)
                    if stop is not None and stop() and done < photons:
                        partial = ended = True
                        break
                    if worst is not None and worst <= precision:
                        reached = ended = True
                        break
        except KeyboardInterrupt:
            partial, interrupted = state[1] < photons, True
        finally:
            for _, fut in pending:
                fut.cancel()
            executor.close()
    finally:
        if batch is not None:
            kscene.nee_batch = batch
    acc, done = state
    seconds = time.perf_counter() - start
    result = Result(done, acc[0], acc[1], acc[2], seconds, slots, seed, kscene.n_sensors, kscene.n_receivers,
                  estimator=kscene.estimator, materials=[m.name for m in kscene.materials], nee_stats=acc[3],
                  partial=partial, interrupted=interrupted)
    result.extra.update(executor.describe())
    if precision is not None:
        if not reached and done == photons:
            reached = bool(largest_sigma(acc, done) <= precision)
        result.extra["precision_reached"] = reached
        result.extra["precision"] = precision
    return result


def progress_printer(stream=sys.stderr, every: float = 2.0):
    """A ``progress`` callback printing photons done, rate and time left every ``every`` seconds."""
    last = [-every]

    def note(text):     # said once while nothing is traced yet, e.g. numba compiling the kernel
        print("  " + text, file=stream, flush=True)

    def show(done, total, seconds):
        if seconds - last[0] < every and done < total:
            return
        last[0] = seconds
        rate = done / seconds if seconds > 0 else 0.0
        if show.estimating:          # a precision run before its first σ: no end to count down to yet
            print("  %d photons  %.3g photons/s  (σ goal: first estimate still to come)" % (done, rate),
                  file=stream, flush=True)
            return
        left = (total - done) / rate if rate > 0 else float("nan")
        print("  %5.1f%%  %d/%d photons  %.3g photons/s  %.0f s left"
              % (100.0 * done / total, done, total, rate, left), file=stream, flush=True)

    show.note = note
    show.estimating = False      # set by run(): precision asked, no σ yet
    return show
