"""The Angers chamber against SEC2: the four built-in scenes at 1e6 and 1e7 photons (1e8 with --full).

For each scene (angers, angers-onlylamps, angers-sansmakrolon, angers-sanstable) runs the kernel and
compares its 240 sensors with the SEC2 file that belongs to the scene (lpy_light.report.validation.SEC2_SCENES;
the full chamber also with the photon-mapping engine's run).  Prints one row per run: seconds,
photons/s, share of sensors within 4σ, mean relative bias ± σ, rms relative difference and the rms
that noise alone explains (σ combines ours and SEC2's Poisson σ; ours is scaled by N_SEC2 / N_ours), and
the rms of our own relative σ per sensor (to compare estimators: time x σ² is their cost).

``--ablations`` runs the physics variants of lpy_light.report.validation.VARIANTS instead (default 1e7
photons each) on the scenes where each one matters.

    .venv/bin/python benchmarks/angers.py [--full] [--estimator nee|weighted|analog] [--out runs/angers.csv]
    .venv/bin/python benchmarks/angers.py --ablations [--photons 1e7] [--out runs/ablations.csv]
"""
import argparse
import csv
import sys
from pathlib import Path

import numpy as np

from lpy_light.run import simulate
from lpy_light.report import validation
from lpy_light.estimators.registry import DEFAULT_ESTIMATOR, ESTIMATORS

FIELDS = ["scene", "variant", "estimator", "photons", "seconds", "photons_per_s", "reference", "within_4sigma",
          "bias", "bias_std", "rms", "rms_noise", "max_abs_z", "rms_ours"]


def rows_of(run):
    """CSV rows (one per reference) of a validation.validate() result."""
    out = []
    p, s = run["result"].sensors()
    with np.errstate(divide="ignore", invalid="ignore"):
        own = float(np.sqrt(np.mean((s[:, 0] / p[:, 0]) ** 2)))     # rms of our own relative σ
    for ref in ("sec2", "photon_mapping"):
        c = run[ref]
        if c is None:
            continue
        out.append({"scene": run["scene"], "variant": run["variant"], "estimator": run["estimator"],
                    "photons": run["photons"], "seconds": round(run["seconds"], 2),
                    "photons_per_s": round(run["photons_per_s"]),
                    "reference": validation.SEC2_SCENES[run["scene"]].sec2 if ref == "sec2" else "photon-mapping",
                    "within_4sigma": round(c.within_4sigma, 4), "bias": round(c.bias, 5),
                    "bias_std": round(c.bias_std, 5), "rms": round(c.rms, 5), "rms_noise": round(c.rms_noise, 5),
                    "max_abs_z": round(float(np.abs(c.z).max()), 2), "rms_ours": round(own, 5)})
    return out


def print_row(r, file=sys.stdout):
    print("%-20s %-24s %-8s %9.0e %8.1f %10.3g  %-25s %6.1f%%  %+6.2f%% ± %.2f%%  %5.2f%%  %5.2f%%  %5.1f  %5.2f%%"
          % (r["scene"], r["variant"], r["estimator"], r["photons"], r["seconds"], r["photons_per_s"],
             r["reference"], 100 * r["within_4sigma"], 100 * r["bias"], 100 * r["bias_std"], 100 * r["rms"],
             100 * r["rms_noise"], r["max_abs_z"], 100 * r["rms_ours"]), file=file, flush=True)


def header(file=sys.stdout):
    print("%-20s %-24s %-8s %9s %8s %10s  %-25s %7s  %-16s  %6s  %6s  %5s  %6s"
          % ("scene", "variant", "estim.", "photons", "seconds", "photons/s", "reference", "in 4σ", "bias ± σ",
             "rms", "noise", "max|z|", "σ ours"), file=file, flush=True)


def save_sensors(directory, run):
    """The run's per-sensor counts (for later analysis): DIR/<scene>_<variant>_<estimator>_<N>.npz."""
    p, s = run["result"].sensors()
    name = "%s_%s_%s_%d.npz" % (run["scene"], run["variant"].replace(" ", "-").replace("=", "-"),
                                run["estimator"], run["photons"])
    Path(directory).mkdir(parents=True, exist_ok=True)
    np.savez(Path(directory) / name, photons=p[:, 0], photons_std=s[:, 0], n=run["photons"],
             seconds=run["seconds"])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", nargs="+", default=list(validation.SEC2_SCENES),
                    choices=list(validation.SEC2_SCENES))
    ap.add_argument("--photons", nargs="+", type=float, default=None,
                    help="photon counts (default 1e6 1e7; with --ablations 1e7)")
    ap.add_argument("--full", action="store_true", help="add 1e8 photons (1-3 min per scene on 2 threads)")
    ap.add_argument("--estimator", choices=tuple(ESTIMATORS), default=DEFAULT_ESTIMATOR,
                    help="nee (default: fastest to a given precision on these sensors), weighted or analog")
    ap.add_argument("--ablations", action="store_true",
                    help="run the physics variants (lpy_light.report.validation.VARIANTS)")
    ap.add_argument("--variants", nargs="+", default=None, help="with --ablations: only these variants")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--out", default=None, help="CSV file for the table")
    ap.add_argument("--save-sensors", default=None, metavar="DIR", help="also save per-sensor counts (.npz)")
    args = ap.parse_args(argv)

    if args.ablations:
        photons = args.photons or [1e7]
        names = args.variants or list(validation.VARIANTS)
        jobs = [(scene, v) for v in names for scene in validation.VARIANTS[v].scenes if scene in args.scenes]
    else:
        photons = args.photons or ([1e6, 1e7] + ([1e8] if args.full else []))
        jobs = [(scene, "default") for scene in args.scenes]

    rows = []
    writer = None
    fh = None
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        fh = open(args.out, "w", newline="")
        writer = csv.DictWriter(fh, fieldnames=FIELDS)
        writer.writeheader()
    print("# %d threads, seed %d, estimator %s" % (args.threads, args.seed, args.estimator))
    header()
    try:
        for scene, variant in jobs:
            ks = validation.kernel_scene(validation.load(scene, variant), args.estimator, args.threads)
            simulate.run(ks, 1000, seed=args.seed + 1, threads=args.threads)     # compile / warm up
            for n in photons:
                run = validation.validate(scene, int(n), args.estimator, args.seed, args.threads, variant, kscene=ks)
                if args.save_sensors:
                    save_sensors(args.save_sensors, run)
                for r in rows_of(run):
                    print_row(r)
                    rows.append(r)
                    if writer:
                        writer.writerow(r)
                        fh.flush()
    finally:
        if fh:
            fh.close()
    return rows


if __name__ == "__main__":
    main()
