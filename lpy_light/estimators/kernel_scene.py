"""The kernel scene: a chamber (and a plant's organs) turned into the kernel's records, built once, traced by chunks.

:class:`KernelScene` holds the chamber's arrays and Embree scene, the organs of the current growth step, the
estimator and its next-event settings (one frozen :class:`~lpy_light.estimators.registry.NextEventSettings`, changed
only by :meth:`KernelScene.configure`), and builds the kernel's records (:meth:`KernelScene.records`).  Beside it: the
default rules for a plant's organs (:func:`cones_for`, :func:`local_for`, :func:`organ_zone_rate`), the pilot of
the mean pick share, and :func:`compile_kernel`.  Running it over many photons is :mod:`lpy_light.run.simulate`'s.
"""
from __future__ import annotations

import threading
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from .registry import DEFAULT_ESTIMATOR, NextEventSettings
from .registry import estimator as estimator_named
from ..chamber.geometry import (coplanar_partners, mirror_planes, partner_free_boxes, plane_ids, triangle_areas,
                                triangle_normals)
from ..kernel import embree
from ..kernel.control import build_control
from ..kernel.nee import NEAR, SHARE_SCALE
from ..kernel.organ_zones import organ_zones
from ..kernel.records import (DIFFUSE_R, DIFFUSE_T, SPECULAR_T, T_MESH1, T_MESH2, Emitters, Geometry, Materials,
                              Mirrors, NextEvents, OrganEvents, Scene, Sensors, Zones, f64, i32, i64, new_tallies, u8)
from ..kernel.tallies import C_PICK_SHARE, C_PICK_VERTICES, N_COUNTERS
from ..kernel.targets import build_targets, cluster_sums, cone_served, target_clusters
from ..kernel.trace import trace_chunk
from ..kernel.zones import near_zones
from ..chamber.materials import SPECULAR_R, sampling_tables
from .memory import check_memory

#: photons per chunk: chunk c holds photons c·CHUNK.., whose random streams depend on (seed, photon index) only
CHUNK = 1 << 15


class KernelScene:
    """A chamber turned into kernel arrays and an Embree scene (built once, reused by runs).

    Organs (:meth:`set_organs`) are a separate Embree geometry, replaced
    between growth steps while the chamber's geometry and arrays stay built.
    Receiver rows: the chamber's solid sensors first, then the organs in the
    order given.
    """

    def __init__(self, chamber, estimator: str = DEFAULT_ESTIMATOR, settings: NextEventSettings | None = None,
                 one_sided_organs: bool = False):
        """``estimator``: a name from :data:`lpy_light.estimators.registry.ESTIMATORS`; ``settings``: its next-event
        settings (default: the estimator's own, :class:`~lpy_light.estimators.registry.NextEventSettings`; change them
        with :meth:`configure`); ``one_sided_organs``: organs seen from their front only (an ablation, see
        :class:`~lpy_light.plant.light.LightModel`)."""
        self.estimator = estimator_named(estimator).name
        # refuse up front what cannot fit (one thread here; run() checks its own thread count)
        check_memory(len(chamber.sensors) + 2 * len(chamber.receivers) + len(chamber.materials) + 4,
                     chamber.n_bands, 1, triangles=len(chamber.triangles), sensors=len(chamber.sensors),
                     what="this scene")
        self.chamber = chamber
        self.settings = estimator_named(estimator).settings if settings is None else settings
        self.receiver_mask = None   # (R,) bool: receivers that are next-event targets (None: all; set_organs)
        self._pick_mean = {}        # the mean pick share, per organs and settings (records())
        self.pick_pilot = PICK_PILOT  # photons of the pilot that finds it (a run of fewer photons asks fewer)
        self.compile_seconds = 0.0  # seconds spent compiling the kernel for this scene (:func:`compile_kernel`)
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
        self.emit = Emitters(i32(em.kind), f64(np.reshape(em.data, (-1, 3, 3))), f64(em.cdf),
                             f64(em.start_weight(chamber.n_bands)))
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
        # benchmarks/seed_plant.py), not physics: a leaf has two faces.
        self.one_sided_organs = bool(one_sided_organs)
        self._assemble(np.zeros((0, 3, 3)), np.zeros((0, 2), np.int32), np.zeros(0, np.int32))

    # A KernelScene pickles without its Embree scene and the C function addresses (a ctypes handle and
    # this process's pointers): unpickling rebuilds them from the same triangles, so a copy on another
    # process or machine (a Dask worker: lpy_light.run.cluster) traces bitwise what this one traces, with
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

    def configure(self, **changes) -> KernelScene:
        """Change next-event settings by name (``configure(picks=2, images=0.2)``): a new, checked
        :class:`~lpy_light.estimators.registry.NextEventSettings` (an unknown name or a value out of range is an
        InputError naming it); the next :meth:`records` uses it.  Returns the scene."""
        self.settings = self.settings.replace(**changes)
        return self

    def _assemble(self, verts, mat, receiver):
        self._assembled = getattr(self, "_assembled", 0) + 1      # the targets' key: these organs, not an id()
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
            self.materials, self.chamber.physics.specular, estimator_named(self.estimator).weighted)
        self.n_receivers = self.n_chamber_receivers + len(self.organs)
        self.n_rows = self.n_sensors + 2 * self.n_receivers + len(self.materials) + 4
        if len(self.mat_nee) < len(self.materials):     # new materials start with next events on
            self.mat_nee = np.concatenate([self.mat_nee, np.ones(len(self.materials) - len(self.mat_nee), np.uint8)])

    # The next-event targets are built when first read after a change of organs or settings, not by every
    # set_organs: a step lit from a light field traces no next event and never reads them (0.24 s of a
    # 516-organ rose's 1.5 s field step went to building them).
    @property
    def targets(self):
        """The next-event targets (:class:`~lpy_light.kernel.records.Targets`), as the organs and settings now are."""
        self.retarget()
        return self._targets

    @property
    def zones(self):
        """Two-step next events beside discs (:class:`~lpy_light.kernel.records.Zones`)."""
        self.retarget()
        return self._zones

    @property
    def organ_events(self):
        """Next events to organs (:class:`~lpy_light.kernel.records.OrganEvents`), or None (no organ targets)."""
        self.retarget()
        return self._organ_events

    def retarget(self):
        """Rebuild the next-event target arrays after a change of organs or of next-event settings (a no-op when
        neither changed since the last build)."""
        mask = self.receiver_mask
        key = (self._assembled, id(self.tri_verts), self.tri_verts.shape, id(self.tri_receiver), id(self.sens), bool(self.settings.sensors), bool(self.settings.receivers),
               int(self.settings.picks), bool(self.settings.importance), bool(self.settings.open_zones),
               bool(self.settings.closed_zones), None if mask is None else np.asarray(mask).tobytes())
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
        self._targets = tgt = build_targets(
            self.sens, sensors.area, bound, self.n_receivers, self.tri_receiver, self.tri_verts, self.two_sided,
            sensors=self.settings.sensors, receivers=self.settings.receivers, receiver_mask=self.receiver_mask,
            tri_normal=self.tri_normal)
        # zones beside discs for two-step next events (only with random picks, where discs have own events)
        n_tgt = len(tgt.kind)
        disc_radius = np.zeros(n_tgt)
        on = tgt.sensor_target >= 0
        disc_radius[tgt.sensor_target[on]] = np.where(self.sens.kind[on] == 0, self.sens.radius[on], 0.0)
        disc_normal = np.zeros((n_tgt, 3))
        disc_normal[tgt.sensor_target[on]] = self.sens.normal[on]
        if self.settings.sensors and 0 < self.settings.picks < n_tgt:
            self._zones = near_zones(self.tri_verts, self.tri_pid, self.n_chamber_triangles, tgt.near_start,
                                    tgt.near_list, tgt.near_r2, tgt.center, disc_radius, disc_normal)
        else:
            self._zones = Zones(0.0, np.zeros((0, 14)), np.zeros((0, 2), np.int64), np.zeros(n_tgt + 1, np.int64))
        # next events to organs (the plant's organs are the targets, with random picks): picks by importance over
        # clusters of targets, two-step events through the organ surface beside an organ
        self._organ_events = None
        if self.settings.importance and self.settings.receivers and not self.settings.sensors and 0 < self.settings.picks < n_tgt:
            clusters = target_clusters(tgt.center, np.sqrt(tgt.img_near2) / NEAR)
            weight = np.ones(n_tgt)
            zones = organ_zones(self.tri_verts, self.tri_receiver, self.tri_pid, tgt.near_start, tgt.near_list,
                                tgt.near_r2, tgt.kind, tgt.ref, tgt.center, clusters,
                                self._own_zones(tgt))
            cluster_of = np.zeros(n_tgt, np.int64)
            cluster_of[clusters.member] = np.repeat(np.arange(len(clusters.radius)), np.diff(clusters.start))
            self._organ_events = OrganEvents(clusters, weight, weight, cluster_sums(weight, clusters), cluster_of,
                                            0.0, weight, 0.0, zones, 0.0, 1.0, np.ones(0))
            self._pick_mean = {}

    def _own_zones(self, tgt) -> np.ndarray:
        """(T,) bool: the targets whose own surface is in their organ zone (:func:`kernel.organ_zones.organ_zones`):
        open ones (``settings.open_zones``), and closed ones whose tissue lets light in (``settings.closed_zones``):
        a closed bud of translucent tissue holds light that bounces inside it, each bounce incident on the bud
        again -- in the far red (a leaf's T ~0.44) a quarter of a bud's light, and ~85 % of its variance while
        only the few photons that land on the bud found it."""
        own = (tgt.facing == 0) & bool(self.settings.open_zones)
        if self.settings.closed_zones and self.settings.open_zones:
            lets_in = (self.mat_prob[:, DIFFUSE_T, :] + self.mat_prob[:, SPECULAR_T, :]).max(axis=1) > 0.0   # (M,)
            on = self.tri_receiver >= 0
            translucent = np.zeros(self.n_receivers, bool)         # per receiver: a triangle of it transmits
            np.logical_or.at(translucent, self.tri_receiver[on], lets_in[self.tri_mat[on]].any(axis=1))
            mesh = (tgt.kind == T_MESH1) | (tgt.kind == T_MESH2)
            own = own | (mesh & translucent[np.where(mesh, tgt.ref, 0)])
        return own

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
        if not (self.settings.sensors or self.settings.receivers):
            return {}
        self.all_sources_on()
        stats = self._pilot_stats(photons, seed, threads)
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

    def all_sources_on(self):
        """Next events from every material, lamp and mirror plane again (what :meth:`prune_next_events` undoes)."""
        self.mat_nee[:] = 1
        self.emit_nee[:] = 1
        self.mir_on[:] = 1

    def replace_targets(self, **fields):
        """An experiment's change of the built next-event targets (``near2=...``: fields of
        :class:`lpy_light.kernel.records.Targets`), used by the next runs until a change of organs or settings
        rebuilds them (:meth:`retarget`)."""
        self._targets = self.targets._replace(**fields)

    def material_index(self, material) -> int:
        """Index of ``material`` (a :class:`~lpy_light.chamber.materials.Material`), added if new (by name)."""
        for i, m in enumerate(self.materials):
            if m.name == material.name and m.type == material.type:
                return i
        self.materials.append(material)
        return len(self.materials) - 1

    def set_organs(self, organs, materials: dict, targets=None):
        """Put ``organs`` (list of :class:`~lpy_light.plant.organs.Organ`) in the chamber, replacing the previous ones.

        ``materials`` maps each front/back name to its Material.  Organ i is
        receiver ``n_chamber_receivers + i``.  ``targets`` (len(organs),) bool or
        None: which organs next events aim at (None: all).
        """
        self.organs = list(organs)
        self.receiver_mask = None if targets is None else np.concatenate(
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

    def records(self, note=None, next_events: bool = True):
        """The kernel's records of this scene as it stands (:mod:`lpy_light.kernel.records`), with the current
        settings (:attr:`settings`, the sources and mirror planes switched on): ``(Scene, NextEvents or None)``, None
        where next events have no target (``weighted``, ``analog``) or are not asked for (``next_events`` False: a
        light field's tracing, which makes none; the targets are then not built).  Built once per run.  With organs as
        targets and ``settings.pick_share``, the vertices' mean pick share comes from a pilot of :attr:`pick_pilot`
        (:data:`PICK_PILOT`) photons (one chunk, a fixed seed: the same for the same organs and settings, on any
        number of threads), once per organs and settings; ``note`` as :func:`compile_kernel`'s, if the kernel compiles for it."""
        phys = self.chamber.physics
        nee = self.settings.sensors or self.settings.receivers
        geometry = Geometry(self.scene.handle, self.intersect, self.occluded, float(phys.offset), i64(self.geom_offset),
                            f64(self.tri_verts), f64(self.tri_normal), i32(self.tri_mat), i32(self.tri_receiver),
                            self.tri_two_sided, i32(self.tri_plane), i32(self.tri_pid), i64(self.cop_start),
                            i32(self.cop_list), f64(self.cop_box), f64(self.cop_free), int(self.n_receivers))
        materials = Materials(f64(self.mat_prob), f64(self.mat_cum), i64(self.band_pass), f64(self.mat_phong),
                              estimator_named(self.estimator).weighted, int(phys.max_depth))
        scene = Scene(geometry, materials, self.emit, self.sens)
        if not next_events:
            return scene, None
        targets = self.targets._replace(on_sensors=bool(self.settings.sensors), on_receivers=bool(self.settings.receivers),
                                        picks=int(self.settings.picks), from_material=u8(self.mat_nee),
                                        from_emitter=u8(self.emit_nee))
        if not self.settings.facing:           # an ablation: points over the whole mesh of closed organs
            targets = targets._replace(facing=np.zeros_like(targets.facing))
        plane = np.flatnonzero(self.mir_on).astype(np.int32)
        mirrors = Mirrors(float(self.settings.images) if nee else 0.0, float(self.settings.images2) if nee else 0.0, i32(plane), f64(self.mir_spec), f64(self.mir_area),
                          u8(self.mir_on),
                          f64(self.mir_point), f64(self.mir_normal), f64(self.mir_box), u8(self.mir_one_sided))
        zones = self.zones._replace(picks=float(self.settings.zones) if self.settings.sensors else 0.0)
        if len(targets.kind) == 0:
            return scene, None
        control = build_control(targets, self.sens, bool(self.settings.control), int(self.settings.batch))
        organs = None
        if self.organ_events is not None:      # a plant's organs are the targets (LightModel)
            ev = self.organ_events
            far = ev.weight
            cones = cones_for(len(self.targets.kind)) if self.settings.cones is None else float(self.settings.cones)
            large = cone_served(self.targets.area, ev.clusters)
            if cones > 0:        # large targets served by cone rays from vertices far from their cluster
                far = np.where(large, 0.0, ev.weight)
            local = local_for(len(self.targets.kind)) if self.settings.local is None else float(self.settings.local)
            near = np.where(large, 0.0, ev.weight) if local > 0 else ev.weight    # ... by local rays from near ones
            # organ zone events for the small targets only (buds): a leaf's near light comes well enough from its
            # own events, and the zone events' own noise was the largest part of some leaves' variance (a 16-rose
            # canopy's p90 leaf: 49 % of σ² for 4 % of its light)
            zw = np.where(large, 0.0, ev.zones.weight)
            rate = organ_zone_rate(zw, ev.zones.own) if self.settings.organ_zones is None else float(self.settings.organ_zones)
            organs = ev._replace(weight=f64(ev.weight), far_weight=f64(far), cluster_weight=cluster_sums(far, ev.clusters),
                                 cones=cones, near_weight=f64(near), local=local,
                                 zones=ev.zones._replace(picks=rate, weight=f64(zw), walk=int(self.settings.zone_walk),
                                                         cluster_weight=cluster_sums(zw, ev.clusters)),
                                 pick_unit=self._pick_unit(), pick_side=self._pick_side())
        recs = scene, NextEvents(targets, mirrors, zones, control, organs)
        if organs is not None and self.settings.pick_share:
            recs = self._with_pick_mean(recs, note)
        return recs

    def size_pilots(self, photons: int):
        """Pilots no larger than the run they serve: the pick-share pilot of a run of ``photons`` traces
        min(:data:`PICK_PILOT`, max(:data:`PILOT_FLOOR`, photons)) photons (a plant lit every step at a few thousand
        photons: 8,192 pilot photons were most of its kernel time; runs of 8,192 photons and more as before)."""
        self.pick_pilot = min(PICK_PILOT, max(PILOT_FLOOR, int(photons)))

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
        ``settings.picks`` at every vertex (cached per organs and settings)."""
        scene, nee = recs
        org = nee.organs
        pilot = self.pick_pilot
        key = (self.settings.picks, org.cones, org.local, org.zones.picks, nee.mirrors.picks, nee.mirrors.picks2,
               bytes(self.mat_nee), bytes(self.emit_nee), bytes(self.mir_on), self.estimator, self.settings.facing,
               pilot)
        if key not in self._pick_mean:
            compile_kernel(self, recs, note)
            _, _, counters, _ = self.trace(PICK_SEED, 0, pilot, recs)
            n = int(counters[C_PICK_VERTICES])
            self._pick_mean[key] = (float(counters[C_PICK_SHARE]) / SHARE_SCALE / n * org.pick_unit) if n else 0.0
        return scene, nee._replace(organs=org._replace(pick_mean=self._pick_mean[key]))

    def _pilot_stats(self, photons: int, seed: int, threads=None) -> np.ndarray:
        """The next-event statistics (rays cast, paths found, weight deposited per source) of ``photons``,
        traced in chunks of :data:`CHUNK` and summed in chunk order, as :func:`lpy_light.run.simulate.run` sums
        them: the same numbers on any number of ``threads``."""
        records = self.records()
        chunks = [(first, min(CHUNK, photons - first)) for first in range(0, photons, CHUNK)]
        total = 0.0
        with ThreadPoolExecutor(max_workers=max(1, min(threads or 1, len(chunks)))) as pool:
            for part in pool.map(lambda c: self.trace(seed, c[0], c[1], records)[3], chunks):
                total = total + part
        return total

    @property
    def n_stats(self) -> int:
        """Rows of the next-event statistics: one per material, lamp element and mirror plane."""
        return len(self.materials) + len(self.emit_nee) + len(self.mir_point)

    def trace(self, seed: int, first: int, count: int, records=None):
        """Trace one chunk through ``records`` (default: :meth:`records` now); returns (tally, tally_sq,
        counters, nee_stats)."""
        scene, nee = self.records() if records is None else records
        tallies, stats = new_tallies(self.n_rows, self.n_bands, self.n_stats, N_COUNTERS)
        scratch = embree.new_scratch()
        trace_chunk(scene, nee, scratch.ctypes.data, seed, first, count, tallies, stats)
        return tallies.tally, tallies.tally_sq, stats.counters, stats.nee_stats


#: a kernel not ready after this many seconds is being compiled (loading numba's cache takes well under it)
COMPILE_NOTE_AFTER = 1.0
#: photons of the pilot that finds the vertices' mean pick share for a plant's organs (KernelScene.records), its seed
PICK_PILOT = 8192
#: the fewest photons of that pilot, for runs of fewer photons (:meth:`KernelScene.size_pilots`)
PILOT_FLOOR = 2048
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
    """The default organ zone events per vertex (``NextEventSettings.organ_zones`` None), for the zone weights
    ``weight`` (n,) (> 0: the target has zone events) and ``own`` (n,) (its own surface is in its zone: an open
    organ, or a closed one of translucent tissue): from :data:`ZONES_CLOSED` to :data:`ZONES_OPEN` with the share
    of those.  An open bud's far red
    comes mostly through its zone events (entries into the tube, then walks), so more of them pay there: on
    rose-simple4 at lit step 15, 1 event per vertex against 0.25 gave the R:FR's spread over eight seeds 0.063
    → 0.028 for +44 % CPU (its variance 2.2x lower per CPU second), 2 per vertex 0.030 for +91 %; a closed bud's
    light comes mostly from picks and own events (the procedural rose: no rate from 0 to 1.5 moved its σ²·CPU
    by more than ~10 %) -- unless it is translucent and its own surface is in its zone: there the procedural
    rose's buds' far red (relative σ at 10⁶ photons 0.113 at 0.25 per vertex, 0.093 at 1 for 1.5x the time) read
    their R:FR at 10⁶ minus at 4·10⁶ photons +0.016 ± 0.003 at 0.25, +0.004 ± 0.008 at 1 (a heavy tail left at
    0.25: ``benchmarks/rfr_bias.py``)."""
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
