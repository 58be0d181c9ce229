"""The chamber as a light field at the plant: the ``field`` estimator.

The chamber does not change between growth steps; what a step needs of it is the light that arrives into the
region around the plant.  Here that is traced once into a :class:`LightField` (:func:`build_field`) and each step
(:func:`field_step`) never leaves the region:

1. **The region** (:func:`plant_region`): a box around the plant's organs (their bounds grown by
   :attr:`FieldSettings.growth` of their size and :attr:`FieldSettings.margin` metres each side), cut back to a
   wall that crosses it whole (:func:`inside_walls`) and clear of every lamp (:func:`clear_of_lamps`: light
   emitted inside it would never cross a face).  What of the
   chamber lies inside it (the table top under the plant, a pot) belongs to the region: its *pieces*, the chamber's
   triangles clipped to a grid of the box (:func:`chamber_pieces`).
2. **The field**: the light entering the region through its six faces, by face, cell on the face, direction
   (bins of equal projected solid angle) and band: every photon segment of a full trace (the plant in place) that
   enters the box from outside, binned where it enters (:mod:`lpy_light.kernel.field`).  The store's photons are
   split in :attr:`FieldSettings.batches` independent parts: its own error is part of every step's σ.
3. **The step**: from both sides of every organ and from the front of every chamber piece, rays from points
   drawn over it (stratified by area), in directions drawn partly cosine-weighted and mostly from a guide: where,
   from the side's centre, the field brings light (:func:`side_guides`), each ray weighed back to the cosine;
   traced against the region alone (its own Embree scene, built each step); a ray that leaves the region reads
   the field where and in the direction it leaves; a ray that meets an organ or a piece reads that side's
   outgoing light, (E·R + E'·T) / π per band, from the irradiance of the previous pass: the passes are repeated
   until they no longer change (:func:`lpy_light.kernel.field.solve_passes`; the rays, and which side each met,
   are kept, so a pass is one sparse product).
4. **σ**: the rays' part and the field's, apart.  The rays of each side are split in as many groups as the store
   has batches; group g, read against the whole field, gives one estimate of the step: their spread is the
   rays'.  All the rays read against batch g of the store alone give another: their spread is the field's own.
   (A group read against its own batch alone would also spread by the two crossed, which the step's estimate,
   every ray reading every batch, does not have: where the field's bins are fine, that overstated σ.)

Bias, by construction: the field is binned (a ray reads the mean of its bin: light that varies within a cell or a
direction bin is averaged there, with the shading of the current plant), an element's outgoing light is its mean
over the element (an organ, a piece), specular reflection and transmission on organs and pieces are treated as
diffuse, and the light the plant sends out of the region and gets back is that of the plant the field was traced
with (:attr:`FieldSettings.renew`).  ``benchmarks/field.py`` measures it against ``nee``.

Units: the field's and the step's tallies are in photons of weight of the store's photons (a :class:`Result` of
``photons`` = the store's), positions in scene units.
"""
from __future__ import annotations

import dataclasses
import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..errors import InputError
from ..kernel import embree
from ..kernel.emission import EMIT_CYLINDER, EMIT_LINE, EMIT_SPHERE, EMIT_TRIANGLE
from ..kernel.field import (add_crossings, bin_crossings, cast_rays, field_links, guide_tables, read_rays, side_links,
                            side_sums, solve_passes)
from ..kernel.records import (ABSORB, DIFFUSE_R, DIFFUSE_T, REPLAY_STORE, SPECULAR_R, SPECULAR_T, START_W, VPL_W,
                              FieldBins, Guide, RayEnds, RaySides, Region, Replay, new_tallies)
from ..kernel.tallies import N_COUNTERS
from ..kernel.trace import trace_chunk
from .reuse import chamber_key, inside

#: photons per chunk of the field's trace
FIELD_CHUNK = 32768
#: passes by triangle side, from the light solved by element side; and of each σ group's solve from there
TRIANGLE_PASSES = 2
GROUP_PASSES = 2


@dataclass(frozen=True)
class FieldSettings:
    """How the ``field`` estimator lights a plant (:class:`lpy_light.plant.light.LightModel` ``field=``).

    Parameters
    ----------
    store_photons : int
        Photons traced into a field (its own error falls as 1/√ of it; traced once per ``renew`` steps).
    batches : int
        Independent parts of the store, and groups of each side's rays: a step's σ is the spread of their
        estimates (≥ 4).
    cells : int
        Cells along the region's longest edge (the faces' cells are about square).
    rings, sectors : int
        Direction bins of a cell: sin²θ in ``rings``, the azimuth in ``sectors`` (each π / (rings · sectors) sr of
        projected solid angle).
    rays : int
        Rays per side of each organ whose light is read (a bud's or a leaf's).
    shading_rays : int
        Rays per side of each organ nobody reads (it shades and sends light to the others).
    piece_rays : int
        Rays from each piece of the chamber inside the region (the table under the plant).
    pieces : int
        The region's grid for the chamber's pieces, along its longest edge.
    bounces : int
        Where a ray meets a surface, its path goes on this many times before it reads the outgoing light of the
        triangle it ends on (that triangle's mean: the bounces make what it reads local).  Far red scatters
        many times among leaves (R + T ≈ 0.95): the buds' R:FR against ``nee`` on the procedural rose is
        −0.021 after 1 bounce, −0.012 after 3, −0.004 after 6 (eight fields each); on the report's rose, whose
        buds sit in the leaves' axils, −0.44, −0.06 and ~0 (±0.05).  6 bounces cost ~6 % of a step more than 3
        (``docs/performance.md``, "The light field").
    growth, margin : float
        The region: the organs' bounds grown by ``growth`` × their size and ``margin`` metres each side.
    renew : int
        Steps after which the field is traced again with the plant then in place; 0: only when the chamber or the
        region changes.
    guide_z, guide_phi : int
        Each side's direction guide: the sphere in ``guide_z`` bands of equal area × ``guide_phi`` sectors, each
        weighted by the field's light a ray from the side's centre that way reads (its bands summed, each as a
        share of its total) × cos⁺; ``guide_z`` 0: cosine-weighted directions only.
    cosine_share : float
        The share of each guided side's first rays drawn cosine-weighted (the rest from its guide), in (0, 1]:
        what keeps the directions the guide misjudges (the plant in the way, the organ's extent) sampled.
    check_photons : int
        Photons of the ``nee`` run that checks each field as it is traced (:mod:`lpy_light.plant.verify`: the
        field's step of the plant it was traced with against ``nee``'s, leaves and buds apart; a field that fails
        is not used, its steps are lit by ``nee``); 0: no check.  The default, 10⁵, costs about a tenth of a
        field and the steps lit from it on a rose (``docs/estimators.md``).
    """

    store_photons: int = 4_000_000
    batches: int = 8
    cells: int = 8
    rings: int = 10
    sectors: int = 20
    rays: int = 1024
    shading_rays: int = 128
    piece_rays: int = 256
    pieces: int = 4
    bounces: int = 6
    growth: float = 0.25
    margin: float = 0.1
    renew: int = 10
    guide_z: int = 16
    guide_phi: int = 32
    cosine_share: float = 0.25
    check_photons: int = 100_000

    def __post_init__(self):
        for name, lo in (("store_photons", 1), ("batches", 4), ("cells", 1), ("rings", 1), ("sectors", 1),
                         ("rays", 1), ("shading_rays", 1), ("piece_rays", 1), ("pieces", 1), ("bounces", 0),
                         ("renew", 0), ("guide_z", 0), ("guide_phi", 1), ("check_photons", 0)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer)) or value != int(value) \
                    or value < lo:
                raise InputError("field setting %r must be a whole number >= %d, got %r" % (name, lo, value))
            object.__setattr__(self, name, int(value))
        for name in ("growth", "margin"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) or \
                    not 0 <= value <= 100:
                raise InputError("field setting %r must be a number in 0..100, got %r" % (name, value))
            object.__setattr__(self, name, float(value))
        if isinstance(self.cosine_share, bool) or not isinstance(self.cosine_share, (int, float, np.integer,
                                                                                     np.floating)) \
                or not 0 < self.cosine_share <= 1:
            raise InputError("field setting 'cosine_share' must be a number in (0, 1], got %r" % (self.cosine_share,))
        object.__setattr__(self, "cosine_share", float(self.cosine_share))


def field_settings(spec) -> FieldSettings:
    """``spec``: None (the defaults), a :class:`FieldSettings`, or a mapping of its fields."""
    if spec is None:
        return FieldSettings()
    if isinstance(spec, FieldSettings):
        return spec
    try:
        return FieldSettings(**dict(spec))
    except TypeError:
        raise InputError("unknown field setting in %r (the settings: %s)"
                         % (dict(spec), ", ".join(f.name for f in dataclasses.fields(FieldSettings)))) from None


# -- the region -----------------------------------------------------------------------------------------------
def plant_region(organs, metres_per_unit: float, settings: FieldSettings, lamps=None, chamber=None) -> np.ndarray:
    """The region around ``organs`` (chamber units): their bounds grown by ``settings.growth`` of their size and
    ``settings.margin`` metres each side, then cut back to the walls, floor or ceiling that cross it whole
    (``chamber``: its triangles (T, 3, 3); :func:`inside_walls`) and clear of every lamp (``lamps``: (E, 2, 3)
    bounds, :func:`lamp_bounds`; :func:`clear_of_lamps`); (6,) lo, hi."""
    pts = np.concatenate([np.asarray(o.triangles, float).reshape(-1, 3) for o in organs])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    grow = settings.growth * (hi - lo) + settings.margin / metres_per_unit
    box = np.concatenate([lo - grow, hi + grow])
    if chamber is not None:
        box = inside_walls(box, lo, hi, chamber)
    return box if lamps is None else clear_of_lamps(box, lo, hi, lamps)


def inside_walls(box, lo, hi, verts, samples: int = 16) -> np.ndarray:
    """``box`` (6,) cut back to the nearest plane of chamber triangles (``verts`` (T, 3, 3)) square to an axis that
    crosses the whole box between the organs' bounds ``lo``, ``hi`` (3,) each and one of its faces (a wall the
    plant stands against, the floor, the ceiling), the face put just inside it.  A face beyond a wall reads no
    light there, and a cell of it partly behind the wall would read the mean of its lit and unlit parts: the light
    a ray reads where it leaves by the lit part would be too low.  A plane is taken as crossing the box where its
    triangles hold every point of a ``samples`` × ``samples`` grid over the box's section; planes within 2 % of
    the organs' size of their bounds (the table a plant stands on) stay inside, as pieces."""
    box = np.array(box, float)
    e1, e2 = verts[:, 1] - verts[:, 0], verts[:, 2] - verts[:, 0]
    n = np.cross(e1, e2)
    n /= np.maximum(np.linalg.norm(n, axis=1), 1e-300)[:, None]
    gap = 0.02 * np.maximum(hi - lo, 1e-12)
    for a in range(3):
        a1, a2 = (a + 1) % 3, (a + 2) % 3
        square = np.abs(n[:, a]) > 1.0 - 1e-9
        c = verts[:, 0, a]
        u, v = np.meshgrid(np.linspace(box[a1], box[3 + a1], samples + 2)[1:-1],
                           np.linspace(box[a2], box[3 + a2], samples + 2)[1:-1])
        grid = np.stack([u.ravel(), v.ravel()], axis=1)
        for side in (0, 1):
            between = square & ((c > box[a]) & (c < lo[a] - gap[a]) if side == 0 else
                                (c < box[3 + a]) & (c > hi[a] + gap[a]))
            for plane in sorted(set(c[between]), reverse=side == 0):       # the nearest the organs first
                tri = verts[between & (np.abs(c - plane) <= 1e-9 * max(1.0, abs(plane)))][:, :, [a1, a2]]
                if _covered(grid, tri).all():
                    inset = 1e-3 * (box[3 + a] - box[a])     # beyond a new ray's offset off the wall
                    box[a + 3 * side] = plane + inset if side == 0 else plane - inset
                    break
    return box


def _covered(points, tri) -> np.ndarray:
    """Which of ``points`` (k, 2) lie in one of the triangles ``tri`` (t, 3, 2) (edges included), (k,) bool."""
    out = np.zeros(len(points), bool)
    for t in tri:
        d = (t[1, 0] - t[0, 0]) * (t[2, 1] - t[0, 1]) - (t[2, 0] - t[0, 0]) * (t[1, 1] - t[0, 1])
        if d == 0.0:
            continue
        px, py = points[:, 0] - t[0, 0], points[:, 1] - t[0, 1]
        b1 = (px * (t[2, 1] - t[0, 1]) - py * (t[2, 0] - t[0, 0])) / d
        b2 = (py * (t[1, 0] - t[0, 0]) - px * (t[1, 1] - t[0, 1])) / d
        out |= (b1 >= -1e-9) & (b2 >= -1e-9) & (b1 + b2 <= 1.0 + 1e-9)
    return out


def lamp_bounds(emitters) -> np.ndarray:
    """The bounds of each lamp element (:class:`lpy_light.chamber.emitters.Emitters`), (E, 2, 3) lo, hi."""
    kind, data = np.asarray(emitters.kind), np.asarray(emitters.data, float)
    out = np.empty((len(kind), 2, 3))
    for e, (k, d) in enumerate(zip(kind, data)):
        if k == EMIT_TRIANGLE:
            pts, r = d, 0.0
        elif k == EMIT_SPHERE:
            pts, r = d[:1], d[1, 0]
        elif k == EMIT_CYLINDER:
            pts, r = d[:2], d[2, 0]
        else:                                    # a line or a point lamp: the segment d[0] → d[1]
            pts, r = d[:2] if k == EMIT_LINE else d[:1], 0.0
        out[e, 0], out[e, 1] = pts.min(axis=0) - r, pts.max(axis=0) + r
    return out


def clear_of_lamps(box, lo, hi, lamps) -> np.ndarray:
    """``box`` (6,) with every lamp (``lamps`` (E, 2, 3)) that reaches into it cut off: the region's field is the
    light that enters through its faces, so light emitted inside it would be missed (a lamp hung low beside the
    plant, or under the bench it stands on).  Each such lamp is cut off by the face moved halfway between it and
    the organs' bounds ``lo``, ``hi`` (3,) each, on the side that keeps the most of the region.  Raises
    :class:`InputError` where a lamp lies within the organs' own bounds."""
    box = np.array(box, float)
    while True:
        hit = [e for e in range(len(lamps)) if np.all(lamps[e, 1] > box[:3]) and np.all(lamps[e, 0] < box[3:])]
        if not hit:
            return box
        l_lo, l_hi = lamps[hit[0]]
        cuts = []                                    # (volume kept, axis, the box so cut)
        for a in range(3):
            if l_hi[a] < lo[a]:
                cut = box.copy()
                cut[a] = 0.5 * (l_hi[a] + lo[a])
                cuts.append((np.prod(cut[3:] - cut[:3]), a, cut))
            if l_lo[a] > hi[a]:
                cut = box.copy()
                cut[3 + a] = 0.5 * (l_lo[a] + hi[a])
                cuts.append((np.prod(cut[3:] - cut[:3]), a, cut))
        if not cuts:
            raise InputError("a lamp (bounds %s to %s) lies among the plant's organs: the field estimator lights "
                             "a region that holds no lamp; use estimator 'nee'" % (l_lo.tolist(), l_hi.tolist()))
        box = max(cuts, key=lambda c: c[0])[2]


def face_grid(box, cells: int):
    """Cells of the region's six faces: ``grid`` (6, 2) along each face's two axes (a + 1, a + 2 mod 3) and
    ``face0`` (6,) the first cell of each face; the faces' cells about square, ``cells`` along the longest edge."""
    size = box[3:] - box[:3]
    h = size.max() / cells
    n = np.maximum(1, np.round(size / h)).astype(np.int64)
    grid = np.array([[n[(f // 2 + 1) % 3], n[(f // 2 + 2) % 3]] for f in range(6)], np.int64)
    face0 = np.concatenate([[0], np.cumsum(grid[:, 0] * grid[:, 1])[:-1]]).astype(np.int64)
    return grid, face0


def clip_polygon(poly, lo, hi):
    """The part of the convex polygon ``poly`` (k, 3) inside the box [lo, hi] (Sutherland–Hodgman), (k', 3)."""
    for a in range(3):
        for bound, keep_above in ((lo[a], True), (hi[a], False)):
            if len(poly) == 0:
                return poly
            out = []
            for i in range(len(poly)):
                p, q = poly[i], poly[(i + 1) % len(poly)]
                pin = p[a] >= bound if keep_above else p[a] <= bound
                qin = q[a] >= bound if keep_above else q[a] <= bound
                if pin:
                    out.append(p)
                if pin != qin:
                    t = (bound - p[a]) / (q[a] - p[a])
                    out.append(p + t * (q - p))
            poly = np.array(out).reshape(-1, 3)
    return poly


def chamber_pieces(kscene, box, pieces: int):
    """The chamber inside the region: each chamber triangle clipped to each cell of a grid of the box (``pieces``
    along its longest edge); returns (triangles (n, 3, 3), piece of each (n,), the chamber triangle of each piece
    (p,), two-sided of each piece (p,))."""
    n = kscene.n_chamber_triangles
    verts = kscene.tri_verts[:n]
    lo, hi = box[:3], box[3:]
    near = np.flatnonzero(np.all(verts.max(axis=1) >= lo, axis=1) & np.all(verts.min(axis=1) <= hi, axis=1))
    size = hi - lo
    h = size.max() / pieces
    steps = np.maximum(1, np.round(size / h)).astype(int)
    edges = [np.linspace(lo[a], hi[a], steps[a] + 1) for a in range(3)]
    tris, owner, source = [], [], []
    for t in near:
        tlo, thi = verts[t].min(axis=0), verts[t].max(axis=0)
        rng = [range(max(0, np.searchsorted(edges[a], tlo[a], "right") - 1),
                     min(steps[a], np.searchsorted(edges[a], thi[a], "left"))) for a in range(3)]
        for i in rng[0]:
            for j in rng[1]:
                for k in rng[2]:
                    clo = np.array([edges[0][i], edges[1][j], edges[2][k]])
                    chi = np.array([edges[0][i + 1], edges[1][j + 1], edges[2][k + 1]])
                    poly = clip_polygon(verts[t].copy(), clo, chi)
                    if len(poly) < 3:
                        continue
                    fan = np.stack([np.repeat(poly[:1], len(poly) - 2, axis=0), poly[1:-1], poly[2:]], axis=1)
                    area = 0.5 * np.linalg.norm(np.cross(fan[:, 1] - fan[:, 0], fan[:, 2] - fan[:, 0]), axis=1)
                    fan = fan[area > 1e-12 * max(1.0, float(size.max()) ** 2)]
                    if len(fan) == 0:
                        continue
                    tris.append(fan)
                    owner.append(np.full(len(fan), len(source)))
                    source.append(t)
    if not tris:
        return np.zeros((0, 3, 3)), np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, bool)
    source = np.array(source, np.int64)
    return (np.concatenate(tris), np.concatenate(owner).astype(np.int64), source,
            np.asarray(kscene.two_sided[source], bool))


# -- the field ------------------------------------------------------------------------------------------------
@dataclass
class LightField:
    """The light entering a region, binned (:mod:`lpy_light.kernel.field`): ``field`` (S, bins, B) per batch of
    the store's ``photons``, in photons of weight per scene unit² (for all its photons), ``box`` (6,) the region,
    ``grid``, ``face0`` its faces' cells, ``rings`` × ``sectors`` the direction bins of a cell; the chamber's
    ``pieces`` inside the region (:func:`chamber_pieces`); ``key`` what it was traced for."""

    key: str
    photons: int
    seed: int
    box: np.ndarray
    grid: np.ndarray
    face0: np.ndarray
    rings: int
    sectors: int
    field: np.ndarray
    pieces: tuple
    crossings: int = 0
    seconds: float = 0.0
    cpu_seconds: float = 0.0

    @property
    def batches(self) -> int:
        return self.field.shape[0]

    @cached_property
    def total(self) -> np.ndarray:
        """(bins, B): the field of all its photons (the batches summed), computed once."""
        return self.field.sum(axis=0)

    @cached_property
    def by_bin(self) -> np.ndarray:
        """(bins, S, B): the field bin by bin, each bin's batches side by side (:func:`read_field` reads them
        all at once for each ray: one stretch of memory instead of S far apart), made once."""
        return np.ascontiguousarray(self.field.transpose(1, 0, 2))

    @property
    def name(self) -> str:
        return self.key[:12]

    @property
    def bins_per_cell(self) -> int:
        return self.rings * self.sectors

    def describe(self) -> dict:
        return {"field": self.name, "photons": self.photons, "batches": self.batches, "seed": self.seed,
                "box": [float(x) for x in self.box], "cells": int((self.grid[:, 0] * self.grid[:, 1]).sum()),
                "directions": self.bins_per_cell, "crossings": self.crossings, "pieces": int(len(self.pieces[2])),
                "seconds": round(self.seconds, 3), "cpu_seconds": round(self.cpu_seconds, 3)}


def field_key(kscene, box, settings: FieldSettings, seed, flux=None) -> str:
    """What a field depends on: the chamber and lamps (:func:`lpy_light.estimators.reuse.chamber_key`), the region and
    the field's settings."""
    s = settings
    return chamber_key(kscene, box, s.store_photons, s.batches, seed, flux) + "-%d.%d.%d.%d" % (
        s.cells, s.rings, s.sectors, s.pieces)


def build_field(kscene, settings: FieldSettings, seed: int = 1, threads: int | None = None, box=None,
                flux=None) -> LightField:
    """Trace ``settings.store_photons`` photons through ``kscene`` as it stands (the chamber and the plant now in
    it) and bin every segment that enters the region ``box`` (default: :func:`plant_region` of its organs).  Chunk
    c belongs to batch c mod S; the chunks' crossings are added in order: the same field on any number of
    ``threads``."""
    t0, c0 = time.perf_counter(), time.process_time()
    mpu = kscene.chamber.metres_per_unit
    if box is None:
        box = plant_region(kscene.organs, mpu, settings, lamp_bounds(kscene.chamber.emitters),
                           kscene.tri_verts[:kscene.n_chamber_triangles])
    box = np.asarray(box, float)
    grid, face0 = face_grid(box, settings.cells)
    n_bins = int((grid[:, 0] * grid[:, 1]).sum()) * settings.rings * settings.sectors
    S, B = settings.batches, kscene.n_bands
    scene, _ = kscene.records(next_events=False)
    organ0 = kscene.n_chamber_receivers
    per_batch = math.ceil(settings.store_photons / S)
    photons = per_batch * S
    n_chunks = S * math.ceil(per_batch / FIELD_CHUNK)
    edges = np.linspace(0, photons, n_chunks + 1).round().astype(np.int64)
    chunks = [(int(a), int(b - a)) for a, b in zip(edges[:-1], edges[1:])]

    def one(chunk):
        first, count = chunk
        cap = 2 * count
        while True:
            replay = Replay(REPLAY_STORE, organ0, np.zeros((1, START_W + B)), np.zeros((1, VPL_W + B)),
                            np.empty((cap, START_W + B)), np.zeros(2, np.int64), box)
            tallies, stats = new_tallies(kscene.n_rows, B, kscene.n_stats, N_COUNTERS)
            scratch = embree.new_scratch()
            trace_chunk(scene, None, scratch.ctypes.data, seed, first, count, tallies, stats, replay)
            n = int(replay.count[1])
            if n <= cap:
                break
            cap = n
        bins = np.empty(n, np.int64)
        weights = np.empty((n, B))
        bin_crossings(replay.seg[:n], START_W, box, grid, face0, settings.rings, settings.sectors, bins, weights)
        keep = bins >= 0
        return bins[keep], weights[keep]

    field = np.zeros((S, n_bins, B))
    crossings = 0
    with ThreadPoolExecutor(max_workers=max(1, threads or 2)) as pool:
        for c, (bins, weights) in enumerate(pool.map(one, chunks)):
            add_crossings(field, c % S, bins, weights)
            crossings += len(bins)
    pieces = chamber_pieces(kscene, box, settings.pieces)
    return LightField(field_key(kscene, box, settings, seed, flux), int(photons), int(seed), box, grid, face0,
                      settings.rings, settings.sectors, field, pieces, crossings, time.perf_counter() - t0,
                      time.process_time() - c0)


# -- a step ---------------------------------------------------------------------------------------------------
def _side_optics(kscene, mat):
    """(reflect, transmit, absorb), each (n, B): the shares of light arriving on a side whose material is ``mat``
    (n,) sent back from it (diffusely or specularly), through it, and absorbed."""
    p = kscene.mat_prob[mat]
    return p[:, DIFFUSE_R] + p[:, SPECULAR_R], p[:, DIFFUSE_T] + p[:, SPECULAR_T], p[:, ABSORB]


def region_elements(kscene, field: LightField):
    """The region's elements as a step traces them: the organs now in ``kscene`` (element i = organ i, both sides),
    then the field's chamber pieces.  Returns a dict of the arrays :func:`lpy_light.kernel.field.cast_rays` reads
    (the region's triangles one-sided pieces first, as its Embree scene numbers them) and each side's optics."""
    n_org = len(kscene.organs)
    n0 = kscene.n_chamber_triangles
    org_verts = kscene.tri_verts[n0:]
    org_elem = kscene.tri_receiver[n0:].astype(np.int64) - kscene.n_chamber_receivers
    org_mat = kscene.tri_mat[n0:]
    ptris, powner, psource, ptwo = field.pieces
    p_elem = n_org + powner
    p_mat = kscene.tri_mat[psource][powner] if len(psource) else np.zeros((0, 2), np.int32)
    one = ~ptwo[powner] if len(powner) else np.zeros(0, bool)
    verts = np.concatenate([ptris[one], org_verts, ptris[~one]]).astype(np.float64)
    elem = np.concatenate([p_elem[one], org_elem, p_elem[~one]]).astype(np.int64)
    mat = np.concatenate([p_mat[one], org_mat, p_mat[~one]]).astype(np.int64)
    n_one = int(one.sum())
    normal = np.cross(verts[:, 1] - verts[:, 0], verts[:, 2] - verts[:, 0])
    area = 0.5 * np.linalg.norm(normal, axis=1)
    normal = normal / np.maximum(2 * area, 1e-300)[:, None]
    n_el = n_org + len(psource)
    tri_side = np.stack([2 * elem, 2 * elem + 1], axis=1)
    tri_side[:n_one, 1] = -1                     # one-sided pieces: not met from behind (Embree skips them too)
    # each element's triangles (both its sides draw their points there) and their cumulative share of its area
    tris = np.argsort(elem, kind="stable").astype(np.int64)
    tri_start = np.concatenate([[0], np.cumsum(np.bincount(elem, minlength=n_el))]).astype(np.int64)
    el_area = np.bincount(elem, weights=area, minlength=n_el)
    cum = np.cumsum(area[tris])
    before = np.concatenate([[0.0], cum])[tri_start[:-1]]
    owner = elem[tris]
    tri_cdf = (cum - before[owner]) / np.maximum(el_area[owner], 1e-300)
    tri_cdf[tri_start[1:][tri_start[1:] > tri_start[:-1]] - 1] = 1.0
    has_back = np.ones(n_el, bool)
    has_back[n_org + np.unique(powner[one])] = False
    # each side's material: the one a ray arriving on it meets (front: column 0, back: column 1)
    el_mat = np.zeros((n_el, 2), np.int64)
    el_mat[elem] = mat
    side_mat = el_mat.reshape(-1)
    reflect, transmit, absorb = _side_optics(kscene, side_mat)
    reflect[1::2][~has_back] = transmit[1::2][~has_back] = 0.0
    transmit[0::2][~has_back] = 0.0
    return {"verts": verts, "normal": normal, "tri_side": tri_side.astype(np.int64), "n_one": n_one,
            "tri_start": tri_start, "tris": tris, "tri_cdf": tri_cdf, "reflect": reflect,
            "transmit": transmit, "absorb": absorb, "area": el_area, "n_organs": n_org, "n_elements": n_el,
            "has_back": has_back}


def side_budget(el, settings: FieldSettings, read=None, scale=None, groups: int = 1) -> np.ndarray:
    """Rays per side (2 · elements,): ``settings.rays`` for the sides of the organs read (``read`` (organs,) bool,
    None: all), ``shading_rays`` for the others, ``piece_rays`` for the chamber pieces' fronts; the organs' times
    ``scale`` (organs,) if given, rounded up to a multiple of ``groups`` (so that every side's rays split evenly
    between the σ's groups); none from a side without triangles."""
    n_org, n_el = el["n_organs"], el["n_elements"]
    per = np.full(n_el, float(settings.piece_rays))
    read = np.ones(n_org, bool) if read is None else np.asarray(read, bool)
    per[:n_org] = np.where(read, settings.rays, settings.shading_rays)
    if scale is not None:
        per[:n_org] *= np.asarray(scale, float)
    S = max(1, int(groups))
    rays = np.repeat((np.ceil(np.maximum(1, np.round(per)) / S) * S).astype(np.int64), 2)
    rays[np.repeat(np.diff(el["tri_start"]) == 0, 2)] = 0
    rays[1::2][~el["has_back"]] = 0
    return rays


#: normals of each guided side the guide weighs directions by (drawn by area over its triangles)
GUIDE_NORMALS = 8


def side_guides(el, field: LightField, rays, settings: FieldSettings, seed: int, threads: int = 1):
    """The direction guides of every side with triangles (:func:`lpy_light.kernel.field.guide_tables`; ``rays``
    (sides,) only gives their number), from the field's light summed over its bands, each band as a share of its
    total; returns (guide (G, bins), guide_of (sides,) −1: cosine alone, where the guide sees no light).  On
    ``threads`` threads, each a slice of the sides (the same rows as on one)."""
    n_dirs = settings.guide_z * settings.guide_phi
    n_sides = len(rays)
    guide_of = np.full(n_sides, -1, np.int64)
    if n_dirs == 0 or settings.cosine_share >= 1.0:
        return np.zeros((1, 1)), guide_of
    sides = np.flatnonzero(np.repeat(np.diff(el["tri_start"]) > 0, 2))
    if len(sides) == 0:
        return np.zeros((1, 1)), guide_of
    total = field.total
    light = (total / np.maximum(total.sum(axis=0), 1e-300)).sum(axis=1)
    elem = sides // 2
    sign = np.where(sides % 2 == 0, 1.0, -1.0)
    u = (np.arange(GUIDE_NORMALS) + 0.5) / GUIDE_NORMALS
    lo, hi = el["tri_start"][elem], el["tri_start"][elem + 1]
    cdf = el["tri_cdf"]
    picks = np.empty((len(sides), GUIDE_NORMALS), np.int64)
    for i, (a, b) in enumerate(zip(lo, hi)):
        picks[i] = el["tris"][a + np.minimum(np.searchsorted(cdf[a:b], u, "right"), b - a - 1)]
    normals = el["normal"][picks] * sign[:, None, None]
    verts = el["verts"]
    centre = verts[picks].mean(axis=(1, 2))
    normals = np.ascontiguousarray(normals)
    cuts = np.linspace(0, len(sides), max(1, min(int(threads), len(sides))) + 1).astype(np.int64)

    def part(k):
        a, b = cuts[k], cuts[k + 1]
        return guide_tables(field.box, field.grid, field.face0, field.rings, field.sectors, light, centre[a:b],
                            normals[a:b], settings.guide_z, settings.guide_phi, int(seed) + 104729, int(a))

    with ThreadPoolExecutor(max_workers=len(cuts) - 1) as pool:      # guide_tables releases the GIL
        table = np.concatenate(list(pool.map(part, range(len(cuts) - 1))))
    lit = table[:, -1] > 0
    guide_of[sides[lit]] = np.arange(int(lit.sum()))
    return np.ascontiguousarray(table[lit]) if lit.any() else np.zeros((1, 1)), guide_of


def field_step(kscene, field: LightField, settings: FieldSettings, seed: int = 1, threads: int | None = None,
               read=None, scale=None, tol: float = 1e-4, max_passes: int = 200):
    """One step of the plant now in ``kscene`` lit from ``field``; returns a :class:`lpy_light.estimators.result.Result`
    in the field's photons, σ from its batches (rays per side: :func:`side_budget`)."""
    from .result import Result
    t0 = time.perf_counter()
    el = region_elements(kscene, field)
    rays = side_budget(el, settings, read, scale, field.batches)
    ray_start = np.concatenate([[0], np.cumsum(rays)]).astype(np.int64)
    n_sides = len(rays)
    out = np.empty(int(ray_start[-1]), np.int64)
    ray_tri = np.empty(int(ray_start[-1]), np.int64)
    through = np.empty((int(ray_start[-1]), kscene.n_bands))
    refl, trans = np.ascontiguousarray(el["reflect"]), np.ascontiguousarray(el["transmit"])
    verts, n_one = el["verts"], el["n_one"]
    region = embree.EmbreeScene(one_sided=verts[:n_one] if n_one else None,
                                two_sided=verts[n_one:] if len(verts) > n_one else None)
    geom_offset = np.array([0, n_one, 0, 0], np.int64)
    intersect = embree.intersect1_address()
    offset_rel = float(kscene.chamber.physics.offset)
    workers = max(1, threads or 2)
    guide, guide_of = side_guides(el, field, rays, settings, seed, workers)
    # the sides in parts of about equal rays, one thread each at a time
    n_parts = max(1, min(n_sides, 4 * workers))
    cuts = np.searchsorted(ray_start, np.linspace(0, ray_start[-1], n_parts + 1)[1:-1])
    bounds = np.unique(np.concatenate([[0], np.clip(cuts, 0, n_sides), [n_sides]]))

    geometry = Region(region.handle, intersect, geom_offset, verts, el["normal"], offset_rel, el["tri_side"])
    sides = RaySides(el["tri_start"], el["tris"], el["tri_cdf"], rays, ray_start, refl, trans, guide_of)
    bins = FieldBins(field.box, field.grid, field.face0, int(field.rings), int(field.sectors))
    guides = Guide(guide, float(settings.cosine_share), int(settings.guide_phi))
    ends = RayEnds(out, ray_tri, through)

    # each part's rays read where they ended on the thread that cast them (parts are whole sides: each sum has
    # rows of its own, summed in the same order as on one thread)
    S, B = field.batches, kscene.n_bands
    ts_side = np.ascontiguousarray(el["tri_side"].reshape(-1))
    counts = np.zeros((1 + S, len(ts_side)))
    direct = np.zeros((1 + S, len(ts_side), B))
    batch = np.zeros((S, n_sides, B))
    met = np.empty(len(out), np.int64)
    by_bin, total = field.by_bin, field.total
    seconds = np.zeros((len(bounds) - 1, 2))

    def part(i):
        t = time.perf_counter()
        scratch = embree.new_scratch()
        cast_rays(geometry, sides, bins, guides, int(bounds[i]), int(bounds[i + 1]), int(seed), int(settings.bounces),
                  int(field.batches), scratch.ctypes.data, ends)
        seconds[i, 0] = time.perf_counter() - t
        k0, k1 = int(ray_start[bounds[i]]), int(ray_start[bounds[i + 1]])
        n_met = read_rays(out, ray_tri, through, by_bin, total, field.bins_per_cell, ts_side, k0, k1,
                          (counts, direct, batch), met)
        seconds[i, 1] = time.perf_counter() - t - seconds[i, 0]
        return met[k0:k0 + n_met]

    with ThreadPoolExecutor(max_workers=workers) as pool:
        met = np.concatenate(list(pool.map(part, range(len(bounds) - 1))))
    src, dst, link_w, link_start = field_links(out, ray_tri, through, met, S)
    t_read = seconds[:, 1].sum() / workers           # of the time up to here, reading the rays (over the threads)
    t_rays = time.perf_counter() - t0 - t_read

    def solve(c, passes, start=None):
        a, b = (0, len(src)) if c == 0 else (link_start[c - 1], link_start[c])
        return solve_passes(counts[c], direct[c], src[a:b], dst[a:b], link_w[a:b], ts_side, n_sides, refl, trans,
                            tol, passes, start)

    # the light between organs to convergence by element sides (their links summed: few), then a few passes by
    # triangle sides from there (what a ray reads where it ends is that triangle's light), then, from the full
    # solve's light, the own passes of each σ group of rays (the whole field; by triangle sides) and of each
    # batch of the field (all the rays; by element sides): the rays' spread and the field's, apart
    own = np.arange(n_sides, dtype=np.int64)
    s_rays, s_direct = side_sums(counts[0], direct[0], ts_side, n_sides)
    s_src, s_dst, s_w = side_links(src, dst, link_w, ts_side, n_sides)
    E_side, passes, _ = solve_passes(s_rays, s_direct, s_src, s_dst, s_w, own, n_sides, refl, trans, tol,
                                     max_passes, None)
    start = np.where(ts_side[:, None] >= 0, E_side[np.maximum(ts_side, 0)], 0.0)
    E, tri_passes, E_ts = solve(0, min(max_passes, TRIANGLE_PASSES), start)
    group_passes = min(max_passes, GROUP_PASSES)
    with ThreadPoolExecutor(max_workers=workers) as pool:      # the solves release the GIL
        E_g = np.stack([e for e, _, _ in pool.map(lambda g: solve(1 + g, group_passes, E_ts), range(S))])
        E_f = np.stack([e for e, _, _ in pool.map(
            lambda g: solve_passes(s_rays, batch[g], s_src, s_dst, s_w, own, n_sides, refl, trans, tol, group_passes,
                                   E_side), range(S))])
    t_solve = time.perf_counter() - t0 - t_rays - t_read
    # per organ: incident (both sides) and absorbed, × its area
    n_org = el["n_organs"]
    area = el["area"][:n_org]

    def organ_rows(Es):
        side = Es[:2 * n_org].reshape(n_org, 2, B)
        inc = (side[:, 0] + side[:, 1]) * area[:, None]
        ab = (side[:, 0] * el["absorb"][0:2 * n_org:2] + side[:, 1] * el["absorb"][1:2 * n_org:2]) * area[:, None]
        return inc, ab

    n_rows = kscene.n_rows
    s0, R, R0 = kscene.n_sensors, kscene.n_receivers, kscene.n_chamber_receivers
    rows_inc = s0 + R0 + np.arange(n_org)
    rows_ab = s0 + R + R0 + np.arange(n_org)
    tally = np.zeros((n_rows, B))
    tally[rows_inc], tally[rows_ab] = organ_rows(E)
    # products such that Result's covariance (batches = S) is the rays' part plus the field's: each the
    # covariance of the mean of S estimates (the groups of rays read against the whole field; the whole of the
    # rays read against each batch of the field); what a group reading its own batch alone would add (the two
    # spreads crossed) is not in the step's estimate, which reads every batch with every ray
    N = field.photons
    prod = np.einsum("rb,rc->rbc", tally, tally) / N
    parts = []
    for Es in (E_g, E_f):
        T = np.zeros((S, n_rows, B))
        for g in range(S):
            T[g, rows_inc], T[g, rows_ab] = organ_rows(Es[g])
        dev = T - T.mean(axis=0)
        prod += np.einsum("srb,src->rbc", dev, dev) / (N * S)
        parts.append(T[:, rows_inc])
    counters = np.zeros(N_COUNTERS, np.int64)
    result = Result(N, tally, prod, counters, time.perf_counter() - t0, workers, seed, kscene.n_sensors,
                    kscene.n_receivers, estimator="field", materials=[m.name for m in kscene.materials],
                    nee_stats=np.zeros((kscene.n_stats, 3)), batches=S)
    result.extra["field_step"] = {"rays": int(ray_start[-1]), "passes": int(passes), "links": int(len(src)), "rays_s": round(t_rays, 4),
                                  "read_s": round(t_read, 4), "solve_s": round(t_solve, 4),
                                  "elements": int(el["n_elements"]), "pieces": int(len(field.pieces[2]))}
    # the organs' incident tallies of each σ group of rays and of each batch of the field, (S, organs, B) each: the
    # σ of a sum over organs, whose field part is common to all of them (lpy_light.plant.verify)
    result.extra["parts"] = parts
    region.close()
    return result


class FieldKeeper:
    """The field a growing plant is lit from: kept while it is valid, traced again when it is not (none yet; the
    chamber, its materials or lamps changed; the plant left its region; every ``settings.renew`` steps).
    ``built`` counts the fields traced; ``why`` says why the last one was; ``verdict`` is the current field's
    self-check (None: not checked), ``checks`` every field's, ``pool`` what the check pools from the fields before
    (:mod:`lpy_light.plant.verify`)."""

    def __init__(self, settings: FieldSettings, seed: int = 1):
        self.settings, self.seed = settings, int(seed)
        self.field: LightField | None = None
        self.steps = 0
        self.built = 0
        self.why = ""
        self.verdict: dict | None = None
        self.checks: list = []
        self.pool: list = []        # the last few self-checks' comparisons, pooled (lpy_light.plant.verify.POOL)

    @property
    def trusted(self) -> bool:
        """Whether the current field may light a step: not checked, or passed its check."""
        return self.verdict is None or bool(self.verdict.get("passed"))

    def field_for(self, kscene, organs, flux=None, threads=None) -> LightField:
        f = self.field
        cfg = self.settings
        if f is None:
            why = "first step"
        elif not inside(f.box, organs):
            why = "the plant left the field's region"
        elif field_key(kscene, f.box, cfg, f.seed, flux) != f.key:
            why = "the chamber, its materials or its lamps changed"
        elif cfg.renew and self.steps >= cfg.renew:
            why = "renewed after %d steps" % self.steps
        else:
            self.steps += 1
            return f
        self.field = build_field(kscene, cfg, seed=self.seed + 7919 * self.built, threads=threads, flux=flux)
        self.built += 1
        self.why = why
        self.steps = 1
        return self.field

    def step(self, kscene, organs, seed: int, flux=None, threads=None, scale=None, read=None, check=None):
        """One step's :class:`~lpy_light.estimators.result.Result` for ``organs`` (in ``kscene`` already); ``scale``
        (organs,) multiplies each organ's rays.  ``check(field, result)``, called on the step of each field traced
        here, returns its verdict (a dict whose ``passed`` says whether it may be used:
        :func:`lpy_light.plant.verify.field_self_check`).  None where the current field failed its check: the
        caller lights the step otherwise (``verdict`` says why)."""
        built = self.built
        field = self.field_for(kscene, organs, flux, threads)
        if self.built != built:
            self.verdict = None
        elif not self.trusted:
            return None
        c0 = time.process_time()
        result = field_step(kscene, field, self.settings, seed=seed, threads=threads, read=read, scale=scale)
        result.extra["cpu_s"] = time.process_time() - c0        # CPU s of the step's rays, every thread's
        result.extra["store"] = dict(field.describe(), why=self.why, steps_from_it=self.steps)
        if self.built != built and check is not None and self.settings.check_photons > 0:
            self.verdict = check(field, result)
            self.checks.append(self.verdict)
            result.extra["field_check"] = self.verdict
        return result if self.trusted else None
