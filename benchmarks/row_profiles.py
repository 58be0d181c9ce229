"""The shape of the Angers light field against its references: ratio per row and per column of each sensor
plane (mean 1), and its change across the rows, for the four SEC2 scenes and ablation variants
(docs/validation.md, section 8).

The full chamber is compared with the average of its two references (SEC2's ``mesures.txt`` and the
photon-mapping engine's run, per emitted photon) and with each of them; the variants with their own SEC2
file.  One line per run, plane and axis: the change across the rows ± σ (both σ's), the rms and largest
row deviation from 1, the mean bias against the reference, then the rows themselves (%, from the lowest
coordinate).  ``--out`` also writes them as csv.

    .venv/bin/python benchmarks/row_profiles.py [--photons 2e7] [--scenes angers ...] [--variants default ...]
"""
import argparse
import csv
import sys

import numpy as np

from lpy_light.report import reference, validation

FIELDS = ["scene", "variant", "photons", "reference", "plane", "axis", "change", "change_std", "rms_rows",
          "max_row", "bias", "rows", "rows_std", "positions"]


def references(scene):
    """(name, Reference) pairs a scene is compared with."""
    vs = validation.SEC2_SCENES[scene]
    sec2 = reference.read_sec2(vs.sec2_path)
    if not vs.photon_mapping:
        return [("sec2", sec2)]
    pm = reference.read_photon_mapping(validation.PHOTON_MAPPING)
    return [("average", reference.average([sec2, pm])), ("sec2", sec2), ("photon-mapping", pm)]


def rows_of(run, chamber):
    p, s = run["result"].sensors()
    out = []
    for name, ref in references(run["scene"]):
        bias = reference.compare(p[:, 0], s[:, 0], run["photons"], ref).bias
        for across in (1, 0):
            for prof in reference.row_profiles(p[:, 0], s[:, 0], ref, chamber.sensors.center,
                                               chamber.sensors.normal, unit=chamber.unit, across=across):
                dev = prof.ratio - 1
                out.append({"scene": run["scene"], "variant": run["variant"], "photons": run["photons"],
                            "reference": name, "plane": prof.plane, "axis": prof.axis,
                            "change": round(prof.slope, 5), "change_std": round(prof.slope_std, 5),
                            "rms_rows": round(float(np.sqrt(np.mean(dev ** 2))), 5),
                            "max_row": round(float(dev[np.argmax(np.abs(dev))]), 5), "bias": round(bias, 5),
                            "rows": " ".join("%.5f" % r for r in prof.ratio),
                            "rows_std": " ".join("%.5f" % r for r in prof.ratio_std),
                            "positions": " ".join("%g" % x for x in prof.position)})
    return out


def print_row(r, file=sys.stdout):
    rows = [100 * (float(x) - 1) for x in r["rows"].split()]
    print("%-20s %-22s %-15s %-6s %s  change %+5.2f%% ± %.2f%%  rms %.2f%%  max %+5.2f%%  bias %+5.2f%%  [%s]"
          % (r["scene"], r["variant"][:22], r["reference"], r["plane"], r["axis"], 100 * r["change"],
             100 * r["change_std"], 100 * r["rms_rows"], 100 * r["max_row"], 100 * r["bias"],
             " ".join("%+.2f" % x for x in rows)), file=file, flush=True)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenes", nargs="+", default=list(validation.SEC2_SCENES), choices=list(validation.SEC2_SCENES))
    ap.add_argument("--variants", nargs="+", default=["default"], choices=list(validation.VARIANTS),
                    help="run each on the scenes it belongs to (validation.VARIANTS[...].scenes) among --scenes")
    ap.add_argument("--photons", type=float, default=2e7, help="per run (default 2e7: rows to < 0.1 %%)")
    ap.add_argument("--estimator", default="nee")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--out", default=None, help="csv of every line")
    args = ap.parse_args(argv)
    table = []
    for variant in args.variants:
        for scene in args.scenes:
            if scene not in validation.VARIANTS[variant].scenes:
                continue
            chamber = validation.load(scene, variant)
            run = validation.validate(scene, int(args.photons), estimator=args.estimator, seed=args.seed,
                                      threads=args.threads, variant=variant,
                                      kscene=validation.kernel_scene(chamber, args.estimator, args.threads))
            for r in rows_of(run, chamber):
                print_row(r)
                table.append(r)
    if args.out:
        with open(args.out, "w", newline="") as fh:
            w = csv.DictWriter(fh, FIELDS)
            w.writeheader()
            w.writerows(table)


if __name__ == "__main__":
    main()
