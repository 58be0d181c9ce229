"""Targets drawn by importance as seen from a vertex, over clusters of targets.

A next event from vertex v picks a few of the n targets (:func:`kernel.nee.next_event`); drawn uniformly, a bud
gets as few picks from the leaf right above it as from a wall across the chamber, and each deposit is scaled
by n / picks: rare, large deposits.  Drawn in proportion to an importance I_t = weight_t / max(d², a²)
(d from v to t's centre, a a floor radius) -- about the solid angle t subtends per unit of its area, i.e. its
share of v's light relative to its own total -- each target's picks come from the vertices that light it
most.  Summing I_t over all n targets at every vertex would cost O(n) (a canopy holds thousands of organs),
so targets are grouped in clusters (:func:`kernel.targets.target_clusters`, ~√n of ~√n targets): a cluster
farther than :data:`CLUSTER_NEAR` of its radii from v counts as its total weight / d², a nearer one as the
exact sum of its targets'; a pick draws a cluster, then one of its targets by their exact importances.  The
probability of the target drawn is known exactly either way, and the deposit is divided by it: unbiased.

Lengths in scene units; importances in 1 / length² (only their ratios matter).
"""
from .jit import helper
from .sampling import search_cdf

CLUSTER_NEAR = 1.0   # within this many of its radii from a cluster's centre, its targets' importances are summed
                     # (2.0: the same σ on the rose, 8 % slower; the farther ones count as their total / d²)


@helper
def _importance(t, v, how, tgt, far):
    """Target t's importance from point v, ``how`` = (weight (n,), far clusters' weight sums (K,), floor2 (n,),
    scale, excl, far weight (n,)): ``weight[t] / max(scale · d², floor2[t])`` (``far``: t's cluster is far from
    v, with ``how[5]`` as weights), 0 if ``excl`` and v is within t's near radius (``tgt.near_r2``: served by an
    own event)."""
    weight, _, floor2, scale, excl, far_weight = how
    if far:
        weight = far_weight
    ex, ey, ez = v[0] - tgt.center[t, 0], v[1] - tgt.center[t, 1], v[2] - tgt.center[t, 2]
    d2 = ex * ex + ey * ey + ez * ez
    if excl and d2 < tgt.near_r2[t]:
        return 0.0
    return weight[t] / max(scale * d2, floor2[t])


@helper
def cluster_cdf(v, how, cl, tgt, cdf, exact):
    """Cumulative importances of the clusters ``cl`` (:class:`~kernel.records.Clusters`) seen from v into
    ``cdf[n : n + K]`` (n targets, K clusters); returns their sum.  A cluster within :data:`CLUSTER_NEAR`
    radii of v counts the exact sum of its targets' importances (:func:`_importance`, cumulated into ``cdf``
    at their positions in ``cl.member``; ``exact[k]`` = 1), a farther one the sum of its targets' far weights
    ``how[1][k] / (scale · d²)`` (``exact[k]`` = 0; targets with far weight 0 are served by :mod:`kernel.cones`
    from there)."""
    n = tgt.kind.shape[0]
    scale = how[3]
    total = 0.0
    for k in range(cl.radius.shape[0]):
        ex, ey, ez = v[0] - cl.center[k, 0], v[1] - cl.center[k, 1], v[2] - cl.center[k, 2]
        d2 = ex * ex + ey * ey + ez * ez
        r = CLUSTER_NEAR * cl.radius[k]
        if d2 < r * r:
            s = 0.0
            for j in range(cl.start[k], cl.start[k + 1]):
                s += _importance(cl.member[j], v, how, tgt, False)
                cdf[j] = s
            exact[k] = 1
        else:
            s = how[1][k] / (scale * d2)
            exact[k] = 0
        total += s
        cdf[n + k] = total
    return total


@helper
def draw(u1, u2, total, v, how, cl, tgt, cdf, exact):
    """One target drawn from the importances :func:`cluster_cdf` left in ``cdf`` (their sum ``total``), from two
    uniforms: ``(t, probability)``; (-1, 0) if the cluster drawn has no target of positive importance."""
    n = tgt.kind.shape[0]
    k = search_cdf(cdf, n, n + cl.radius.shape[0] - 1, u1 * total) - n
    p_k = (cdf[n + k] - (cdf[n + k - 1] if k > 0 else 0.0)) / total
    a, b = cl.start[k], cl.start[k + 1]
    if exact[k] == 0:          # a far cluster: its targets' importances, now (kept for the vertex's other picks)
        s = 0.0
        for j in range(a, b):
            s += _importance(cl.member[j], v, how, tgt, True)
            cdf[j] = s
        exact[k] = 1
    s = cdf[b - 1]
    if not (s > 0.0 and p_k > 0.0):
        return -1, 0.0
    j = search_cdf(cdf, a, b - 1, u2 * s)
    p_t = (cdf[j] - (cdf[j - 1] if j > a else 0.0)) / s
    return cl.member[j], p_k * p_t


@helper
def near_cluster(t, vx, vy, vz, organs):
    """Is vertex v within :data:`CLUSTER_NEAR` radii of target t's cluster (its importances summed exactly there:
    :func:`cluster_cdf`)?"""
    cl = organs.clusters
    k = organs.cluster_of[t]
    ex, ey, ez = cl.center[k, 0] - vx, cl.center[k, 1] - vy, cl.center[k, 2] - vz
    r = CLUSTER_NEAR * cl.radius[k]
    return ex * ex + ey * ey + ez * ez < r * r
