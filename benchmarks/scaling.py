"""Beyond one machine: photons/s against Dask workers, the cost of a task, and a sweep's runs per hour.

Prints, on a ``LocalCluster`` of this machine (127.0.0.1):

1. photons/s of the Angers chamber against workers (1, 2 worker processes of 1 thread) beside a
   local run with as many threads, same photons and seed (the numbers are bitwise the same);
2. the cost of one task: tasks of 1 photon on 1 worker (scheduling, transfer, the client's merge),
   tasks of growing chunks (efficiency = tracing time / wall time per task), the smallest chunk
   that keeps the overhead under 5 %, the scene's first build on a worker (registration, the
   Embree build, the worker's first task with its imports), and the client's merge per chunk
   (bytes and time for 1 band, 12 bands, and 12 bands with 500 organs);
3. a sweep's runs per hour: ``angers`` runs of ``--sweep-photons`` photons, seeds 1..``--sweep-runs``,
   on a local pool of 2 processes and on ``--dask local:2``; with ``--grow STEPS`` (needs L-Py),
   also ``lsystems/rose.lpy`` grown STEPS steps.

    .venv/bin/python benchmarks/scaling.py [--photons 2e6] [--repeats 3] [--estimators weighted,nee]
                                           [--sweep-runs 4] [--sweep-photons 1e6] [--grow 10] [--json F]

Wall-clock times (the workers are other processes); on a shared 2-core machine they are noisy:
runs are interleaved and repeated, best and median printed.  docs/scaling.md has the figures
and projects them to 100 workers.
"""
from __future__ import annotations

import argparse
import json
import os
import pickle
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from lpy_light.run import cluster, simulate, sweep
from lpy_light.cli import resolve_scene
from lpy_light.chamber.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
CHUNK = simulate.CHUNK


def kernel_scene(name, estimator):
    ks = simulate.KernelScene(load_scene(resolve_scene(name)), estimator)
    if estimator == "nee":
        ks.prune_next_events(threads=1)
    return ks


def best_median(values):
    return max(values), statistics.median(values)


# ------------------------------------------------------------------------------------------
def rates(args, out):
    """photons/s: local threads against Dask workers of 1 thread, interleaved."""
    print("1. photons/s, %s, %.3g photons, best / median of %d (wall)" % (args.scene, args.photons, args.repeats))
    out["rates"] = {}
    for workers in (1, 2):
        with cluster.dask_client("local:%d" % workers, threads=1) as client:
            client.wait_for_workers(workers)
            for est in args.estimators:
                ks = kernel_scene(args.scene, est)
                simulate.run(ks, 2 * CHUNK, seed=1, executor=cluster.DaskChunks(client))     # warm the workers
                simulate.run(ks, 2 * CHUNK, seed=1, threads=workers)
                local, dask, per_task = [], [], None
                for _ in range(args.repeats):
                    r = simulate.run(ks, int(args.photons), seed=5, threads=workers)
                    local.append(r.photons / r.seconds)
                    d = simulate.run(ks, int(args.photons), seed=5, executor=cluster.DaskChunks(client))
                    dask.append(d.photons / d.seconds)
                    per_task = d.extra["dask"]["chunks_per_task"]
                    assert np.array_equal(r.tally, d.tally)          # bitwise the same numbers
                (lb, lm), (db, dm) = best_median(local), best_median(dask)
                print("   %-8s %d worker(s): local threads %.3g / %.3g, Dask %.3g / %.3g photons/s "
                      "(Dask / local %.2f / %.2f; %d chunks per task)" % (est, workers, lb, lm, db, dm, db / lb,
                                                                          dm / lm, per_task))
                out["rates"]["%s_%d" % (est, workers)] = {"local": [lb, lm], "dask": [db, dm], "chunks_per_task": per_task}


def _timed_trace(digest, n, reps, repeats):
    """On a worker: the best of ``repeats`` mean times of ``reps`` chunks of ``n`` photons (s)."""
    kscene = cluster.worker_scene(digest)
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        for k in range(reps):
            kscene.trace(1, k * n, n)
        best = min(best, (time.perf_counter() - start) / reps)
    return best


def task_costs(args, out):
    """Per-task overhead on 1 worker of 1 thread, chunk efficiency, first build, merge per chunk."""
    print("2. the cost of a task (1 worker, 1 thread, %s weighted)" % args.scene)
    ks = kernel_scene(args.scene, "weighted")
    sizes = [1, 2048, 8192, CHUNK, 4 * CHUNK]
    # a fresh cluster: the first task pays the worker's imports and the scene's build
    start = time.perf_counter()
    with cluster.dask_client("local:1", threads=1) as client:
        client.wait_for_workers(1)
        up = time.perf_counter() - start
        ex = cluster.DaskChunks(client, chunks_per_task=1)
        start = time.perf_counter()
        ex.open(ks, 1)
        registered = time.perf_counter() - start
        start = time.perf_counter()
        ex.submit(1, [(0, 1)]).result()
        first = time.perf_counter() - start
        build = [s for builds in client.run(cluster.build_seconds).values() for _, s in builds]
        trace = {}
        for n in sizes:                                 # tracing alone, on the worker, one chunk after another
            reps = max(3, min(200, int(2e6 // max(n, 1))))
            trace[n] = client.submit(_timed_trace, ex.digest, n, reps, args.repeats, pure=False).result()
        t_photon = trace[CHUNK] / CHUNK
        wall = {}
        for n in sizes:
            K = max(20, min(300, int(4e6 // max(n, 1))))
            w = []
            for r in range(args.repeats):
                pending, start = [], time.perf_counter()
                for k in range(K):                      # as simulate.run: 2 tasks in flight per thread
                    pending.append(ex.submit(1, [(k * n, n)]))
                    if len(pending) >= 2:
                        pending.pop(0).result()
                for f in pending:
                    f.result()
                w.append((time.perf_counter() - start) / K)
            wall[n] = min(w)
        warm = wall[1]
        ex.close()
    overhead = wall[1] - trace[1]
    out["trace_seconds"] = trace
    print("   cluster start %.2f s; scene registered on the workers in %.3f s; Embree build on a worker %.3f s; "
          "first task on a fresh worker %.2f s (its imports), a warm 1-photon task %.2f ms"
          % (up, registered, max(build), first, 1e3 * warm))
    print("   per-task overhead (1-photon tasks, wall per task minus tracing): %.2f ms; tracing %.3f µs/photon"
          % (1e3 * overhead, 1e6 * t_photon))
    for n in sizes[1:]:
        print("   chunk %7d photons: tracing %.2f ms (on the worker), wall per task %.2f ms, efficiency %.1f %% "
              "(%.1f %% from the overhead)" % (n, 1e3 * trace[n], 1e3 * wall[n], 100 * trace[n] / wall[n],
                                              100 * trace[n] / (trace[n] + overhead)))
    smallest = overhead / (0.05 * t_photon)
    print("   smallest chunk with overhead < 5 %%: %.3g photons (= overhead / (0.05 x tracing time per photon)); "
          "CHUNK = %d" % (smallest, CHUNK))
    out["task"] = {"cluster_start": up, "register": registered, "build": max(build), "first_task": first,
                   "overhead": overhead, "t_photon": t_photon, "wall": wall, "smallest_chunk_5pct": smallest}
    # the client's share: one chunk's tallies arrive (deserialised) and are added to the sums
    print("   the client's merge, per chunk:")
    out["merge"] = {}
    for label, rows, bands in (("angers, 1 band", None, 1), ("angers-12bands", None, 12),
                               ("12 bands + 500 organs", 240 + 2 * 500 + 20, 12)):
        if rows is None:
            kk = kernel_scene("angers" if bands == 1 else "angers-12bands", "weighted")
            part = kk.trace(1, 0, 1000)
        else:
            part = (np.random.rand(rows, bands), np.random.rand(rows, bands, bands), np.zeros(8, np.int64),
                    np.zeros((40, 3)))
        acc = [np.zeros_like(p) for p in part]
        blob = pickle.dumps(part, protocol=5)
        reps = 200
        start = time.perf_counter()
        for _ in range(reps):
            acc = [a + p for a, p in zip(acc, pickle.loads(blob))]
        t = (time.perf_counter() - start) / reps
        print("     %-22s %8.0f kB, %.3f ms (deserialise + add)" % (label, len(blob) / 1e3, 1e3 * t))
        out["merge"][label] = {"bytes": len(blob), "seconds": t}


def sweeps(args, out):
    print("3. a sweep's runs per hour: %s --photons %.3g, %d seeds" % (args.scene, args.sweep_photons, args.sweep_runs))
    out["sweep"] = {}
    jobs = [("runs", [args.scene], ["seed=1..%d" % args.sweep_runs], ["--photons", "%d" % args.sweep_photons])]
    if args.grow:
        try:
            import openalea.lpy  # noqa: F401
            jobs.append(("rose", [str(ROOT / "lsystems" / "rose.lpy")], ["SEED=1..%d" % args.sweep_runs],
                         ["--steps", str(args.grow), "--photons", "%d" % args.grow_photons]))
        except ImportError:
            print("   (--grow: L-Py not importable here; no growth sweep)")
    for label, inputs, sets, extra in jobs:
        for where in ("local", "dask"):
            with tempfile.TemporaryDirectory() as tmp:
                tasks = sweep.tasks_for(inputs, sets, extra)
                start = time.perf_counter()
                if where == "local":
                    code = sweep.run_sweep(tasks, Path(tmp) / "s", workers=2)
                else:
                    with cluster.dask_client("local:2", threads=1) as client:
                        code = sweep.run_sweep(tasks, Path(tmp) / "s", client=client)
                wall = time.perf_counter() - start
            assert code == 0, [t.message for t in tasks]
            per_run = statistics.median(t.seconds for t in tasks)
            print("   %-5s %-5s %d runs in %.1f s: %.0f runs/hour (a run: %.1f s, median; 2 at once)"
                  % (label, where, len(tasks), wall, 3600 * len(tasks) / wall, per_run))
            out["sweep"]["%s_%s" % (label, where)] = {"runs": len(tasks), "seconds": wall, "per_run": per_run}


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scene", default="angers")
    p.add_argument("--photons", type=float, default=2e6)
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--estimators", default="weighted,nee")
    p.add_argument("--sweep-runs", type=int, default=4)
    p.add_argument("--sweep-photons", type=float, default=1e6)
    p.add_argument("--grow", type=int, default=0, metavar="STEPS", help="also sweep rose.lpy (needs L-Py)")
    p.add_argument("--grow-photons", type=float, default=1e5)
    p.add_argument("--parts", default="rates,task,sweep")
    p.add_argument("--json", default=None, help="write the figures here")
    args = p.parse_args()
    args.estimators = args.estimators.split(",")
    print("%d cores, Python %s, load average %.1f" % (os.cpu_count(), sys.version.split()[0], os.getloadavg()[0]))
    out = {"args": vars(args)}
    parts = args.parts.split(",")
    if "rates" in parts:
        rates(args, out)
    if "task" in parts:
        task_costs(args, out)
    if "sweep" in parts:
        sweeps(args, out)
    if args.json:
        Path(args.json).write_text(json.dumps(out, indent=1, default=float) + "\n")


if __name__ == "__main__":
    main()
