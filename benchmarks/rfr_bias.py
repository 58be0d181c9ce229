"""R:FR of the rose's buds and leaves against the photon budget, with and without the ratio's bias correction.

The 516-organ rose of ``benchmarks/rose.py`` (its last stage) in the Angers chamber, lit as that benchmark
lights it (``angers-12bands``, next events aimed at leaves and buds), at each photon budget for each seed.
Per organ, R:FR as reported (without the first-order bias of a ratio of two estimates,
:mod:`lpy_light.chamber.ratios`) and the plain ratio of the same run's two ppfd (red / far red: what
``ratios.uncorrected()`` reports, and what R:FR was before issue 45).  A seed lights every budget with the
same photon streams (chunk c is the same photons in every run), so budgets are compared organ by organ,
seed by seed.  Printed: per budget and kind of organ, the mean R:FR over the organs, the organs whose R:FR
is not reported (far red's σ above 0.3), the median σ; then the differences "LOW minus HIGH" (mean over
the organs that have an R:FR at both budgets, the same organs for the plain ratio, and the plain ratio over
every organ, as issue 45 measured it) with their standard error from the seeds' spread (and, in brackets,
from the organs' spread, organs taken as independent).  ``far σ/far``: the median relative σ of the far
red, which falls as 1/√N where the σ is honest (a heavy tail makes it grow: docs/performance.md).

    .venv/bin/python benchmarks/rfr_bias.py [--photons 1e6 4e6 1.6e7] [--seeds 1 2 3 4] [--threads 2]
                                            [--stage 4 --stages 4] [--csv docs/efficiency/rfr_bias.csv]
                                            [--chart docs/efficiency/rfr_bias.png] [--uncorrected]

``--lpy lsystems/rose.lpy`` lights the plant a real L-Py model grows (``--steps`` steps at ``--grow-photons`` a
step) instead, with the model's own ``LightModel``: its materials, targets and settings (rose.lpy's buds are
opaque, the procedural rose's translucent):

    .venv-lpy/bin/python benchmarks/rfr_bias.py --lpy lsystems/rose.lpy --photons 1e6 4e6 --seeds 1 2 3 4

``--uncorrected`` runs the whole benchmark inside ``ratios.uncorrected()`` (both columns then the plain
ratio, every organ with a number): a check that the plain column is what the switch gives.
"""
from __future__ import annotations

import argparse
import contextlib
import csv
import math
import time
from pathlib import Path

import numpy as np

from lpy_light.chamber import ratios
from lpy_light.plant.light import LightModel
from rose import LEAF_MATERIAL, rose

KINDS = ("Bud", "Leaf")


def light_the_rose(photons, seeds, stage, stages, threads):
    """R:FR per organ: ``{(seed, photons): {"module": (O,), "rfr": (O,), "rfr_std": (O,), "plain": (O,)}}``
    for the target organs (leaves and buds, in the plant's order), and the seconds each run took."""
    model = LightModel("angers-12bands", plant_unit="cm", threads=threads, targets=list(KINDS),
                       organs={"Leaf": LEAF_MATERIAL, "Internode": LEAF_MATERIAL[0], "Bud": LEAF_MATERIAL[0]})
    organs = model.organs_from_meshes({k: (m, mat, mod) for k, (m, mat, mod) in rose(stage, stages).items()})
    return light_at_budgets(model, organs, photons, seeds)


def light_a_grown_model(model_path, steps, photons, seeds, threads, grow_photons):
    """As :func:`light_the_rose` for the plant a real L-Py model grows: ``model_path`` (e.g. ``lsystems/rose.lpy``,
    whose ``LightModel`` is its module variable ``light``) derived ``steps`` steps at ``grow_photons`` a step, then
    its last plant lit by the model's own ``LightModel`` at each budget and seed (no precision: the budget
    whole).  Needs L-Py (``.venv-lpy``)."""
    from openalea.lpy import Lsystem
    t = time.perf_counter()
    lsys = Lsystem(str(model_path), {"STEPS": steps, "PHOTONS": int(grow_photons), "PRECISION": None})
    lsys.derive()
    model = lsys.context()["light"]
    print("  %s grown %d steps in %.0f s: %d organs" % (model_path, steps, time.perf_counter() - t,
                                                        len(model.last_organs)))
    model.precision, model.threads = None, threads
    return light_at_budgets(model, model.last_organs, photons, seeds)


def light_at_budgets(model, organs, photons, seeds):
    """``organs`` lit by ``model`` at each budget for each seed (a seed: the same photon streams at every
    budget); the per-organ numbers of :func:`light_the_rose` and the seconds of each run."""
    red, far = model.chamber.band_labels.index("655-665"), model.chamber.band_labels.index("725-735")
    out, seconds = {}, {}
    for seed in seeds:
        for n in photons:
            model.seed, model.step = seed, 0         # every budget of a seed: the same photon streams
            t = time.perf_counter()
            step = model.run(organs, photons=int(n))
            seconds[seed, n] = time.perf_counter() - t
            lights = [light for light in step.organs.values() if light.module in KINDS]
            out[seed, n] = {"module": np.array([light.module for light in lights]),
                            "rfr": np.array([light.rfr for light in lights]),
                            "rfr_std": np.array([light.rfr_std for light in lights]),
                            "plain": np.array([light.ppfd[red] / light.ppfd[far] for light in lights]),
                            "far_cv": np.array([light.ppfd_std[far] / light.ppfd[far] for light in lights])}
            print("  seed %d, %.3g photons: %.1f s" % (seed, n, seconds[seed, n]), flush=True)
    return out, seconds


def budget_rows(runs, photons, seeds):
    """Per budget and kind: mean R:FR (corrected, plain) over the organs and seeds, organs without an R:FR,
    median σ."""
    rows = []
    for n in photons:
        for kind in KINDS:
            rfr = np.concatenate([runs[s, n]["rfr"][runs[s, n]["module"] == kind] for s in seeds])
            plain = np.concatenate([runs[s, n]["plain"][runs[s, n]["module"] == kind] for s in seeds])
            std = np.concatenate([runs[s, n]["rfr_std"][runs[s, n]["module"] == kind] for s in seeds])
            far_cv = np.concatenate([runs[s, n]["far_cv"][runs[s, n]["module"] == kind] for s in seeds])
            ok = np.isfinite(rfr)
            rows.append({"photons": n, "organs": kind, "n": len(rfr), "unreported": int((~ok).sum()),
                         "rfr_mean": float(rfr[ok].mean()), "plain_mean_same_organs": float(plain[ok].mean()),
                         "plain_mean_all": float(plain.mean()), "rfr_std_median": float(np.median(std[ok])),
                         "far_red_cv_median": float(np.median(far_cv))})
    return rows


def difference(runs, low, high, seeds, kind, column, every_organ=False):
    """Mean over organs of ``column`` at ``low`` minus at ``high`` photons, over the organs with an R:FR at
    both (``every_organ``: over all of them, for the plain ratio), and its standard error: from the spread of
    the seeds' means (None for one seed), and from the spread over organs × seeds.  Returns (mean, se_seeds,
    se_organs, organs)."""
    per_seed, every = [], []
    for s in seeds:
        a, b = runs[s, low], runs[s, high]
        keep = (a["module"] == kind) & (every_organ or (np.isfinite(a["rfr"]) & np.isfinite(b["rfr"])))
        d = a[column][keep] - b[column][keep]
        per_seed.append(d.mean())
        every.append(d)
    every = np.concatenate(every)
    se_seeds = float(np.std(per_seed, ddof=1) / math.sqrt(len(seeds))) if len(seeds) > 1 else None
    return float(every.mean()), se_seeds, float(every.std(ddof=1) / math.sqrt(len(every))), len(every)


def chart(path, rows, photons, seeds):
    """Mean R:FR against photons, buds and leaves, as reported and as the plain ratio (same organs)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from matplotlib.ticker import NullFormatter

    fig, axes = plt.subplots(1, 2, figsize=(9, 4.2))
    for ax, kind in zip(axes, KINDS):
        sel = [r for r in rows if r["organs"] == kind]
        x = [r["photons"] for r in sel]
        ax.plot(x, [r["plain_mean_all"] for r in sel], "s--", color="tab:red", label="plain ratio (before), all organs")
        ax.plot(x, [r["plain_mean_same_organs"] for r in sel], "o:", color="tab:orange",
                label="plain ratio, organs with an R:FR")
        ax.plot(x, [r["rfr_mean"] for r in sel], "o-", color="tab:blue", label="reported (bias-corrected)")
        for r in sel:
            if r["unreported"]:
                ax.annotate("%d/%d without R:FR" % (r["unreported"], r["n"]), (r["photons"], r["rfr_mean"]),
                            textcoords="offset points", xytext=(0, -13), fontsize=7, color="tab:blue", ha="center")
        ax.set_xscale("log")
        ax.set_xticks(photons)
        ax.set_xticklabels(["%.3g" % p for p in photons])
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel("photons per step")
        ax.set_title("%s: mean R:FR over organs and seeds" % {"Bud": "buds", "Leaf": "leaves"}[kind], fontsize=10)
        ax.margins(x=0.12, y=0.12)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("R:FR (655-665 / 725-735)")
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=3, fontsize=8, frameon=False)
    per_kind = {r["organs"]: r["n"] // seeds for r in rows}
    fig.suptitle("benchmarks/rfr_bias.py: the rose of benchmarks/rose.py in Angers (%d buds, %d leaves; %d seeds)"
                 % (per_kind["Bud"], per_kind["Leaf"], seeds), fontsize=9)
    fig.tight_layout(rect=(0, 0.07, 1, 1))
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    print("chart: %s" % path)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--photons", type=float, nargs="+", default=[1e6, 4e6])
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--stage", type=int, default=4, help="the rose's stage (benchmarks/rose.py; 4 of 4: 516 organs)")
    ap.add_argument("--stages", type=int, default=4)
    ap.add_argument("--csv", default=None, help="write the per-budget table here")
    ap.add_argument("--chart", default=None, help="write the chart here (e.g. docs/efficiency/rfr_bias.png)")
    ap.add_argument("--uncorrected", action="store_true",
                    help="R:FR as the plain ratio (ratios.uncorrected(): the bias left in), for comparison")
    ap.add_argument("--lpy", default=None, metavar="MODEL",
                    help="light the plant this .lpy model grows instead (real L-Py: run with .venv-lpy/bin/python)")
    ap.add_argument("--steps", type=int, default=30, help="with --lpy: steps grown (default 30)")
    ap.add_argument("--grow-photons", type=float, default=2e5, help="with --lpy: photons a step while it grows")
    args = ap.parse_args()
    photons = sorted(args.photons)
    with ratios.uncorrected() if args.uncorrected else contextlib.nullcontext():
        if args.lpy:
            runs, seconds = light_a_grown_model(args.lpy, args.steps, photons, args.seeds, args.threads,
                                                args.grow_photons)
        else:
            runs, seconds = light_the_rose(photons, args.seeds, args.stage, args.stages, args.threads)
    rows = budget_rows(runs, photons, args.seeds)
    print("\n%10s %6s %6s %11s %12s %14s %14s %9s %12s" % ("photons", "organs", "n", "unreported", "R:FR mean",
                                                          "plain (same)", "plain (all)", "σ median", "far σ/far"))
    for r in rows:
        print("%10.3g %6s %6d %11d %12.4f %14.4f %14.4f %9.4f %12.3f" % (
            r["photons"], r["organs"], r["n"], r["unreported"], r["rfr_mean"], r["plain_mean_same_organs"],
            r["plain_mean_all"], r["rfr_std_median"], r["far_red_cv_median"]))
    print("\nmean over organs (with an R:FR at both budgets) of R:FR at LOW minus at HIGH photons, ± s.e. from "
          "the %d seeds' spread [from the organs' spread]:" % len(args.seeds))
    for i, low in enumerate(photons):
        for high in photons[i + 1:]:
            for kind in KINDS:
                cells, counts = [], []
                for column, every in (("rfr", False), ("plain", False), ("plain", True)):
                    m, se_s, se_o, n = difference(runs, low, high, args.seeds, kind, column, every)
                    cells.append("%+.4f ± %s [± %.4f]" % (m, "n/a" if se_s is None else "%.4f" % se_s, se_o))
                    counts.append(n)
                print("  %.3g minus %.3g, %-5s: corrected %s   plain %s (%d organ-seeds with an R:FR at both)   "
                      "plain, every organ %s (%d)" % (low, high, kind, cells[0], cells[1], counts[0], cells[2],
                                                     counts[2]))
    print("\nseconds per run: " + ", ".join("%.3g photons %.1f s" % (n, np.mean([seconds[s, n] for s in args.seeds]))
                                          for n in photons))
    if args.csv:
        with open(args.csv, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=list(rows[0]), lineterminator="\n")
            w.writeheader()
            w.writerows(rows)
        print("table: %s" % args.csv)
    if args.chart:
        chart(args.chart, rows, photons, len(args.seeds))


if __name__ == "__main__":
    main()
