"""A canopy, not a plant: k × k rose bushes on the Angers flood table, one step each, per estimator.

Each bush is ``benchmarks/rose.py``'s grown rose (516 organs: internodes, 14-triangle blades, icosphere
buds), 30 cm apart, each turned by its own angle, centred on the table.  One ``LightModel`` step per canopy
and estimator (next events aimed at leaves and buds, as ``lsystems/rose.lpy`` does), ``--photons`` photons.
Prints per canopy and estimator: organs, triangles, the step's wall and CPU seconds, the leaves' 90th
percentile and the buds' median relative σ on PAR, and the cost to bring the leaves' p90 to 3 % (the step's
CPU seconds × (p90 / 3 %)², σ ∝ 1/√N), then the cost ratio to one rose and writes a CSV and a log-log chart
(cost against organs, the linear line drawn):

    .venv/bin/python benchmarks/canopy.py [--roses 1 4 9 16] [--photons 1e6] [--estimators nee weighted analog]
                                          [--cones N] [--out docs/efficiency]

Costs are CPU seconds (steadier than wall time on a shared machine; with 2 threads ≈ 2 × wall when quiet).  For
``reuse`` a step's cost is its gather's plus a tenth of its first step's (the store traced once per ``renew`` = 10
steps).
"""
import argparse
import csv
import math
import time
from pathlib import Path

import numpy as np

from lpy_light.plant.light import LightModel

import rose as bush

SPACING = 30.0          # cm between bushes
GOAL = 0.03             # the leaves' p90 relative σ the cost is counted to


def canopy(k: int) -> dict:
    """Organs of k × k bushes: {key: (mesh (v, f) in cm, material, module)}, centred on the plant position."""
    plant = bush.rose(4, 4)
    organs = {}
    n = int(round(math.sqrt(k)))
    offsets = [(i - (n - 1) / 2, j - (n - 1) / 2) for i in range(n) for j in range(n)]
    for b, (i, j) in enumerate(offsets):
        angle = 2.399963 * b                       # golden angle: each bush turned differently
        c, s = math.cos(angle), math.sin(angle)
        rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
        shift = np.array([i * SPACING, j * SPACING, 0.0])
        for key, ((v, f), mat, mod) in plant.items():
            organs[(b, key)] = ((v @ rot.T + shift, f), mat, mod)
    return organs


def step(organs, estimator, photons, threads, seed=3, cones=None):
    model = LightModel("angers-12bands", photons=photons, plant_unit="cm", estimator=estimator, threads=threads,
                       seed=seed, targets=["Leaf", "Bud"], cone_rays=cones,
                       organs={"Leaf": bush.LEAF_MATERIAL, "Internode": bush.LEAF_MATERIAL[0],
                               "Bud": bush.LEAF_MATERIAL[0]})
    converted = model.organs_from_meshes(organs)
    store_cpu = 0.0
    if model.keeper is not None:      # reuse: the store is traced once per ``renew`` steps, its cost shared by them
        cpu = time.process_time()
        model.run(converted)
        store_cpu = (time.process_time() - cpu) / model.keeper.settings.renew
    t, cpu = time.perf_counter(), time.process_time()
    result = model.run(converted)
    wall, cpu = time.perf_counter() - t, time.process_time() - cpu + store_cpu
    rel = lambda mod: np.array([l.par_std / l.par for l in result.organs.values()      # noqa: E731
                                if l.module == mod and l.role == "target" and l.par > 0])
    leaves, buds = rel("Leaf"), rel("Bud")
    p90 = float(np.percentile(leaves, 90))
    return {"organs": len(converted), "triangles": result.triangles, "wall_s": wall, "cpu_s": cpu,
            "leaves_p90": p90, "buds_median": float(np.median(buds)) if len(buds) else math.nan,
            "cost_to_3pc_cpu_s": cpu * (p90 / GOAL) ** 2}


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--roses", type=int, nargs="+", default=[1, 4, 9, 16])
    ap.add_argument("--photons", type=float, default=1e6)
    ap.add_argument("--estimators", nargs="+", default=["nee", "weighted", "analog"])
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--cones", type=float, default=None,
                    help="LightModel's cone_rays (nee; default: 10 from 1,000 targets, i.e. 4 roses; 0: picks only)")
    ap.add_argument("--out", default=None, help="folder for canopy.csv and canopy.png")
    args = ap.parse_args()
    rows = []
    print("%6s %9s %7s %9s %8s %8s %10s %10s %12s" % ("roses", "estimator", "organs", "triangles", "wall s",
                                                       "CPU s", "leaf p90", "bud med", "cost to 3 %"))
    for k in args.roses:
        organs = canopy(k)
        for est in args.estimators:
            r = {"roses": k, "estimator": est, **step(organs, est, int(args.photons), args.threads, cones=args.cones)}
            rows.append(r)
            print("%6d %9s %7d %9d %8.2f %8.2f %9.1f%% %9.1f%% %11.1f s" % (
                k, est, r["organs"], r["triangles"], r["wall_s"], r["cpu_s"], 100 * r["leaves_p90"],
                100 * r["buds_median"], r["cost_to_3pc_cpu_s"]), flush=True)
    for est in args.estimators:
        mine = {r["roses"]: r for r in rows if r["estimator"] == est}
        if 1 in mine:
            print("%s: cost to leaves p90 3 %% relative to one rose: %s" % (est, ", ".join(
                "%d roses %.1fx" % (k, mine[k]["cost_to_3pc_cpu_s"] / mine[1]["cost_to_3pc_cpu_s"]) for k in sorted(mine))))
    big = max(args.roses)
    costs = {r["estimator"]: r["cost_to_3pc_cpu_s"] for r in rows if r["roses"] == big}
    if "nee" in costs:
        print("at %d roses: nee is %s" % (big, ", ".join("%.1fx ahead of %s" % (costs[e] / costs["nee"], e)
                                                       for e in costs if e != "nee")))
    if args.out:
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        with open(out / "canopy.csv", "w", newline="") as fh:
            writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
            writer.writeheader()
            writer.writerows(rows)
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, ax = plt.subplots(figsize=(6, 4.5))
        for est in args.estimators:
            pts = sorted((r["organs"], r["cost_to_3pc_cpu_s"]) for r in rows if r["estimator"] == est)
            ax.loglog(*zip(*pts), "o-", label=est)
        pts = sorted((r["organs"], r["cost_to_3pc_cpu_s"]) for r in rows if r["estimator"] == "nee")
        if pts:
            x = np.array([p[0] for p in pts], float)
            ax.loglog(x, pts[0][1] * x / x[0], "k--", lw=0.8, label="linear in organs (from nee, 1 rose)")
        ax.set_xlabel("organs")
        ax.set_ylabel("CPU s to leaves' p90 σ = 3 %")
        ax.legend()
        ax.set_title("Canopy on the Angers table, %g photons per step" % args.photons)
        fig.tight_layout()
        fig.savefig(out / "canopy.png", dpi=110)
        print("wrote %s and %s" % (out / "canopy.csv", out / "canopy.png"))


if __name__ == "__main__":
    main()
