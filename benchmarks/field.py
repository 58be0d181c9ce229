"""The light field (``field``) against the full kernel (``nee``) on the same growing plant: error against time.

The procedural rose of ``benchmarks/rose.py`` (its last stage: 516 organs; leaves and buds read, internodes shade)
in ``angers-12bands``, 2 threads.  Per estimator and setting: the wall and CPU time of a step (the field's without
tracing its field, which is printed apart: it is traced once per ``renew`` steps), the leaves' 90th-percentile and
the buds' median relative σ on PAR, the buds' median σ on R:FR, and the bias against the full kernel at
``--reference`` photons on the same plant: the mean over leaves and over buds of (x − ref) / ref on PAR with its
standard error, the mean difference of the buds' R:FR, and the share of organs within max(4σ, 3 %) of the reference.

``--weighted P``: also the ``weighted`` estimator (no next events: every photon's own hits) at P photons against
the same reference: a check of the reference itself that shares none of its next-event machinery.

``--grey R T`` and ``--lamp-flux F``: a scene without the Angers optical tables or a lamp spectrum (``chambre2``):
every organ grey, the lamps' flux given (any value: biases are relative), and its one band's ppfd in PAR's place.

    .venv/bin/python benchmarks/field.py [--reference 1e7] [--full 3e5 1.15e6 4e6] [--stores 2e6 8e6]
                                         [--rays 256 1024 4096] [--cells 8] [--weighted 6.4e7]
                                         [--scene chambre2] [--position X Y Z]
                                         [--reference-cache runs/field_ref.npz]
                                         [--chart docs/efficiency/field.png] [--csv docs/efficiency/field.csv]
    .venv/bin/python benchmarks/field.py --scene chambre2 --position 160 35 87 --grey 0.2 0.2 --lamp-flux 1 \
                                         --full 1.15e6 --stores 8e6 --rays 1024 4096        # a chamber not tuned on
    .venv/bin/python benchmarks/field.py --replot docs/efficiency/field.csv --chart docs/efficiency/field.png
    .venv/bin/python benchmarks/field.py --full --stores 2e6 --rays 1024 --spread 8 --reference-cache runs/field_ref.npz
"""
from __future__ import annotations

import argparse
import csv
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from reuse import bias, lights_of, plant_model, precision, table  # noqa: E402

from lpy_light.estimators.field import FieldSettings, build_field, field_step  # noqa: E402


def within(tab, ref):
    """The share of lit organs within max(4σ, 3 %) of the reference."""
    mod, par, par_s, _, _ = tab
    _, rpar, rpar_s, _, _ = ref
    ok = (rpar > 0) & (par > 0) & np.isin(mod, ("Leaf", "Bud"))
    tol = np.maximum(4 * np.hypot(par_s[ok], rpar_s[ok]), 0.03 * rpar[ok])
    return float(np.mean(np.abs(par[ok] - rpar[ok]) <= tol))


def timed(fn):
    w, c = time.perf_counter(), time.process_time()
    out = fn()
    return out, time.perf_counter() - w, time.process_time() - c


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stage", type=int, default=4)
    ap.add_argument("--stages", type=int, default=4)
    ap.add_argument("--reference", type=float, default=1e7, help="photons of the full kernel's reference")
    ap.add_argument("--full", type=float, nargs="*", default=[3e5, 1.15e6, 4e6], help="photons of nee's steps")
    ap.add_argument("--stores", type=float, nargs="+", default=[2e6, 8e6], help="photons of the fields")
    ap.add_argument("--rays", type=int, nargs="+", default=[256, 1024, 4096], help="rays per side of a read organ")
    ap.add_argument("--cells", type=int, nargs="+", default=[FieldSettings().cells],
                    help="the field's cells along the region's edge")
    ap.add_argument("--weighted", type=float, default=0, metavar="P", help="also the weighted estimator at P photons")
    ap.add_argument("--spread", type=int, default=0, metavar="N",
                    help="also: N independent fields and rays (the first --stores, the middle --rays): each organ's "
                         "spread over them against the σ it reports")
    ap.add_argument("--scene", default="angers-12bands", help="the chamber (a built-in name or a .toml)")
    ap.add_argument("--position", type=float, nargs=3, default=None, metavar=("X", "Y", "Z"),
                    help="where the rose stands (chamber units; default: the scene's plant_position)")
    ap.add_argument("--grey", type=float, nargs=2, default=None, metavar=("R", "T"),
                    help="every organ of reflectance R and transmittance T in every band (a scene without the "
                         "Angers optical tables: chambre2)")
    ap.add_argument("--lamp-flux", type=float, nargs="+", default=None, metavar="F",
                    help="the lamps' µmol/s per band where the scene has no spectrum (chambre2: any, for biases)")
    ap.add_argument("--reference-cache", default=None, metavar="FILE.npz")
    ap.add_argument("--csv", default=None)
    ap.add_argument("--chart", default=None)
    ap.add_argument("--replot", default=None, metavar="CSV", help="only draw --chart from a --csv file")
    args = ap.parse_args()
    if args.replot:
        replot(args.replot, args.chart)
        return

    model, organs = plant_model(args.stage, args.stages, args.reference, scene=args.scene, position=args.position,
                                grey=args.grey, lamp_flux=args.lamp_flux)
    where = "%s at %s%s" % (args.scene, "its plant_position" if args.position is None else args.position,
                            "" if args.grey is None else ", grey organs %s" % args.grey)
    model.run(organs, photons=20_000)                 # compile, prune, pilots: not timed
    cache = Path(args.reference_cache) if args.reference_cache else None
    names = ("module", "par", "par_s", "rfr", "rfr_s")
    if cache and cache.is_file() and float(np.load(cache)["photons"]) == args.reference and \
            str(np.load(cache).get("where", where)) == where:
        ref = tuple(np.load(cache)[k] for k in names)
    else:
        ref, wall, cpu = timed(lambda: table(model.run(organs).organs, organs))
        print("reference: full kernel, %.3g photons, %.0f s" % (args.reference, wall))
        if cache:
            cache.parent.mkdir(parents=True, exist_ok=True)
            np.savez(cache, photons=args.reference, where=where, **dict(zip(names, ref)))
    rows = []

    def report(row):
        rows.append(row)
        print("%-8s %-26s %7.3f %7.3f %7.2f %7.2f %7.3f | %+6.2f±%.2f %+6.2f±%.2f %+7.3f±%.3f %6.1f%%" % (
            row["estimator"], row["setting"], row["step_s"], row["cpu_s"], 100 * row["leaf_p90"],
            100 * row["bud_med"], row["bud_rfr_sigma"], 100 * row["leaf_bias"], 100 * row["leaf_bias_se"],
            100 * row["bud_bias"], 100 * row["bud_bias_se"], row["bud_rfr_bias"], row["bud_rfr_bias_se"],
            100 * row["within"]), flush=True)

    print("%-8s %-26s %7s %7s %7s %7s %7s | %12s %12s %15s %7s" % (
        "", "setting", "step s", "CPU s", "leaf90", "bud med", "rfr σ", "leaf bias %", "bud bias %", "bud R:FR bias",
        "within"))
    for photons in args.full:
        step, wall, cpu = timed(lambda: model.run(organs, photons=int(photons)))
        tab = table(step.organs, organs)
        report({"estimator": "nee", "setting": "%.3g photons" % photons, "step_s": wall, "cpu_s": cpu,
                "store_s": 0.0, **precision(tab), **bias(tab, ref), "within": within(tab, ref)})
    if args.weighted:
        wmodel, _ = plant_model(args.stage, args.stages, args.weighted, estimator="weighted", scene=args.scene,
                                position=args.position, grey=args.grey, lamp_flux=args.lamp_flux)
        wmodel.flux, wmodel.flux_std = model.flux, model.flux_std
        step, wall, cpu = timed(lambda: wmodel.run(organs))
        tab = table(step.organs, organs)
        report({"estimator": "weighted", "setting": "%.3g photons" % args.weighted, "step_s": wall, "cpu_s": cpu,
                "store_s": 0.0, **precision(tab), **bias(tab, ref), "within": within(tab, ref)})

    ks = model.kscene
    read = np.array([o.module in ("Leaf", "Bud") for o in organs])
    for cells in args.cells:
        for store_photons in args.stores:
            cfg = FieldSettings(store_photons=int(store_photons), cells=cells)
            field, wall, cpu = timed(lambda: build_field(ks, cfg, seed=11, threads=2, flux=model.flux))
            print("field of %.3g photons, %d cells: %.1f s (CPU %.1f s), %d crossings"
                  % (store_photons, cells, wall, cpu, field.crossings), flush=True)
            field_step(ks, field, cfg, seed=4, threads=2, read=read)          # compile: not timed
            for rays in args.rays:
                cfg_r = FieldSettings(store_photons=int(store_photons), cells=cells, rays=rays,
                                      shading_rays=max(8, rays // 8))
                result, wall_s, cpu_s = timed(lambda: field_step(ks, field, cfg_r, seed=5, threads=2, read=read))
                tab = table(lights_of(model, organs, result), organs)
                report({"estimator": "field", "setting": "%.3g ph, %d cells, %d rays" % (store_photons, cells, rays),
                        "step_s": wall_s, "cpu_s": cpu_s, "store_s": wall, **precision(tab), **bias(tab, ref),
                        "within": within(tab, ref)})
            del field

    if args.spread:
        spread(ks, model, organs, read, int(args.stores[0]), args.rays[len(args.rays) // 2], args.spread, ref)

    if args.csv:
        with open(args.csv, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
    if args.chart:
        chart(rows, args.chart)


def spread(ks, model, organs, read, store_photons, rays, n, ref):
    """``n`` independent fields (other seeds), one step each with its own rays: each organ's spread of PAR over
    them against the σ it reports (honest: ~0.95, the median of a 7-dof χ's s / σ for n = 8), and the bias against
    the reference averaged over the fields, its standard error from their spread (a field's own error is common to
    every organ it lights: one field's bias carries it)."""
    cfg = FieldSettings(store_photons=store_photons, rays=rays)
    tabs = []
    for i in range(n):
        field = build_field(ks, cfg, seed=100 + i, threads=2, flux=model.flux)
        tabs.append(table(lights_of(model, organs, field_step(ks, field, cfg, seed=7 + i, threads=2, read=read)),
                          organs))
    par = np.array([t[1] for t in tabs])
    par_s = np.array([t[2] for t in tabs])
    mod = tabs[0][0]
    ok = np.all(par > 0, axis=0) & np.isin(mod, ("Leaf", "Bud"))
    ratio = np.std(par[:, ok], axis=0, ddof=1) / np.median(par_s[:, ok], axis=0)
    print("%d independent fields of %.3g photons, %d rays: per organ, spread / reported σ: median %.3f (leaves %.3f, "
          "buds %.3f; 10-90 %%: %.2f-%.2f)" % (n, store_photons, rays, np.median(ratio),
                                               np.median(ratio[mod[ok] == "Leaf"]), np.median(ratio[mod[ok] == "Bud"]),
                                               *np.percentile(ratio, [10, 90])))
    biases = [bias(t, ref) for t in tabs]
    parts = []
    for key, scale, unit in (("leaf_bias", 100, " %"), ("bud_bias", 100, " %"), ("bud_rfr_bias", 1, "")):
        v = np.array([b[key] for b in biases]) * scale
        parts.append("%s %+.3f ± %.3f%s" % (key, v.mean(), v.std(ddof=1) / math.sqrt(n), unit))
    print("bias over the %d fields (± their spread / √%d): %s; within max(4σ, 3 %%): %s" % (
        n, n, ", ".join(parts), " ".join("%.1f" % (100 * within(t, ref)) for t in tabs)))


def chart(rows, path):
    """Error against CPU time per step: σ (solid) and |mean bias| (dotted) of the leaves (left, σ their 90th
    percentile) and the buds (right, σ their median), one line per estimator and field."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
    lines = {}
    for r in rows:
        key = r["estimator"] if r["estimator"] != "field" else "field, " + r["setting"].split(" ph")[0] + " photons"
        lines.setdefault(key, []).append(r)
    for ax, (what, sig, b, title) in zip(axes, (("leaves", "leaf_p90", "leaf_bias", "leaves: p90 σ"),
                                               ("buds", "bud_med", "bud_bias", "buds: median σ"))):
        for key, sel in lines.items():
            t = [float(r["cpu_s"]) for r in sel]
            line, = ax.plot(t, [100 * float(r[sig]) for r in sel], "s-" if key.startswith("field") else "o-",
                            label="%s σ" % key)
            ax.plot(t, [100 * abs(float(r[b])) for r in sel], ":", marker=line.get_marker(), color=line.get_color(),
                    label="%s |bias|" % key)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.axhline(3, color="grey", lw=0.5)
        ax.set_xlabel("CPU s per step (2 threads; the field's own tracing apart)")
        ax.set_ylabel("% of PAR")
        ax.set_title("%s and mean |bias| against nee 1e7" % title)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def replot(csv_path, path):
    """The chart again from a ``--csv`` file."""
    with open(csv_path) as f:
        chart(list(csv.DictReader(f)), path)


if __name__ == "__main__":
    main()
