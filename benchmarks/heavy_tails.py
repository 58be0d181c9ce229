"""Heavy tails on the Angers sensors: σ²·N against N, and the chunks where a sensor's sum jumps.

An estimator without a heavy tail has σ²·N (relative variance times photons) constant in N.  This traces
``--photons`` photons of ``run angers`` (``nee``, the CLI's pruning) chunk by chunk (``simulate.CHUNK``
photons each, the same chunks as any run of that seed), and prints

* per sensor, σ²·N from the first N photons for N = 1e6, 4e6, 1.6e7 ... (σ from the chunks' sums of
  squares, as ``Result`` does): the median and the sensors where it grows most from the first N to the last;
* for those sensors, the chunks whose sum is largest against the sensor's mean per chunk: a jump of about
  one photon's weight (1.0 in these units) is a single deposit of a whole photon -- a counted crossing,
  not a next event.

Measured (2026-11-24, 1.6e7 photons, seed 1): median σ²·N 34 at every N, but 48 of the 240 sensors above
200 at 1.6e7 (sensor 43: 12.6 at 1e6, 13.0 at 4e6, 457 at 1.6e7), each jump +1.0 in one chunk.  Printing
the counted crossings of weight > 0.3 from the kernel (a temporary ``print`` after the crossing's
``record`` in ``kernel/trace.py``) showed where they come from: photons that reach the sensor straight
after *two or more* specular reflections -- between the parallel metal walls y = 0 and y = 1840 mm
(MurMetal, 6.5 % specular), or off the aluminium angle (CorniereAlu, 20 % specular) that lies in the
Makrolon's plane at z = 1970 mm.  Image events (``kernel/images.py``) serve one reflection after a
next-event vertex; a second one leaves the segment to counting, with the photon's full weight.

    .venv/bin/python benchmarks/heavy_tails.py [--photons 1.6e7] [--seed 1] [--show 8]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from lpy_light.run import simulate
from lpy_light.chamber.scene import load_scene, resolve_scene


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default="angers")
    ap.add_argument("--photons", type=float, default=1.6e7)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--show", type=int, default=8, help="sensors shown with their largest chunks")
    ap.add_argument("--sensors", type=int, nargs="*", default=[], help="sensors whose σ²·N is printed")
    ap.add_argument("--worst", type=int, default=0, help="the sensors of largest σ²·N at the last N printed")
    args = ap.parse_args()
    chamber = load_scene(resolve_scene(args.scene))
    ks = simulate.KernelScene(chamber, estimator="nee")
    report = ks.prune_next_events()
    print("switched off:", ", ".join(report.get("off", [])) or "none")
    records = ks.records()
    n_sens, chunk = ks.n_sensors, simulate.CHUNK
    n_chunks = int(args.photons) // chunk
    sums = np.zeros((n_chunks, n_sens))
    sq = np.zeros((n_chunks, n_sens))
    t0 = time.perf_counter()
    for c in range(n_chunks):
        tally, tally_sq, counters, _ = ks.trace(args.seed, c * chunk, chunk, records)
        sums[c], sq[c] = tally[:n_sens, 0], tally_sq[:n_sens, 0, 0]
    print("%d photons in %d chunks, %.1f s" % (n_chunks * chunk, n_chunks, time.perf_counter() - t0))

    def sigma2n(k):
        """σ²·N (relative) of each sensor from the first k chunks: the products are per batch of
        ``settings.batch`` photons (the control variate's), so N / (batches − 1) · (Q − T² / N) as ``Result``."""
        n = k * chunk
        batches = n / max(ks.settings.batch, 1)
        t, s = sums[:k].sum(axis=0), sq[:k].sum(axis=0)
        var = n / (batches - 1.0) * np.maximum(s - t * t / n, 0.0)
        return var / np.maximum(t, 1e-300) ** 2 * n

    marks = [k for k in (int(1e6) // chunk, int(4e6) // chunk, int(1.6e7) // chunk, int(6.4e7) // chunk) if 2 <= k <= n_chunks]
    if not marks or marks[-1] != n_chunks:
        marks.append(n_chunks)
    table = np.array([sigma2n(k) for k in marks])
    print("N:            " + "  ".join("%9.2g" % (k * chunk) for k in marks))
    print("median σ²·N:  " + "  ".join("%9.1f" % np.median(row) for row in table))
    print("mean σ²·N:    " + "  ".join("%9.1f" % row.mean() for row in table))
    print("max σ²·N:     " + "  ".join("%9.1f" % row.max() for row in table))
    print("p90 σ²·N:     " + "  ".join("%9.1f" % np.percentile(row, 90) for row in table))
    print("sensors > 200:" + "  ".join("%9d" % (row > 200).sum() for row in table))
    for s in args.sensors:
        print("sensor %3d:   " % s + "  ".join("%9.1f" % row[s] for row in table))
    if args.worst:
        order = np.argsort(table[-1])[::-1][:args.worst]
        print("largest σ²·N at the last N: " + ", ".join("%d %s %.0f" % (s, np.array2string(np.asarray(chamber.sensors.center[s]), precision=0), table[-1, s]) for s in order))
    growth = table[-1] / np.maximum(table[0], 1e-300)
    pos = chamber.sensors.center if hasattr(chamber.sensors, "center") else None
    print("\nsensors whose σ²·N grows most (first N -> last), with their largest chunk sums against the mean:")
    for s in np.argsort(growth)[::-1][:args.show]:
        top = np.argsort(sums[:, s])[::-1][:3]
        where = "" if pos is None else " at %s" % np.array2string(np.asarray(pos[s]), precision=0)
        print("  sensor %3d%s: σ²·N %s  (x%.1f); mean chunk %.3f, largest %s" % (
            s, where, " ".join("%.0f" % v for v in table[:, s]), growth[s], sums[:, s].mean(),
            ", ".join("chunk %d: %.3f" % (c, sums[c, s]) for c in top)))


if __name__ == "__main__":
    main()
