"""Where the next-event estimator's variance is on the Angers sensors, and the knobs that move it.

Runs the full chamber with ``--estimator nee`` and prints the spread of the sensors' relative σ (median,
rms, 90th percentile, max), the median per row of constant y (the row y = 1830 touches the wall at
y = 1840), then the same with an exclusion radius around each sensor (next events from vertices closer
than R replaced by counted crossings: what the estimator did before discs were drawn by solid angle,
with R = 30 mm), with other near-disc zones (a disc nearer than factor · radius · √targets gets its own
next event instead of a scaled random pick; default factor 1; 0 = none) and with more next events
through mirrors per vertex (default 0.25).  σ²·t (mean relative variance × seconds) is the cost to
compare: lower is better.

    .venv/bin/python benchmarks/nee_variance.py [--photons 3e6] [--radii 30 100] [--near 0 0.5 2] [--images 1 2]
"""
import argparse
import time

import numpy as np

from lpy_light.run import simulate
from lpy_light.report import validation
from lpy_light.kernel.targets import near_discs


def measure(ks, photons, seed=3, threads=2):
    simulate.run(ks, 1000, seed=seed + 1, threads=threads)      # compile / warm up
    t0 = time.perf_counter()
    r = simulate.run(ks, photons, seed=seed, threads=threads)
    seconds = time.perf_counter() - t0
    p, s = r.sensors()
    return s[:, 0] / p[:, 0], seconds


def line(label, rel, seconds, y):
    return ("%-28s %5.1f s  σ median %.2f%%  rms %.2f%%  p90 %.2f%%  max %.2f%%  row y=1830 %.2f%%  σ²·t %.3g"
            % (label, seconds, 100 * np.median(rel), 100 * np.sqrt(np.mean(rel ** 2)), 100 * np.percentile(rel, 90),
               100 * rel.max(), 100 * np.median(rel[y == 1830]), np.mean(rel ** 2) * seconds))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--photons", type=float, default=3e6)
    ap.add_argument("--radii", type=float, nargs="*", default=[30, 100], help="exclusion radii (mm)")
    ap.add_argument("--near", type=float, nargs="*", default=[0, 0.5, 2],
                    help="near-disc factors (own next event within factor · radius · √targets; default 1)")
    ap.add_argument("--images", type=float, nargs="*", default=[1, 2], help="mirror next events per vertex")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    n = int(args.photons)
    chamber = validation.load("angers")
    ks = validation.kernel_scene(chamber, "nee", args.threads)
    y = ks.sens.center[:, 1]
    rel, sec = measure(ks, n, threads=args.threads)
    print(line("default", rel, sec, y), flush=True)
    print("median relative σ per row of y:", " ".join("%g: %.2f%%" % (v, 100 * np.median(rel[y == v]))
                                                    for v in np.unique(y)), flush=True)
    share = np.sum(rel[y == 1830] ** 2) / np.sum(rel ** 2)
    print("the %d sensors of row y = 1830 hold %.0f %% of the summed relative variance" % ((y == 1830).sum(),
                                                                                          100 * share), flush=True)
    default = ks.targets
    for radius in args.radii:
        ks.replace_targets(near2=np.maximum(default.near2, radius * radius))
        rel, sec = measure(ks, n, threads=args.threads)
        print(line("exclusion radius %g mm" % radius, rel, sec, y), flush=True)
    ks.replace_targets(**default._asdict())
    disc_radius = np.where(default.kind == 0, ks.sens.radius[default.ref], 0.0)
    for factor in args.near:
        start, near, r2 = near_discs(ks.tri_verts, default.center, disc_radius, factor)
        ks.replace_targets(near_start=start, near_list=near, near_r2=r2)
        rel, sec = measure(ks, n, threads=args.threads)
        print(line("near discs at %g·a·√n" % factor, rel, sec, y), flush=True)
    ks.replace_targets(**default._asdict())
    for k in args.images:
        ks = simulate.KernelScene(chamber, estimator="nee")
        ks.configure(images=k)
        ks.prune_next_events(threads=args.threads)
        rel, sec = measure(ks, n, threads=args.threads)
        print(line("%g mirror events per vertex" % k, rel, sec, y), flush=True)


if __name__ == "__main__":
    main()
