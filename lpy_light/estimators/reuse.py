"""The chamber's light traced once, replayed into each step's plant: the ``reuse`` estimator.

A growth step with the full kernel (``nee``) traces the lamps, the lamp box, the diffusing ceiling and the walls
again at every step, to learn how much light reaches the plant; ~80 % of its shadow rays and ~87 % of the organs'
light come from vertices on the chamber (``docs/physics.md``, "The chamber's light stored once").  Here that is
traced once into a :class:`ChamberStore` (:func:`build_store`), and each step (:func:`gather_step`) only

* gathers the store's light at every organ target, ``samples`` draws per target through the current plant (a bud
  gets as many as a leaf): :func:`lpy_light.kernel.gather.gather_batch`;
* traces on from each draw that reached an organ, and from each stored segment that crosses the plant's region,
  until the path meets the chamber again: the light the organs send each other.

The store is the chamber's light *with the plant that was there when it was built*: what the plant changes in the
chamber's light (its shadow on the table, the light its leaves send to the walls) is that plant's until the store
is renewed (:class:`StoreKeeper`).  The light between organs is the current plant's.

σ: the store's photons are split in ``batches`` independent parts, each gathered on its own; the spread of the
batches' estimates is the step's σ, the store's own error included (:attr:`lpy_light.estimators.result.Result.batches`).

Measured (``benchmarks/reuse.py``, ``docs/performance.md``): unbiased, σ honest, a step ~5x cheaper than ``nee``'s
at ~2x its σ, and so at the same σ no cheaper on a rose (and dearer amid a canopy): the shadow rays through the
current plant, which a gather casts again at every step, are the cost, not the chamber's flights.
"""
from __future__ import annotations

import dataclasses
import hashlib
import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..kernel import embree
from ..kernel.gather import cluster_cdf, gather_batch
from ..kernel.nee import NEAR
from ..kernel.records import (DIFFUSE_R, DIFFUSE_T, REPLAY_CONTINUE, REPLAY_STORE, START_W, V_ISOTROPIC, V_SURFACE,
                              VPL_W, GatherDraws, GatherOut, Replay, new_tallies)
from ..kernel.tallies import N_COUNTERS
from ..kernel.trace import trace_chunk, work_arrays

#: photons per chunk of the store's trace
STORE_CHUNK = 16384
#: edge of the cells that group the stored vertices for the gather's first draw, in metres
CELL = 0.1
#: the plant's region: its bounding box grown by this share of its size and by :data:`MARGIN` metres each side
GROWTH = 0.5
MARGIN = 0.2


@dataclass(frozen=True)
class ReuseSettings:
    """How the ``reuse`` estimator lights a plant (:class:`lpy_light.plant.light.LightModel` ``reuse=``).

    Parameters
    ----------
    store_photons : int
        Photons traced into a store (its own error falls as 1/√ of it; its memory, ~300 bytes a photon).
    batches : int
        Independent parts of the store: a step's σ is the spread of their estimates (≥ 8).
    samples : int
        Draws per organ target and batch of the light coming straight from the chamber.
    zone_samples : int or None
        Two-step draws through the zone of each target that has one (buds), per batch (None: ``samples``).
    image_draws : float
        Stored vertices drawn per organ target and batch to light the organs through a mirror.
    paths : float
        Paths per organ target and batch traced on from the organs the draws reached (the light between organs),
        from each organ in proportion to its light.
    renew : int
        Steps after which the store is traced again with the plant then in place (what the plant changes in the
        chamber's light is the store's plant's until then); 0: never for that reason.
    """

    store_photons: int = 200_000
    batches: int = 16
    samples: int = 64
    zone_samples: int | None = None
    image_draws: float = 8.0
    paths: float = 2.0
    renew: int = 10

    def __post_init__(self):
        for name in ("image_draws", "paths"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) or \
                    not 0 <= value <= 1e6:
                raise InputError("reuse setting %r must be a number of draws per organ in 0..1e6, got %r"
                                 % (name, value))
            object.__setattr__(self, name, float(value))
        for name, lo in (("store_photons", 1), ("batches", 8), ("samples", 1), ("zone_samples", 0), ("renew", 0)):
            value = getattr(self, name)
            if value is None and name == "zone_samples":
                continue
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer)) or value != int(value) \
                    or value < lo:
                raise InputError("reuse setting %r must be a whole number >= %d, got %r" % (name, lo, value))
            object.__setattr__(self, name, int(value))


def reuse_settings(spec) -> ReuseSettings:
    """``spec``: None (the defaults), a :class:`ReuseSettings`, or a mapping of its fields."""
    if spec is None:
        return ReuseSettings()
    if isinstance(spec, ReuseSettings):
        return spec
    try:
        return ReuseSettings(**dict(spec))
    except TypeError:
        raise InputError("unknown reuse setting in %r (the settings: %s)"
                         % (dict(spec), ", ".join(f.name for f in dataclasses.fields(ReuseSettings)))) from None


@dataclass
class ChamberStore:
    """The chamber's light, stored: its next-event vertices and the uncovered segments that cross the plant's region.

    ``vpl`` (n, VPL_W + B) and ``seg`` (m, START_W + B): rows as :class:`lpy_light.kernel.records.Replay` has
    them, with ``vpl_batch`` (n,), ``seg_batch`` (m,) their batch; ``photons`` the photons traced (the tallies'
    unit), ``batches`` S, ``box`` (6,) the plant's region (scene units), ``key`` what it was built for.
    The gather's cells: ``cells`` (the arrays :func:`lpy_light.kernel.gather.gather_batch` reads) and the
    clusters' centres, normals and light (``cl_*``)."""

    key: str
    photons: int
    batches: int
    seed: int
    box: np.ndarray
    vpl: np.ndarray
    vpl_batch: np.ndarray
    seg: np.ndarray
    seg_batch: np.ndarray
    cells: tuple = ()
    clusters: tuple = ()
    seconds: float = 0.0
    extra: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        """A short name of this store (its key's first 12 hex digits), as ``summary.json`` gives it."""
        return self.key[:12]

    def describe(self) -> dict:
        return {"store": self.name, "photons": self.photons, "batches": self.batches, "seed": self.seed,
                "vertices": int(len(self.vpl)), "segments": int(len(self.seg)),
                "box": [float(x) for x in self.box], "seconds": round(self.seconds, 3)}


def plant_box(organs, metres_per_unit: float) -> np.ndarray:
    """The region a store serves for the plant ``organs`` (chamber units): their bounding box grown by
    :data:`GROWTH` of its size and :data:`MARGIN` metres each side (a store serves a growing plant for steps: a
    larger region costs only the segments that cross it); (6,) lo, hi."""
    pts = np.concatenate([np.asarray(o.triangles, float).reshape(-1, 3) for o in organs])
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    grow = GROWTH * (hi - lo) + MARGIN / metres_per_unit
    return np.concatenate([lo - grow, hi + grow])


def inside(box, organs) -> bool:
    """Do ``organs`` lie within ``box`` (6,)?"""
    pts = np.concatenate([np.asarray(o.triangles, float).reshape(-1, 3) for o in organs])
    return bool(np.all(pts.min(axis=0) >= box[:3]) and np.all(pts.max(axis=0) <= box[3:]))


def chamber_key(kscene, box, photons, batches, seed, flux=None) -> str:
    """What a store depends on, hashed: the chamber's triangles and materials, the lamps (their elements and
    ``flux``), the sources that make next events, the plant's region ``box`` and the store's size and seed."""
    h = hashlib.sha256()
    n = kscene.n_chamber_triangles
    for a in (kscene.tri_verts[:n], kscene.tri_mat[:n], kscene.mat_prob, kscene.mat_phong, kscene.emit.kind,
              kscene.emit.data, kscene.emit.cdf, kscene.mat_nee, kscene.emit_nee, np.asarray(box, float),
              np.asarray([] if flux is None else flux, float)):
        h.update(np.ascontiguousarray(a).tobytes())
    h.update(repr((int(photons), int(batches), int(seed), float(kscene.chamber.physics.max_depth))).encode())
    return h.hexdigest()


def build_store(kscene, photons: int, batches: int = 16, seed: int = 1, threads: int | None = None, box=None,
                flux=None) -> ChamberStore:
    """Trace ``photons`` photons through ``kscene`` as it stands (the chamber and the plant now in it) and store
    the chamber's light for the plant's region ``box`` (default: :func:`plant_box` of its organs).  ``photons`` is
    rounded up to a multiple of ``batches``; chunk c belongs to batch c mod ``batches``, each batch the same
    number of photons; the same store on any number of ``threads``."""
    t0 = time.perf_counter()
    box = plant_box(kscene.organs, kscene.chamber.metres_per_unit) if box is None else np.asarray(box, float)
    scene, nee, _, _ = reuse_records(kscene)
    organ0 = kscene.n_chamber_receivers
    n_bands = kscene.n_bands
    per_batch = math.ceil(photons / batches)
    photons = per_batch * batches                 # every batch the same photons: the batches' estimates are alike
    n_chunks = batches * math.ceil(per_batch / STORE_CHUNK)
    edges = np.linspace(0, photons, n_chunks + 1).round().astype(np.int64)
    chunks = [(int(a), int(b - a)) for a, b in zip(edges[:-1], edges[1:])]

    def one(chunk):
        first, count = chunk
        cap_v, cap_s = 8 * count, 2 * count
        while True:
            replay = Replay(REPLAY_STORE, organ0, np.zeros((1, START_W + n_bands)), np.empty((cap_v, VPL_W + n_bands)),
                            np.empty((cap_s, START_W + n_bands)), np.zeros(2, np.int64), box)
            tallies, stats = new_tallies(kscene.n_rows, n_bands, kscene.n_stats, N_COUNTERS)
            scratch = embree.new_scratch()
            trace_chunk(scene, nee, scratch.ctypes.data, seed, first, count, tallies, stats, replay)
            n_v, n_s = int(replay.count[0]), int(replay.count[1])
            if n_v <= cap_v and n_s <= cap_s:
                return replay.vpl[:n_v].copy(), replay.seg[:n_s].copy()
            cap_v, cap_s = max(cap_v, n_v), max(cap_s, n_s)

    with ThreadPoolExecutor(max_workers=max(1, threads or 2)) as pool:
        parts = list(pool.map(one, chunks))
    vpl = np.concatenate([p[0] for p in parts]) if parts else np.zeros((0, VPL_W + n_bands))
    seg = np.concatenate([p[1] for p in parts]) if parts else np.zeros((0, START_W + n_bands))
    vpl_batch = np.concatenate([np.full(len(p[0]), c % batches) for c, p in enumerate(parts)]).astype(np.int64)
    seg_batch = np.concatenate([np.full(len(p[1]), c % batches) for c, p in enumerate(parts)]).astype(np.int64)
    store = ChamberStore(chamber_key(kscene, box, photons, batches, seed, flux), int(photons), int(batches), int(seed),
                         box, vpl, vpl_batch, seg, seg_batch)
    store.cells, store.clusters = _cells(kscene, store)
    store.seconds = time.perf_counter() - t0
    return store


def vertex_light(kscene, vpl) -> np.ndarray:
    """(n,) the light each stored vertex can send out by a diffuse event, band mean: its photon's mean weight ×
    its material's larger diffuse reflectance or transmittance (1 at a lamp)."""
    w = vpl[:, VPL_W:].mean(axis=1)
    m = vpl[:, 7].astype(np.int64)
    side = np.maximum(kscene.mat_prob[:, DIFFUSE_R, :], kscene.mat_prob[:, DIFFUSE_T, :]).mean(axis=1)
    return np.where(vpl[:, 6] == V_SURFACE, w * side[m], w)


def _cells(kscene, store):
    """Group the stored vertices into clusters (a triangle's part within a :data:`CELL` cube, or a lamp's) and lay
    them out by batch and cluster for :func:`~lpy_light.kernel.gather.gather_batch`."""
    vpl, S = store.vpl, store.batches
    n = len(vpl)
    pos = vpl[:, :3]
    cell = CELL / kscene.chamber.metres_per_unit
    vox = np.floor(pos / cell).astype(np.int64)
    tri = vpl[:, 9].astype(np.int64)
    surface = vpl[:, 6] == V_SURFACE
    # lamps: grouped by cell and by how they leave (isotropic or by their normal, rounded)
    lamp_tag = np.where(surface, 0, 1 + (vpl[:, 6] == V_ISOTROPIC) + 4 * np.round(vpl[:, 3:6] * 2).astype(np.int64)
                        @ np.array([1, 5, 25]))
    keys = np.stack([tri, lamp_tag, vox[:, 0], vox[:, 1], vox[:, 2]], axis=1) if n else np.zeros((0, 5), np.int64)
    _, cluster = np.unique(keys, axis=0, return_inverse=True)
    cluster = cluster.reshape(-1)
    K = int(cluster.max()) + 1 if n else 1
    light = vertex_light(kscene, vpl)
    # per cluster: light-weighted centre, a normal (the triangle's; a lamp's own), light towards each side
    wsum = np.bincount(cluster, weights=light, minlength=K)
    cl_pos = np.stack([np.bincount(cluster, weights=light * pos[:, a], minlength=K) for a in range(3)], axis=1)
    cl_pos /= np.where(wsum > 0, wsum, 1.0)[:, None]
    normal = np.where(surface[:, None], kscene.tri_normal[np.maximum(tri, 0)], vpl[:, 3:6])
    cl_normal = np.zeros((K, 3))
    cl_normal[cluster] = normal
    m = vpl[:, 7].astype(np.int64)
    w = vpl[:, VPL_W:]
    front = np.einsum("ij,ij->i", vpl[:, 3:6], normal) > 0        # arrived on the normal's side
    refl = np.einsum("ib,ib->i", w, kscene.mat_prob[m, DIFFUSE_R, :]) / w.shape[1]
    trans = np.einsum("ib,ib->i", w, kscene.mat_prob[m, DIFFUSE_T, :]) / w.shape[1]
    lamb = vpl[:, 6] != V_ISOTROPIC
    up = np.where(surface, np.where(front, refl, trans), np.where(lamb, w.mean(axis=1), 0.0))
    down = np.where(surface, np.where(front, trans, refl), 0.0)
    iso = np.where(vpl[:, 6] == V_ISOTROPIC, w.mean(axis=1), 0.0)
    cl_up, cl_down, cl_iso = (np.bincount(cluster, weights=x, minlength=K) for x in (up, down, iso))
    # the vertices by batch, then cluster; each cell's range, cumulative light, and total
    cell_id = store.vpl_batch * K + cluster
    order = np.argsort(cell_id, kind="stable")
    bounds = np.searchsorted(cell_id[order], np.arange(S * K + 1))
    cell_start = np.stack([bounds[b * K:(b + 1) * K + 1] for b in range(S)])       # (S, K + 1)
    cell_w = np.bincount(cell_id, weights=light, minlength=S * K).reshape(S, K)
    cum = np.cumsum(light[order])
    start_of = bounds[:-1][cell_id[order]]
    before = np.where(start_of > 0, cum[np.maximum(start_of - 1, 0)], 0.0)
    cell_cum = (cum - before) / np.where(cell_w.reshape(-1)[cell_id[order]] > 0, cell_w.reshape(-1)[cell_id[order]], 1.0)
    batch_of = store.vpl_batch[order]
    cum_b = np.cumsum(light[order])
    first_b = bounds[::K][batch_of]                          # each vertex's batch's first position in ``order``
    before_b = np.where(first_b > 0, cum_b[np.maximum(first_b - 1, 0)], 0.0)
    w_b = cell_w.sum(axis=1)[batch_of]
    batch_cum = (cum_b - before_b) / np.where(w_b > 0, w_b, 1.0)
    cells = (np.ascontiguousarray(vpl), order.astype(np.int64), cell_start.astype(np.int64), cell_cum,
             np.ascontiguousarray(cell_w), np.ascontiguousarray(light), batch_cum)
    clusters = (np.ascontiguousarray(cl_pos), np.ascontiguousarray(cl_normal), cl_up, cl_down, cl_iso)
    return cells, clusters


def reuse_records(kscene):
    """The kernel's records for the store's trace, the gather and the paths: ``(scene, store, gather, paths)``.

    Mirrors: next events through one mirror from the chamber's vertices are the gather's (``picks`` 1: one per
    image draw), from the organs' the paths' (the plant's setting); through two, none anywhere (``picks2`` 0),
    so that the store counts the segments after a second mirror.  The store's trace makes no next events but
    marks, as the kernel does, the segments that leave a mirror after a next-event vertex."""
    scene, nee = kscene.records()
    on = nee.mirrors.plane.shape[0] > 0
    store = nee._replace(mirrors=nee.mirrors._replace(picks=1.0 if on else 0.0, picks2=0.0))
    paths = nee._replace(mirrors=nee.mirrors._replace(picks2=0.0))
    return scene, store, store, paths


def gather_cdf(kscene, store, nee) -> np.ndarray:
    """(T, K) the cumulative probabilities of the store's clusters for each target of ``nee``."""
    tgt = nee.targets
    radius = np.sqrt(tgt.img_near2) / NEAR
    out = np.empty((len(tgt.kind), len(store.clusters[2])))
    return cluster_cdf(np.ascontiguousarray(tgt.center), np.ascontiguousarray(tgt.area, dtype=float),
                       np.ascontiguousarray(radius), target_normals(kscene, tgt), *store.clusters, out)


def target_normals(kscene, tgt) -> np.ndarray:
    """(T, 3) each mesh target's area-weighted mean unit normal (length 1 for a flat leaf, ~0 for a closed bud;
    zero for sensors)."""
    out = np.zeros((len(tgt.kind), 3))
    mesh = np.flatnonzero(np.asarray(tgt.count) > 0)
    if len(mesh):
        idx = np.concatenate([tgt.tri[tgt.first[t]:tgt.first[t] + tgt.count[t]] for t in mesh])
        owner = np.repeat(mesh, np.asarray(tgt.count)[mesh])
        v = kscene.tri_verts[idx]
        n_area = 0.5 * np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])     # normal × area
        for a in range(3):
            out[:, a] = np.bincount(owner, weights=n_area[:, a], minlength=len(tgt.kind))
        out /= np.maximum(np.asarray(tgt.area, float), 1e-300)[:, None]
    return out


def gather_step(kscene, store: ChamberStore, samples: int = 64, seed: int = 1, threads: int | None = None,
                paths: int = 1024, zone_samples: int | None = None, image_draws: int = 4096, read=None, scale=None,
                parts=("gather", "paths", "segments")):
    """One step of the plant now in ``kscene`` lit from ``store``; returns a :class:`lpy_light.estimators.result.Result`
    in the store's photons, σ from its batches.

    Per organ target and batch: ``samples`` draws of the chamber's direct light and ``zone_samples`` (default
    ``samples``) two-step draws through a bud's zone (:func:`lpy_light.kernel.gather.gather_batch`), a quarter of
    those for the organs not in ``read`` ((organs,) bool; None: all read), each organ's times ``scale``
    ((organs,), if given); per batch, ``image_draws`` vertices lighting the organs through a mirror and ``paths``
    paths traced on from the organs reached (:func:`_roulette`), with the stored segments (``REPLAY_CONTINUE``).
    ``parts``: which of the three to tally (a diagnostic: each part's share and noise)."""
    from .result import Result
    t0 = time.perf_counter()
    zone_samples = samples if zone_samples is None else int(zone_samples)
    scene, _, nee, nee_paths = reuse_records(kscene)
    cdf = gather_cdf(kscene, store, nee)
    n_t = len(nee.targets.kind)
    targets = np.arange(n_t, dtype=np.int64)
    organs = nee.organs       # organ zone events as the kernel makes them (kernel.trace: organ_on), or none
    if organs is None or not (organs.zones.picks > 0.0 and organs.zones.target.shape[0] > 0
                              and 0 < nee.targets.picks < n_t):
        zone_samples = 0
    # draws per target: the organs the caller reads get ``samples``; the others (they shade and scatter, and start
    # paths, but nobody reads their numbers) a quarter of them
    rec = np.asarray(nee.targets.ref) - kscene.n_chamber_receivers
    organ = np.clip(rec, 0, len(kscene.organs) - 1)
    read = np.ones(n_t, bool) if read is None else np.asarray(read, bool)[organ]
    times = np.ones(n_t) if scale is None else np.asarray(scale, float)[organ]
    per_target = np.maximum(1, np.round(np.where(read, samples, samples / 4) * times)).astype(np.int64)
    per_zone = np.round(np.where(read, zone_samples, zone_samples / 4) * times).astype(np.int64)
    n_bands, n_rows = kscene.n_bands, kscene.n_rows
    organ0 = kscene.n_chamber_receivers
    S = store.batches

    def batch(b):
        tallies, stats = new_tallies(n_rows, n_bands, kscene.n_stats, N_COUNTERS)
        scratch = embree.new_scratch()
        photon, _, _ = work_arrays(scene, nee, scratch.ctypes.data, tallies)
        tally = np.zeros((n_rows, n_bands))
        starts = np.empty((int(per_target.sum()), START_W + n_bands))
        draws = GatherDraws(targets, per_target, per_zone, np.int64(image_draws), np.int64(seed))
        n_s = gather_batch(scene, nee, nee.organs, np.int64(b), store.cells, cdf, draws, GatherOut(tally, starts),
                           photon, stats)
        if "gather" not in parts:
            tally[:] = 0.0
        if "paths" not in parts:
            n_s = 0
        seg = store.seg[store.seg_batch == b] if "segments" in parts else store.seg[:0]
        starts = np.concatenate([_roulette(starts, n_s, paths, np.random.default_rng([seed, b])), seg])
        n_s = len(starts)
        if n_s:
            replay = Replay(REPLAY_CONTINUE, organ0, starts[:n_s], np.zeros((1, VPL_W + n_bands)),
                            np.zeros((1, START_W + n_bands)), np.zeros(2, np.int64), store.box)
            trace_chunk(scene, nee_paths, scratch.ctypes.data, seed ^ 0x5EED, b * (1 << 40), n_s, tallies, stats, replay)
        return tally + tallies.tally, stats.counters, stats.nee_stats

    workers = max(1, threads or 2)
    with ThreadPoolExecutor(max_workers=workers) as pool:
        done = list(pool.map(batch, range(S)))
    Z = np.stack([d[0] for d in done])                  # (S, rows, B): each batch's estimate of its share
    N = store.photons
    prod = (S / N) * np.einsum("srb,src->rbc", Z, Z)     # so that Result's σ is the spread over batches
    counters = np.sum([d[1] for d in done], axis=0)
    nee_stats = np.sum([d[2] for d in done], axis=0)
    result = Result(N, Z.sum(axis=0), prod, counters, time.perf_counter() - t0, workers, seed, kscene.n_sensors,
                    kscene.n_receivers, estimator="reuse", materials=[m.name for m in kscene.materials],
                    nee_stats=nee_stats, batches=S)
    result.extra["store"] = store.name
    return result


def _roulette(starts, n, budget, rng):
    """About ``budget`` paths from the ``n`` first rows of ``starts``, all of the same mean weight w₀ = Σ w / budget
    (w a row's mean over the bands): a row of weight w gives ⌊w / w₀⌋ paths, and one more with probability the
    rest, each of its weights times w₀ / w (unbiased: w / w₀ paths of weight w₀ in expectation).  Light is then
    traced on from the organs in proportion to it, as photons would land there, and no path carries the weight
    of a lucky draw: a draw that deposits much (a small q) is split, not kept whole.  Returns the rows, a new
    array."""
    if n == 0 or budget <= 0:
        return starts[:0]
    w = starts[:n, START_W:].mean(axis=1)
    w0 = w.sum() / budget
    if not w0 > 0.0:
        return starts[:0]
    copies = np.floor(w / w0).astype(np.int64)
    copies += rng.random(n) < (w / w0 - copies)
    rows = np.repeat(starts[:n], copies, axis=0)
    keep = np.repeat(w, copies)
    rows[:, START_W:] *= (w0 / keep)[:, None]
    return rows


class StoreKeeper:
    """The store a growing plant is lit from: kept while it is valid, built again when it is not.

    A store is traced again (:meth:`store_for`) when there is none, when what it was built for has changed (its
    key, :func:`chamber_key`: the chamber's triangles and materials, the lamps and their flux, the sources that
    make next events, the plant's region), when the plant has left its region, and every ``settings.renew``
    steps.  ``built`` counts the stores traced; ``why`` says why the last one was."""

    def __init__(self, settings: ReuseSettings, seed: int = 1):
        self.settings, self.seed = settings, int(seed)
        self.store: ChamberStore | None = None
        self.steps = 0            # steps lit from the current store
        self.built = 0
        self.why = ""

    def store_for(self, kscene, organs, flux=None, threads=None) -> ChamberStore:
        s = self.store
        cfg = self.settings
        if s is None:
            why = "first step"
        elif not inside(s.box, organs):
            why = "the plant left the store's region"
        elif chamber_key(kscene, s.box, s.photons, s.batches, s.seed, flux) != s.key:
            why = "the chamber, its materials or its lamps changed"
        elif cfg.renew and self.steps >= cfg.renew:
            why = "renewed after %d steps" % self.steps
        else:
            self.steps += 1
            return s
        self.store = build_store(kscene, cfg.store_photons, cfg.batches, seed=self.seed + 7919 * self.built,
                                 threads=threads, flux=flux)
        self.built += 1
        self.why = why
        self.steps = 1
        return self.store

    def step(self, kscene, organs, seed: int, flux=None, threads=None, scale=None, read=None):
        """One step's :class:`~lpy_light.estimators.result.Result` for ``organs`` (in ``kscene`` already), from a valid
        store; ``scale`` (organs,) multiplies each organ's draws (a precision goal asks more where it is not met;
        the paths and image draws by their mean)."""
        store = self.store_for(kscene, organs, flux, threads)
        cfg = self.settings
        zone = cfg.samples if cfg.zone_samples is None else cfg.zone_samples
        per = len(organs) * (1.0 if scale is None else float(np.mean(scale)))     # organ targets × their scale
        result = gather_step(kscene, store, samples=cfg.samples, seed=seed, threads=threads,
                             paths=max(1, round(cfg.paths * per)), zone_samples=zone,
                             image_draws=max(1, round(cfg.image_draws * per)), read=read, scale=scale)
        result.extra["store"] = dict(store.describe(), why=self.why, steps_from_it=self.steps)
        return result
