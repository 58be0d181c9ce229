"""Tallies: what each photon deposits, summed per row and band, with the products between bands.

A photon's deposits (in photons of weight: it leaves its lamp with weight 1 per band) are summed per tally
row in its own accumulator first (:func:`record`); when it ends they are added to the chunk's sums, and
their products band by band to ``tally_sq`` (:func:`flush`), so that ``tally_sq`` gives the sample
covariance between bands of per-photon contributions (a photon may cross a sensor twice; all bands ride on
the same photons, so a sum of bands such as PAR, or a ratio such as R:FR, needs the covariances for its σ).

Rows (K + M + 4 of them, :class:`kernel.records.Tallies`): S sensor crossings, R receivers' incident
hits, R receivers' absorbed weight, then the photon's fates — absorbed per material (M rows), escaped,
cut at max_depth, lost to numerical failure — and a last row holding each photon's total deposit over the
fates, whose mean is 1 per band: energy closure with its own standard error.
"""
import numpy as np

from .jit import helper
from .ptr import prefetch

# counters
C_RAYS, C_CAND_OVERFLOW, C_SCRATCH_FLUSH, C_LOST, C_SHADOW, C_BATCHES = 0, 1, 2, 3, 4, 5
C_PICK_SHARE, C_PICK_VERTICES = 6, 7     # next events to organs: Σ of the vertices' pick shares, and the vertices
                                          # (kernel.nee.pick_mean; in units of PICK_SHARE_UNIT · pick_unit)
N_COUNTERS = 8


@helper
def fate_rows(tallies, n_materials):
    """First fate row (absorbed in material 0), and the rows escaped, cut, lost."""
    fate0 = tallies.tally.shape[0] - n_materials - 4
    return fate0, fate0 + n_materials, fate0 + n_materials + 1, fate0 + n_materials + 2


@helper
def record(k, w, n_rows, accum):
    """Add weights ``w`` (B,) to this photon's row k (``accum``: :class:`~kernel.records.Accumulator`); returns
    the number of rows the photon has touched."""
    touched, acc = accum.touched, accum.acc
    if touched[k] == 0:
        touched[k] = 1
        accum.rows[n_rows] = k
        n_rows += 1
    for b in range(w.shape[0]):     # explicit loops: slice assignment costs ~15% at 12 bands
        acc[k, b] += w[b]
    return n_rows


@helper
def record_all(n_out, n_rows, photon, accum):
    """:func:`record` the ``n_out`` deposits a next event wrote to ``photon.out_k`` / ``photon.out_w``."""
    for a in range(n_out):
        n_rows = record(photon.out_k[a], photon.out_w[a], n_rows, accum)
    return n_rows


#: rows of ``tally`` and ``tally_sq`` asked ahead of their turn in :func:`flush`: amid a canopy a photon adds to
#: dozens of rows spread over megabytes (16 roses: 16,500 rows of 1.2 kB), and each row's first access missed
#: the caches (~10 % of a 16-rose step)
PREFETCH_ROWS = 3
_LINE = 64


@helper
def prefetch_row(k, base, stride, base_sq, stride_sq):
    """Prefetch row k of ``tally`` and ``tally_sq`` (given by their base addresses and row strides, in bytes)."""
    if k < 0:
        return
    a = base + k * stride
    for off in range(0, stride + _LINE, _LINE):
        prefetch(np.uint64(a + off))
    a = base_sq + k * stride_sq
    for off in range(0, stride_sq + _LINE, _LINE):
        prefetch(np.uint64(a + off))


@helper
def flush(n_rows, fate0, accum, tallies):
    """Add one photon's contributions (its rows of ``accum.acc``, in the order first touched): sums and
    products between bands; clear them for the next photon.

    Rows ``fate0 ..`` are fates; the last row receives the photon's total deposit (closure), summed in
    ``accum.tot`` (B,)."""
    rows, acc, touched, tot = accum.rows, accum.acc, accum.touched, accum.tot
    tally, tally_sq = tallies.tally, tallies.tally_sq
    total_row = tally.shape[0] - 1
    n_bands = acc.shape[1]
    tot[:] = 0.0
    base, base_sq = np.int64(tally.ctypes.data), np.int64(tally_sq.ctypes.data)
    stride, stride_sq = tally.strides[0], tally_sq.strides[0]
    for a in range(min(n_rows, PREFETCH_ROWS)):
        prefetch_row(rows[a], base, stride, base_sq, stride_sq)
    for a in range(n_rows):
        k = rows[a]
        if a + PREFETCH_ROWS < n_rows:
            prefetch_row(rows[a + PREFETCH_ROWS], base, stride, base_sq, stride_sq)
        if k < 0:
            continue
        for b in range(n_bands):
            x = acc[k, b]
            tally[k, b] += x
            for b2 in range(n_bands):
                tally_sq[k, b, b2] += x * acc[k, b2]
            if k >= fate0:
                tot[b] += x
        for b in range(n_bands):
            acc[k, b] = 0.0
        touched[k] = 0
    if n_rows > 0:
        for b in range(n_bands):
            tally[total_row, b] += tot[b]
            for b2 in range(n_bands):
                tally_sq[total_row, b, b2] += tot[b] * tot[b2]
