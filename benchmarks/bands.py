"""Twelve bands in one pass: what do they cost against one band?

Traces the Angers chamber with SEC2's 12 bands (``angers-12bands``) and with its
one band (``angers``, 655-665 nm): same photons, same seed, same estimator
(``weighted`` and ``nee``), runs interleaved and repeated; prints the time per
photon (best and median of the repeats), rays per photon, the 12-band / 1-band
cost ratio (target ≤ 1.3×), and the precision per band (median relative σ over
the 240 sensors) of the 12-band run against the 1-band run.

    .venv/bin/python benchmarks/bands.py [--photons 1e6] [--repeats 5] [--threads 1]
                                         [--estimators weighted,nee] [--csv runs/bands.csv]

One thread and process CPU time by default: the ratio is what matters, and CPU
time is steadier than wall time on a shared machine (``--clock wall`` for wall time).

Measured (2-core shared VM, 1e6 photons, 5 repeats, CPU time): weighted 1.25x, nee 1.21-1.22x
before the control variate; on 2026-11-23 weighted 1.15-1.32x, nee 2.0-2.1x (the control variate's γ
deposits and band products on all 240 sensors at every vertex; 1.19x without it, at 8x its σ²·t);
rays per photon rise 3.5% (q = max over bands of the scattering probability keeps a photon alive
while its brightest band would scatter), the rest is the per-event band work (B weights copied, B²
products per tally event for the covariances).  Computing only the upper triangle of the B²
products was tried and was slower (1.46x): the variable-start inner loop stops numba vectorising.
Fifth session (the photon loop without reference counting, 1 thread): weighted 0.526 / 0.639 µs per
photon, 1.21-1.24x; nee 2.21 / 5.25 µs, 2.23-2.37x (both runs faster, the one-band run more: the 12-band
cost is in the control variate's arithmetic, which reference counting did not touch).
Then the control variate's products per batch of 8 photons (batch means): nee 2.25 / 3.51 µs, 1.56-1.61x.
"""
import argparse
import csv
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from lpy_light.run import simulate
from lpy_light.chamber.scene import resolve_scene
from lpy_light.chamber.scene import load_scene

SCENES = {"1 band": "angers", "12 bands": "angers-12bands"}


def kernel_scenes(estimator, threads):
    out = {}
    for label, name in SCENES.items():
        ks = simulate.KernelScene(load_scene(resolve_scene(name)), estimator=estimator)
        if estimator == "nee":
            ks.prune_next_events(threads=threads)
        simulate.run(ks, 2 * simulate.CHUNK, seed=1, threads=threads)     # compile, warm caches
        out[label] = ks
    return out


def median_rel_sigma(result):
    p, s = result.sensors()
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.where(p > 0, s / p, np.nan)
    return np.nanmedian(rel, axis=0)        # (B,)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--photons", type=float, default=1e6)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--estimators", default="weighted,nee")
    ap.add_argument("--clock", choices=("cpu", "wall"), default="cpu",
                    help="cpu (default: process CPU time, steady on a shared machine) or wall time")
    ap.add_argument("--csv", default=None, help="write one row per run")
    args = ap.parse_args(argv)
    n = int(args.photons)
    rows = []
    print("Angers chamber, %d photons per run, %d repeats, %d thread(s), %s time"
          % (n, args.repeats, args.threads, args.clock))
    for est in args.estimators.split(","):
        scenes = kernel_scenes(est, args.threads)
        times = {k: [] for k in scenes}
        last = {}
        for rep in range(args.repeats):
            for label, ks in scenes.items():      # interleaved: drifts in machine load hit both alike
                cpu = time.process_time()
                res = simulate.run(ks, n, seed=11, threads=args.threads)
                cpu = time.process_time() - cpu
                times[label].append((cpu if args.clock == "cpu" else res.seconds) / res.photons)
                last[label] = res
                rows.append({"estimator": est, "scene": SCENES[label], "bands": ks.n_bands, "repeat": rep,
                             "photons": res.photons, "seconds": res.seconds, "cpu_seconds": cpu, "rays": res.rays,
                             "shadow_rays": int(res.counters[4])})
        print("\nestimator %s" % est)
        print("  %-9s %12s %12s %10s %12s" % ("", "best µs/ph", "median µs/ph", "rays/ph", "shadow/ph"))
        for label, t in times.items():
            r = last[label]
            print("  %-9s %12.3f %12.3f %10.3f %12.3f" % (label, 1e6 * min(t), 1e6 * statistics.median(t),
                                                          r.rays / r.photons, r.counters[4] / r.photons))
        best = min(times["12 bands"]) / min(times["1 band"])
        med = statistics.median(times["12 bands"]) / statistics.median(times["1 band"])
        per_ray = ((min(times["12 bands"]) / (last["12 bands"].rays / n))
                   / (min(times["1 band"]) / (last["1 band"].rays / n)))
        print("  cost ratio 12 bands / 1 band: best %.2fx, median %.2fx (target <= 1.3x); per ray traced %.2fx"
              % (best, med, per_ray))
        one = median_rel_sigma(last["1 band"])[0]
        many = median_rel_sigma(last["12 bands"])
        labels = last["12 bands"].n_sensors and scenes["12 bands"].chamber.band_labels
        print("  precision per band (median relative σ over the sensors, %d photons):" % n)
        for b, label in enumerate(labels):
            mark = "   <- 1-band run: %.3f%%" % (100 * one) if label == "655-665" else ""
            print("    %-8s %6.3f%%%s" % (label, 100 * many[b], mark))
    if args.csv:
        Path(args.csv).parent.mkdir(parents=True, exist_ok=True)
        with open(args.csv, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
