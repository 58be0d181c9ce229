"""The control variate of next events: a cheap guess of every sensor's light at every vertex.

With random picks (``nee`` picks one target per vertex among hundreds), a pick deposits n_targets times
the light of one target, rarely: most of a sensor's variance.  At every next-event vertex v the kernel
therefore deposits γ, each sensor's light as if it were a point at its centre with nothing in the way
(:func:`kernel.nee.point_view`: A · cos θ_c / d² · p(ω), in photons of weight), on every sensor target
(:func:`control_deposits`), and each pick deposits only the difference between the true, occluded value
and γ (:func:`kernel.nee.next_event`) — unbiased, and a pick then carries a small difference.

Every photon then deposits on every sensor: the products between bands are taken per batch of
``Control.batch`` photons instead of per photon (:func:`control_products`, σ from batch means:
:func:`lpy_light.estimators.result.effective_samples`).
"""
import numpy as np

from .jit import helper
from .nee import NEAR_FLOOR, ZERO32, gamma32, view_factors
from .records import DIFFUSE_R, DIFFUSE_T, T_DISC, V_LAMBERT, V_SURFACE, Control, f32, i64


def build_control(targets, sensors, on: bool, batch: int) -> Control:
    """The control variate's arrays (numpy, once per run) from the scene's :class:`~kernel.records.Targets`
    and :class:`~kernel.records.Sensors`: the sensor targets (they come first) in float32, their exclusion
    radii², and their runs of one plane and normal.  ``on``: wanted; it is used only with sensor targets and
    random picks (0 < picks < targets)."""
    n_tgt = len(targets.kind)
    on = bool(on and targets.on_sensors and 0 < targets.picks < n_tgt)
    n = 0
    while on and n < n_tgt and targets.kind[n] <= 1:
        n += 1
    ref = targets.ref[:n]
    center = f32(targets.center[:n].T)
    normal = f32(sensors.normal[ref].T)
    # no control within NEAR_FLOOR radii of a disc: its point value is no approximation there
    floor = NEAR_FLOOR * sensors.radius[ref]
    floor2 = np.where(targets.kind[:n] == T_DISC, floor * floor, 0.0)
    near2 = targets.near2[:n]
    thr = f32(np.stack([np.maximum(near2, floor2), np.maximum(np.maximum(near2, floor2), targets.near_r2[:n])]))
    # runs of targets on one plane with one normal: first, end; the plane's offset n·c (float32 arithmetic)
    offset = normal[0] * center[0] + normal[1] * center[1] + normal[2] * center[2]
    runs, plane = [], []
    for t in range(n):
        if runs and offset[t] == plane[-1] and (normal[:, t] == normal[:, t - 1]).all():
            runs[-1][1] = t + 1
        else:
            runs.append([t, t + 1])
            plane.append(offset[t])
    return Control(on, int(batch), i64(targets.row[:n]), center, normal, f32(targets.area[:n]),
                   thr.reshape(2, n), i64(np.reshape(runs, (-1, 2))), f32(plane))


@helper
def control_deposits(v, w, near, mat, cv, cvw):
    """Add γ (:func:`kernel.nee.point_view`) of every sensor target, seen from vertex ``v``
    (:class:`~kernel.records.Vertex`) with weights ``w`` (B,), to its batch's ``cvw.batch`` (B, c) -- except
    where a pick of :func:`kernel.nee.next_event` would not serve it (inside an exclusion radius, or a near
    disc with an event of its own: ``cv.thr[near]`` holds those radii²).

    Targets come in runs of one plane and normal (``cv.runs``, ``cv.plane``); a run whose plane v is behind
    is skipped whole (γ = 0 there).  Within a run the loop is branch-free so that it vectorises: γ split by
    the side of v it leaves (``cvw.g_r``, ``cvw.g_t``), then one pass per band."""
    mode, m = v.mode, v.material
    g_r, g_t, cv_acc = cvw.g_r, cvw.g_t, cvw.batch
    c0, c1 = view_factors(mode)
    c0, c1 = np.float32(c0), np.float32(c1)
    thr = cv.thr[near]
    cx, cy, cz = cv.center[0], cv.center[1], cv.center[2]
    mx, my, mz = cv.normal[0], cv.normal[1], cv.normal[2]
    area = cv.area
    vx, vy, vz = np.float32(v.x), np.float32(v.y), np.float32(v.z)
    nx, ny, nz = np.float32(v.nx), np.float32(v.ny), np.float32(v.nz)
    for r in range(cv.runs.shape[0]):
        lo, n = cv.runs[r, 0], cv.runs[r, 1] - cv.runs[r, 0]
        if lo < 0 or vx * mx[lo] + vy * my[lo] + vz * mz[lo] <= cv.plane[r]:
            continue
        for i in range(n):          # (indices from 0: no wrap-around test, so the loop vectorises)
            t = lo + i
            g = gamma32((vx, vy, vz), (nx, ny, nz), c0, c1, (cx[t], cy[t], cz[t]), (mx[t], my[t], mz[t]), area[t])
            ex, ey, ez = cx[t] - vx, cy[t] - vy, cz[t] - vz
            ok = (ex * ex + ey * ey + ez * ez >= thr[t]) & (g > ZERO32)
            g = g * np.float32(ok)     # arithmetic, not branches: vectorises
            up = np.float32(ex * nx + ey * ny + ez * nz > ZERO32)
            g_r[t] = g * up
            g_t[t] = g - g * up
        for b in range(w.shape[0]):
            if mode == V_SURFACE:
                a_r, a_t = w[b] * mat.prob[m, DIFFUSE_R, b], w[b] * mat.prob[m, DIFFUSE_T, b]
            elif mode == V_LAMBERT:
                a_r, a_t = w[b], 0.0
            else:
                a_r, a_t = w[b], w[b]
            acc = cv_acc[b]
            for i in range(n):
                t = lo + i
                acc[t] += a_r * g_r[t] + a_t * g_t[t]


@helper
def fold_control(n_rows, accum, cvw, sensor_target, n_sens):
    """End of a photon, with the control variate on: fold its other deposits on the sensor targets' rows
    into its batch's ``cvw.batch`` (B, c), so that the batch's products are taken whole by
    :func:`control_products`; the photon's other rows are left to :func:`kernel.tallies.flush` (those folded
    become -1 in ``accum.rows``).  ``sensor_target`` (S,): each sensor's target, or -1."""
    rows, acc, touched, cv_acc = accum.rows, accum.acc, accum.touched, cvw.batch
    n_bands = acc.shape[1]
    n = cv_acc.shape[1]
    for a in range(n_rows):
        k = rows[a]
        if k < n_sens and sensor_target[k] >= 0 and sensor_target[k] < n:
            t = sensor_target[k]
            for b in range(n_bands):
                cv_acc[b, t] += acc[k, b]
                acc[k, b] = 0.0
            touched[k] = 0
            rows[a] = -1


@helper
def control_products(size, cvw):
    """Add one batch of ``size`` photons -- their summed sensor-target deposits ``cvw.batch`` (B, c) -- to
    the chunk's ``cvw.tally`` (B, c) and ``cvw.sq`` (B, B, c): S_b · S_b2 / size, upper triangle
    b ≤ b2 (:func:`add_control` mirrors it); clear ``cvw.batch``.

    Batch means: with the control variate every photon deposits on all c sensor rows, and products
    between bands per photon (B(B+1)/2 · c of them) cost as much as the rest of a 12-band photon.  Summed
    over batches instead, Q = Σ_j S_j S_jᵀ / m_j satisfies E[Q − T Tᵀ / N] = (n_b − 1) Σ (Σ the covariance
    of one photon, T the total of N photons in n_b batches of m_j photons), so ``Result`` estimates
    the covariance of T as N / (n_b − 1) · (Q − T Tᵀ / N): the per-photon formula with n_b − 1 in place
    of N − 1 (:func:`lpy_light.estimators.result.effective_samples`)."""
    cv_acc, cv_tally, cv_sq = cvw.batch, cvw.tally, cvw.sq
    n_bands, n = cv_acc.shape[0], cv_acc.shape[1]
    inv = 1.0 / size
    for b in range(n_bands):         # contiguous over the targets: vectorises
        x = cv_acc[b]
        tb = cv_tally[b]
        for t in range(n):
            tb[t] += x[t]
        for b2 in range(b, n_bands):
            y = cv_acc[b2]
            sq = cv_sq[b, b2]
            for t in range(n):
                sq[t] += x[t] * y[t] * inv
    for b in range(n_bands):
        x = cv_acc[b]
        for t in range(n):
            x[t] = 0.0


@helper
def add_control(cv, cvw, tallies):
    """End of a chunk: add the sensor targets' sums and batch products to their tally rows."""
    tally, tally_sq = tallies.tally, tallies.tally_sq
    cv_tally, cv_sq = cvw.tally, cvw.sq
    n_bands = tally.shape[1]
    for t in range(cv.row.shape[0]):
        for b in range(n_bands):
            tally[cv.row[t], b] += cv_tally[b, t]
            for b2 in range(n_bands):    # control_products filled b2 >= b (x·y = y·x exactly)
                tally_sq[cv.row[t], b, b2] += cv_sq[min(b, b2), max(b, b2), t]
