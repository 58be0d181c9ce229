"""Memory: a run that cannot fit is refused before it allocates anything large (:func:`check_memory`)."""
from __future__ import annotations

import os

from ..errors import ResourceError
from ..kernel.tallies import N_COUNTERS

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
