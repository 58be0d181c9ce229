"""The ray log: every ray the kernel casts, with its kind, for casting them again without the kernel.

``benchmarks/raw_embree.py`` measures what a ray costs in a step against what Embree alone costs for the same
rays: it opens a log (:func:`open_log`), runs a step on one thread, and casts the logged rays again in a bare
loop (no filters, no physics).  While no log is open, a ray costs one load and a branch that is never taken
(:func:`kernel.rays.cast`); the kernel's numbers are the same with or without a log.

A row is 8 float32: origin (3), unit direction (3), ``tfar``, and the ray's kind (:data:`KINDS`), in scene
units.  The log is shared by every scratch block made while it is open (:func:`kernel.embree.new_scratch`), with
one counter and no lock: open it for runs on one thread only.
"""
import numpy as np

#: what a ray is for: its row's last column
RAY_PHOTON = 0      # a photon's flight (rtcIntersect1 on the chamber + plant, sensors crossed)
RAY_SHADOW = 1      # a shadow ray to a sensor's point (rtcOccluded1)
RAY_TARGET = 2      # a next event's ray to a point on an organ or other mesh target, a zone, a mirror (rtcIntersect1)
RAY_FIELD = 3       # a light field's ray or bounce, in its region's scene (rtcIntersect1)
KINDS = {RAY_PHOTON: "photon", RAY_SHADOW: "shadow", RAY_TARGET: "next-event", RAY_FIELD: "field"}
OCCLUDED = (RAY_SHADOW,)         # kinds cast with rtcOccluded1

_open = None        # (rows (cap, 8) float32, count (1,) int64) while a log is open


def open_log(capacity: int):
    """Open a log of at most ``capacity`` rays; scratch blocks made from now on write to it."""
    global _open
    _open = (np.zeros((int(capacity), 8), np.float32), np.zeros(1, np.int64))


def close_log() -> tuple:
    """Close the log; returns its rows (n, 8) float32 (the first ``capacity`` rays if more were cast) and the
    number of rays cast while it was open, as ``(rows, cast)``."""
    global _open
    rows, count = _open
    _open = None
    n = int(count[0])
    return rows[:min(n, len(rows))], n


def attach(fields: np.ndarray):
    """Write the open log's addresses into a scratch block's three log fields (uint64 (3,)); 0: no log."""
    if _open is None:
        fields[:] = 0
        return
    rows, count = _open
    fields[0], fields[1], fields[2] = rows.ctypes.data, count.ctypes.data, len(rows)
