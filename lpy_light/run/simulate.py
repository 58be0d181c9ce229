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
import time
from concurrent.futures import ThreadPoolExecutor
import numpy as np

from ..errors import InputError
from ..estimators.kernel_scene import (CHUNK, CONE_RAYS, CONE_TARGETS, LOCAL_RAYS, PICK_PILOT, PICK_SEED, ZONES_CLOSED,
                                       ZONES_OPEN, KernelScene, compile_kernel, cones_for, local_for, organ_zone_rate)
from ..estimators.memory import check_memory, memory_estimate
from ..estimators.result import Result, effective_samples, relative_sigma
from ..kernel.tallies import N_COUNTERS

#: what ``from lpy_light.run import simulate`` offers: the run loop, and the kernel scene and memory check it runs
__all__ = ["CHUNK", "MAX_SEED", "MAX_THREADS", "KernelScene", "LocalThreads", "Result", "run", "default_threads",
           "effective_samples", "relative_sigma", "progress_printer", "compile_kernel", "check_memory",
           "memory_estimate", "cones_for", "local_for", "organ_zone_rate", "CONE_RAYS", "CONE_TARGETS", "LOCAL_RAYS",
           "PICK_PILOT", "PICK_SEED", "ZONES_CLOSED", "ZONES_OPEN"]

MAX_THREADS = 1024
MAX_SEED = 2 ** 63 - 1

def default_threads() -> int:
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1))


class LocalThreads:
    """Chunks traced by a pool of threads in this process: :func:`run`'s default executor.

    An executor of :func:`run` is where chunks are traced, and only that; the merge in chunk
    order, ``precision``, ``progress`` and interrupts are :func:`run`'s, whatever the executor.
    Its methods:

    * ``open(kscene, n_chunks, note=None) -> slots``: get ready to trace ``kscene`` (``note(text)``: said once
      if the kernel compiles for it); ``slots`` is how many
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
    :class:`lpy_light.run.cluster.DaskChunks` is the other one: chunks as tasks on a Dask cluster.
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
    default, with ``threads``; :class:`lpy_light.run.cluster.DaskChunks` on a Dask
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
    # the control variate's products are taken per batch of settings.batch photons (kernel.control.control_products);
    # a run too short for 64 batches takes them per photon, so that its σ rests on enough samples
    batch = kscene.settings.batch
    if photons < 64 * batch:
        kscene.configure(batch=1)
    slots = 1
    pending = []
    try:
        try:
            # after the batch is set: an executor may copy the scene; LocalThreads compiles the kernel (first run only)
            note = getattr(progress, "note", None)
            slots = executor.open(kscene, n_chunks, note)
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
        if kscene.settings.batch != batch:
            kscene.configure(batch=batch)
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
