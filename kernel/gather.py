"""The gather: a step's organs lit from the chamber's light stored once (the ``reuse`` estimator).

The chamber does not change between growth steps; a full step (:mod:`kernel.trace`) nevertheless traces the
lamps, the lamp box, the diffusing ceiling and the walls again to learn how much light reaches the plant.  The
reuse traces that once, into a *store* (:func:`kernel.trace.trace_chunk` with ``REPLAY_STORE``):

* the chamber's next-event vertices (a lamp, a diffuse event on the chamber), each with its photon's weights:
  the light that next events from there would bring the organs (``Replay.vpl``);
* the segments from the chamber that next events do not cover (after a specular event, from a pruned source)
  and that cross the plant's region (``Replay.seg``).

A step then estimates, for every organ target t, the sum over the stored vertices v of a next event's expected
deposit E_v[t] (:func:`kernel.nee.target_event`, whatever the vertex: the same estimator as the full kernel's,
through the current plant) with ``samples`` draws per target -- a bud gets as many as a leaf:

    v drawn in two steps: a cluster k of vertices with probability q_k(t) (its light towards t, ~ W_k p_k(ω) A_t / d²,
    :func:`cluster_cdf`), then a vertex of k in proportion to its mean weight w̄_v / W_k;
    deposit E_v[t] / (samples · q_k · w̄_v / W_k)

an unbiased estimate of Σ_v E_v[t] for the store's vertices.  Each draw that reaches t continues as a path from
there (``Replay.starts``, ``REPLAY_CONTINUE``): the light the organs send each other is traced at every step, and
ends where it meets the chamber again (what the chamber sends back is in the store).  The stored segments are
replayed the same way, their crossings counted.  Everything is per *batch* of the store (its photons split in
``S`` independent parts): each batch gives one independent estimate of the step, so the spread over batches is the
step's σ, the store's own error included.

Positions in scene units; weights in photons of weight of the store's photons.
"""
import math

import numpy as np
from numba import njit

from .images import image_event
from .nee import INV_4PI, target_event
from .organ_zones import zone_event_to
from .records import START_W, V_ISOTROPIC, VPL_W, Vertex
from .rng import seed_stream, uniform
from .sampling import search_cdf

#: share of each target's draws spread over the clusters by their light alone, whatever their direction: no
#: cluster that can light a target has q = 0, however poor the importance's guess
FLOOR = 0.02


@njit(nogil=True, cache=True)
def cluster_cdf(center, area, radius, normal, cl_pos, cl_normal, cl_up, cl_down, cl_iso, out):
    """Cumulative probabilities of drawing each cluster for each target, into ``out`` (T, K).

    Targets: ``center`` (T, 3), ``area`` (T,), bounding ``radius`` (T,), area-weighted mean unit ``normal`` (T, 3)
    (its length f: 1 for a flat leaf, 0 for a closed bud; the area seen from ω taken as A (|n · ω| + (1 − f) / 4)).  Clusters: weighted centre ``cl_pos``
    (K, 3), unit normal ``cl_normal`` (K, 3), band-mean light leaving towards the normal's side ``cl_up`` (K,)
    and the other ``cl_down`` (K,) (p(ω) = up · cos⁺ / π + down · cos⁻ / π), isotropic light ``cl_iso`` (K,)
    (p = iso / 4π).  q_k ∝ (1 − FLOOR) · p_k(ω) · A_t(ω) / (d² + r_t²) + FLOOR · (the cluster's share of all light).
    """
    n_t, n_k = out.shape
    total_w = 0.0
    for k in range(n_k):
        total_w += cl_up[k] + cl_down[k] + cl_iso[k]
    for t in range(n_t):
        s = 0.0
        flat = math.sqrt(normal[t, 0] ** 2 + normal[t, 1] ** 2 + normal[t, 2] ** 2)
        for k in range(n_k):
            ex = center[t, 0] - cl_pos[k, 0]
            ey = center[t, 1] - cl_pos[k, 1]
            ez = center[t, 2] - cl_pos[k, 2]
            d2 = ex * ex + ey * ey + ez * ez
            d = math.sqrt(d2) if d2 > 0.0 else 1.0
            c = (ex * cl_normal[k, 0] + ey * cl_normal[k, 1] + ez * cl_normal[k, 2]) / d
            p = (cl_up[k] * c if c > 0.0 else -cl_down[k] * c) / math.pi + cl_iso[k] * INV_4PI
            seen = abs(ex * normal[t, 0] + ey * normal[t, 1] + ez * normal[t, 2]) / d + 0.25 * (1.0 - flat)
            out[t, k] = p * area[t] * seen / (d2 + radius[t] * radius[t])
            s += out[t, k]
        acc = 0.0
        for k in range(n_k):
            share = (cl_up[k] + cl_down[k] + cl_iso[k]) / total_w if total_w > 0.0 else 1.0 / n_k
            acc += (1.0 - FLOOR) * (out[t, k] / s if s > 0.0 else share) + FLOOR * share
            out[t, k] = acc
        for k in range(n_k):
            out[t, k] /= acc
    return out


@njit(nogil=True, no_cfunc_wrapper=True, cache=True, _nrt=False)
def gather_batch(scene, nee, organs, batch, store, cdf, draws, out, photon, stats):
    """One batch's gather (``draws``: :class:`~kernel.records.GatherDraws`): ``samples[j]`` draws for each target
    ``targets[j]`` (index into ``nee.targets``), from the stored vertices of this batch; deposits added to
    ``out.tally`` (rows, B); each draw that reaches its target written to ``out.starts`` (START_W + B columns) to
    continue from there (:class:`~kernel.records.GatherOut`).  Returns the number of starts.

    ``store`` = (vpl (n, VPL_W + B), order (n,): the vertices by batch and cluster, cell_start (S, K + 1): their
    range per batch and cluster in ``order``, cell_cum (n,): each one's cumulative mean weight within its cell,
    ending at 1, cell_w (S, K): the cells' mean-weight sums, mean_w (n,)).  ``cdf`` (T, K): :func:`cluster_cdf`.
    Target j's draws use the random stream (seed, batch · T + j): the same on any number of threads.

    ``image_draws`` vertices of the batch, drawn in proportion to their light, each make one next event through a
    mirror (:func:`kernel.images.image_event`, ``nee.mirrors.picks`` 1), weighted by the inverse of that
    probability: the light the chamber sends the organs by its mirrors, as every vertex's image events estimate it
    in the full kernel (a stored segment leaving a mirror is then counted only where they do not cover it).

    A target with an organ zone (a bud, ``organs.zones.weight`` > 0) also gets ``zone_samples[j]`` two-step events
    through its zone from vertices drawn the same way (:func:`kernel.organ_zones.zone_event_to`): the light the
    leaf and stem beside it send it, as every vertex's organ zone events estimate it in the full kernel; a path
    that reaches the zone straight from a stored vertex skips it then, as there (:func:`kernel.nee.zone_served`)."""
    geo, mat, emitters, sens = scene
    targets, samples, zone_samples, image_draws, seed = draws
    tally, starts = out
    tgt = nee.targets
    vpl, order, cell_start, cell_cum, cell_w, mean_w, batch_cum = store
    state, out_k, out_w, leg = photon.state, photon.out_k, photon.out_w, photon.leg
    n_t, n_k = cdf.shape
    n_bands = tally.shape[1]
    n_starts = 0
    for j in range(targets.shape[0]):
        t = targets[j]
        seed_stream(state, seed, batch * n_t + j)
        row_cdf = cdf[j]
        n_direct = samples[j]
        n_zone = zone_samples[j] if organs is not None and organs.zones.weight[t] > 0.0 else 0
        for draw in range(n_direct + n_zone):
            u = uniform(state)
            k = search_cdf(row_cdf, 0, n_k - 1, u)
            q = row_cdf[k] - (row_cdf[k - 1] if k > 0 else 0.0)
            lo, hi = cell_start[batch, k], cell_start[batch, k + 1]
            u1, u2, u3, uv = uniform(state), uniform(state), uniform(state), uniform(state)
            if hi <= lo or not q > 0.0 or not cell_w[batch, k] > 0.0:
                continue              # no light in this cell of this batch
            i = order[search_cdf(cell_cum, lo, hi - 1, uv)]
            if not mean_w[i] > 0.0:
                continue
            r = vpl[i]
            v = Vertex(r[0], r[1], r[2], r[3], r[4], r[5], np.int64(r[6]), np.int64(r[7]), r[8], np.int64(r[9]))
            if draw >= n_direct:      # a two-step event through t's zone
                for b in range(n_bands):
                    photon.w[b] = r[VPL_W + b]
                n_out = zone_event_to(v, (t, n_zone * q * mean_w[i] / cell_w[batch, k], 1.0), mat.max_depth,
                                      np.int64(r[10]), geo, mat, sens, tgt, organs, photon, stats, 0)
                for a in range(n_out):
                    for b in range(n_bands):
                        tally[out_k[a], b] += out_w[a, b]
                continue
            ex, ey, ez = r[0] - tgt.center[t, 0], r[1] - tgt.center[t, 1], r[2] - tgt.center[t, 2]
            tscale = cell_w[batch, k] / (n_direct * q * mean_w[i])
            n_out = target_event(v, (t, ex * ex + ey * ey + ez * ez, tscale), r[VPL_W:], (u1, u2, u3),
                                 np.int64(r[10]), geo, mat, sens, tgt, photon, stats, 0)
            for a in range(n_out):
                for b in range(n_bands):
                    tally[out_k[a], b] += out_w[a, b]
            if n_out > 0 and out_k[0] == tgt.row[t]:     # the organ was reached: the path goes on from there
                s = starts[n_starts]
                for c in range(6):
                    s[c] = leg[c]
                s[6], s[7], s[8], s[9] = r[0], r[1], r[2], 1.0
                s[10], s[11], s[12], s[13] = -1.0, 0.0, 0.0, 0.0
                for b in range(n_bands):
                    s[START_W + b] = out_w[0, b]
                n_starts += 1
    mir = nee.mirrors
    lo, hi = cell_start[batch, 0], cell_start[batch, n_k]
    w_batch = 0.0
    for k in range(n_k):
        w_batch += cell_w[batch, k]
    if image_draws > 0 and mir.plane.shape[0] > 0 and hi > lo and w_batch > 0.0:
        stat0 = np.int64(mat.prob.shape[0] + tgt.from_emitter.shape[0])
        seed_stream(state, seed ^ IMAGE_STREAM, batch)
        for _ in range(image_draws):
            i = order[search_cdf(batch_cum, lo, hi - 1, uniform(state))]
            if not mean_w[i] > 0.0:
                continue
            r = vpl[i]
            scale = w_batch / (image_draws * mean_w[i])
            for b in range(n_bands):
                photon.w[b] = r[VPL_W + b] * scale
            v = Vertex(r[0], r[1], r[2], r[3], r[4], r[5], np.int64(r[6]), np.int64(r[7]), r[8], np.int64(r[9]))
            n_out = image_event(v, 1, stat0, geo, mat, sens, tgt, mir, organs, photon, stats)
            for a in range(n_out):
                for b in range(n_bands):
                    tally[out_k[a], b] += out_w[a, b]
    return n_starts


#: the random streams of a batch's image draws: (seed ^ IMAGE_STREAM, batch)
IMAGE_STREAM = 0x1A6E5


def no_isotropic(modes) -> np.ndarray:
    """(n,) bool: stored vertices that leave by a normal (surfaces, Lambertian lamps), not isotropically."""
    return np.asarray(modes) != V_ISOTROPIC
