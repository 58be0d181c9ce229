"""The chamber's light stored once (``reuse``) against the full kernel (``nee``) on the same growing plant.

The procedural rose of ``benchmarks/rose.py`` (its last stage: 516 organs, every organ a target) in
``angers-12bands``, 2 threads.  Per estimator and setting: the time of a step (the reuse's without building its
store, which is printed apart: it is traced once per ``renew`` steps), the leaves' 90th-percentile and the buds'
median relative σ on PAR, the buds' median σ on R:FR, and the bias per organ against the full kernel at
``--reference`` photons on the same plant: the mean over leaves and over buds of (x − ref) / ref on PAR with its
standard error, the mean difference of the buds' R:FR, and the share of organs within 4σ of the reference.

``--spread N``: N independent stores, one gather each: each organ's spread over them against the σ it reports, and
the bias per store against the reference (a store's own error is common to the organs it lights: the bias's
standard error is the stores' spread).

``--renewal``: the store built with the plant of an earlier stage (``--stage - 1``) lights the last stage's plant:
the bias of a store not renewed while the plant grew (its shadow on the table and walls, the light it sends back,
are the earlier plant's).

    .venv/bin/python benchmarks/reuse.py [--reference 2e7] [--full 3e5 1.15e6 4e6] [--stores 2e5 5e5 2e6]
                                         [--samples 32 64 128] [--renewal] [--spread 8]
                                         [--chart docs/efficiency/reuse.png]
                                         [--csv docs/efficiency/reuse.csv]
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
from rose import LEAF_MATERIAL, rose  # noqa: E402

from lpy_light.plant.light import LightModel  # noqa: E402
from lpy_light.plant.organ_light import organ_lights  # noqa: E402
from lpy_light.estimators.reuse import ReuseSettings, build_store, gather_step, plant_box  # noqa: E402

ORGANS = {"Leaf": LEAF_MATERIAL, "Internode": LEAF_MATERIAL[0], "Bud": LEAF_MATERIAL[0]}


def plant_model(stage, stages, photons, estimator="nee", targets=("Leaf", "Bud"), scene="angers-12bands",
                position=None, grey=None, lamp_flux=None):
    """The rose's last stage in ``scene``; ``grey`` (R, T): every organ of that reflectance and transmittance in
    every band (a scene without the Angers optical tables, e.g. ``chambre2``), else the Angers leaf tables;
    ``lamp_flux``: the lamps' µmol/s per band where the scene cannot tell (no spectrum: any value, for biases)."""
    grey = None if grey is None else {"reflectance": float(grey[0]), "transmittance": float(grey[1])}
    model = LightModel(scene, photons=int(photons), plant_unit="cm", organs=ORGANS if grey is None else
                       {k: grey for k in ORGANS}, threads=2, estimator=estimator, targets=targets, position=position,
                       lamp_flux=lamp_flux)
    organs = model.organs_from_meshes({k: (m, mat if grey is None else grey, mod)
                                       for k, (m, mat, mod) in rose(stage, stages).items()})
    return model, organs


def table(lights, organs):
    """Per organ (in the organs' order): module, PAR, its σ, R:FR, its σ (a scene whose bands give no PAR, e.g.
    ``chambre2``'s one unlabelled band: the first band's ppfd in its place, R:FR NaN)."""
    rows = [lights[o.key] for o in organs]

    def column(name):
        return np.array([np.nan if getattr(l, name) is None else getattr(l, name) for l in rows], float)
    par, par_s = column("par"), column("par_std")
    if np.isnan(par).all():
        par = np.array([l.ppfd[0] for l in rows], float)
        par_s = np.array([l.ppfd_std[0] for l in rows], float)
    return np.array([l.module for l in rows]), par, par_s, column("rfr"), column("rfr_std")


def precision(tab):
    mod, par, par_s, rfr, rfr_s = tab
    leaf, bud = (mod == "Leaf") & (par > 0), (mod == "Bud") & (par > 0)
    return {"leaf_p90": float(np.percentile(par_s[leaf] / par[leaf], 90)),
            "bud_med": float(np.median(par_s[bud] / par[bud])),
            "bud_rfr_sigma": float(np.nanmedian(rfr_s[bud]))}


def bias(tab, ref):
    mod, par, par_s, rfr, rfr_s = tab
    _, rpar, rpar_s, rrfr, rrfr_s = ref
    out = {}
    for kind in ("Leaf", "Bud"):
        k = (mod == kind) & (rpar > 0) & (par > 0)
        rel = par[k] / rpar[k] - 1.0
        se = math.sqrt(np.sum((par_s[k] ** 2 + rpar_s[k] ** 2) / rpar[k] ** 2)) / k.sum()
        out[kind.lower() + "_bias"], out[kind.lower() + "_bias_se"] = float(np.mean(rel)), se
    k = (mod == "Bud") & np.isfinite(rfr) & np.isfinite(rrfr)
    out["bud_rfr_bias"] = float(np.mean(rfr[k] - rrfr[k])) if k.any() else float("nan")
    out["bud_rfr_bias_se"] = float(math.sqrt(np.sum(rfr_s[k] ** 2 + rrfr_s[k] ** 2)) / k.sum()) if k.any() \
        else float("nan")
    ok = (rpar > 0) & (par > 0)
    z = (par[ok] - rpar[ok]) / np.hypot(par_s[ok], rpar_s[ok])
    out["within_4sigma"] = float(np.mean(np.abs(z) < 4))
    out["z_std"] = float(np.std(z))
    return out


def lights_of(model, organs, result):
    read = np.array([o.module in ("Leaf", "Bud") for o in organs])
    return organ_lights(model.kscene, result, organs, model.flux, model.flux_std, model.chamber, read)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--stage", type=int, default=4)
    ap.add_argument("--stages", type=int, default=4)
    ap.add_argument("--reference", type=float, default=2e7, help="photons of the full kernel's reference")
    ap.add_argument("--full", type=float, nargs="*", default=[3e5, 1.15e6, 4e6], help="photons of the full kernel's steps")
    ap.add_argument("--stores", type=float, nargs="+", default=[2e5, 5e5, 2e6], help="photons of the stores")
    ap.add_argument("--samples", type=int, nargs="+", default=[32, 64, 128], help="the gather's draws per target and batch")
    ap.add_argument("--renewal", action="store_true", help="also: a store built with the plant of the stage before")
    ap.add_argument("--spread", type=int, default=0, metavar="N",
                    help="also: N independent stores (the middle --stores and --samples): σ against their spread, "
                         "and the bias with its error from it")
    ap.add_argument("--reference-cache", default=None, metavar="FILE.npz",
                    help="keep the reference's table in FILE (read it there if it was made with the same photons)")
    ap.add_argument("--csv", default=None)
    ap.add_argument("--chart", default=None)
    args = ap.parse_args()

    model, organs = plant_model(args.stage, args.stages, args.reference)
    model.run(organs, photons=20_000)                 # compile, prune, pilots: not timed
    t = time.perf_counter()
    cache = Path(args.reference_cache) if args.reference_cache else None
    if cache and cache.is_file() and float(np.load(cache)["photons"]) == args.reference:
        ref = tuple(np.load(cache)[k] for k in ("module", "par", "par_s", "rfr", "rfr_s"))
    else:
        ref = table(model.run(organs).organs, organs)
        if cache:
            np.savez(cache, photons=args.reference, **dict(zip(("module", "par", "par_s", "rfr", "rfr_s"), ref)))
    print("reference: full kernel, %.3g photons, %.0f s" % (args.reference, time.perf_counter() - t))
    rows = []

    def report(row):
        rows.append(row)
        print("%-8s %-22s %8.3f %8.2f %8.2f %8.3f | %+7.2f±%.2f %+7.2f±%.2f %+7.3f±%.3f %6.1f%% %5.2f" % (
            row["estimator"], row["setting"], row["step_s"], 100 * row["leaf_p90"], 100 * row["bud_med"],
            row["bud_rfr_sigma"], 100 * row["leaf_bias"], 100 * row["leaf_bias_se"], 100 * row["bud_bias"],
            100 * row["bud_bias_se"], row["bud_rfr_bias"], row["bud_rfr_bias_se"], 100 * row["within_4sigma"],
            row["z_std"]), flush=True)

    print("%-8s %-22s %8s %8s %8s %8s | %13s %13s %15s %7s %5s" % (
        "", "setting", "step s", "leaf p90", "bud med", "bud rfr σ", "leaf bias %", "bud bias %", "bud R:FR bias",
        "in 4σ", "z sd"))
    for photons in args.full:
        t = time.perf_counter()
        step = model.run(organs, photons=int(photons))
        dt = time.perf_counter() - t
        tab = table(step.organs, organs)
        report({"estimator": "nee", "setting": "%.3g photons" % photons, "step_s": dt, "store_s": 0.0,
                **precision(tab), **bias(tab, ref)})

    # the reuse gathers at every organ (the internodes too: they shade and scatter), a quarter of the draws where
    # nobody reads the numbers: a light model of its own, set up once for this plant (every organ a target)
    rmodel, _ = plant_model(args.stage, args.stages, 20_000, estimator="reuse")
    rmodel.flux, rmodel.flux_std = model.flux, model.flux_std
    rmodel.keeper.settings = ReuseSettings(store_photons=16, batches=8, samples=1, image_draws=0, paths=0)
    n_t = len(organs)
    rmodel.run(organs)
    ks = rmodel.kscene
    read = np.array([o.module in ("Leaf", "Bud") for o in organs])
    for store_photons in args.stores:
        t = time.perf_counter()
        store = build_store(ks, int(store_photons), batches=16, seed=11, threads=2, flux=model.flux)
        store_s = time.perf_counter() - t
        print("store of %.3g photons: %.1f s, %d vertices, %d segments" % (store_photons, store_s, len(store.vpl),
                                                                          len(store.seg)), flush=True)
        for samples in args.samples:
            # paths and image draws in proportion to the draws: the defaults' (2 and 8 per organ at 64 draws)
            t = time.perf_counter()
            result = gather_step(ks, store, samples=samples, seed=5, threads=2, paths=n_t * samples // 32,
                                 image_draws=n_t * samples // 8, read=read)
            dt = time.perf_counter() - t
            tab = table(lights_of(rmodel, organs, result), organs)
            report({"estimator": "reuse", "setting": "store %.3g, %d draws" % (store_photons, samples), "step_s": dt,
                    "store_s": store_s, **precision(tab), **bias(tab, ref)})
        del store

    if args.renewal:
        earlier = rmodel.organs_from_meshes({k: (m, mat, mod) for k, (m, mat, mod)
                                            in rose(args.stage - 1, args.stages).items()})
        rmodel.run(earlier)                                # the earlier plant in the scene
        store = build_store(ks, int(args.stores[-1]), batches=16, seed=11, threads=2, flux=model.flux,
                            box=plant_box(organs, ks.chamber.metres_per_unit))
        rmodel.run(organs)                                 # the last stage's plant back in it
        result = gather_step(ks, store, samples=args.samples[-1], seed=5, threads=2,
                             paths=n_t * args.samples[-1] // 32, image_draws=n_t * args.samples[-1] // 8, read=read)
        tab = table(lights_of(rmodel, organs, result), organs)
        report({"estimator": "reuse", "setting": "stage %d's store" % (args.stage - 1), "step_s": result.seconds,
                "store_s": 0.0, **precision(tab), **bias(tab, ref)})

    if args.spread:
        # independent stores (other seeds), one gather each: the spread of each organ's PAR over them against the σ
        # each reports (issue 46: median ratio within 0.8-1.25), and the bias over leaves and buds with its standard
        # error from the stores' spread (a store's error is common to the organs it lights)
        store_photons, samples = int(args.stores[len(args.stores) // 2]), args.samples[len(args.samples) // 2]
        tabs = []
        for i in range(args.spread):
            store = build_store(ks, store_photons, batches=16, seed=1000 + i, threads=2, flux=model.flux)
            result = gather_step(ks, store, samples=samples, seed=77 + i, threads=2, paths=n_t * samples // 32,
                                 image_draws=n_t * samples // 8, read=read)
            tabs.append(table(lights_of(rmodel, organs, result), organs))
            del store
        par = np.array([t[1] for t in tabs])
        par_s = np.array([t[2] for t in tabs])
        mod = tabs[0][0]
        ok = np.all(par > 0, axis=0)
        ratio = np.std(par[:, ok], axis=0, ddof=1) / np.median(par_s[:, ok], axis=0)
        print("%d independent stores of %.3g photons, %d draws: per organ, spread over the stores / reported σ: "
              "median %.3f (leaves %.3f, buds %.3f; 10-90 %%: %.2f-%.2f)"
              % (args.spread, store_photons, samples, np.median(ratio), np.median(ratio[mod[ok] == "Leaf"]),
                 np.median(ratio[mod[ok] == "Bud"]), *np.percentile(ratio, [10, 90])))
        for kind in ("Leaf", "Bud"):
            k = (mod == kind) & ok & (ref[1] > 0)
            per_store = np.mean(par[:, k] / ref[1][k] - 1.0, axis=1)
            print("  %s: bias against the reference per store %s; mean %+.2f %% ± %.2f (from the stores' spread)"
                  % ({"Leaf": "leaves", "Bud": "buds"}[kind], " ".join("%+.2f" % (100 * b) for b in per_store), 100 * per_store.mean(),
                     100 * per_store.std(ddof=1) / math.sqrt(len(per_store))))
        rfr = np.array([t[3] for t in tabs])
        k = (mod == "Bud") & np.all(np.isfinite(rfr), axis=0) & np.isfinite(ref[3])
        per_store = np.mean(rfr[:, k] - ref[3][k], axis=1)
        print("  buds' R:FR: bias per store %s; mean %+.4f ± %.4f" % (" ".join("%+.3f" % b for b in per_store),
                                                                     per_store.mean(),
                                                                     per_store.std(ddof=1) / math.sqrt(len(per_store))))

    if args.csv:
        with open(args.csv, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0]))
            w.writeheader()
            w.writerows(rows)
    if args.chart:
        chart(rows, args.chart)


def chart(rows, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.5))
    for est, marker in (("nee", "o"), ("reuse", "s")):
        sel = [r for r in rows if r["estimator"] == est and "stage" not in r["setting"]]
        t = [r["step_s"] for r in sel]
        axes[0].plot(t, [100 * r["leaf_p90"] for r in sel], marker, label=est + ": leaves' p90")
        axes[0].plot(t, [100 * r["bud_med"] for r in sel], marker, mfc="none", label=est + ": buds' median")
        axes[1].errorbar(t, [100 * r["leaf_bias"] for r in sel], [100 * r["leaf_bias_se"] for r in sel], fmt=marker,
                         label=est + ": leaves")
        axes[1].errorbar(t, [100 * r["bud_bias"] for r in sel], [100 * r["bud_bias_se"] for r in sel], fmt=marker,
                         mfc="none", label=est + ": buds")
        axes[2].errorbar(t, [r["bud_rfr_bias"] for r in sel], [r["bud_rfr_bias_se"] for r in sel], fmt=marker,
                         label=est)
        for r in sel:
            axes[0].annotate(r["setting"], (r["step_s"], 100 * r["leaf_p90"]), fontsize=6)
    for ax, title in zip(axes, ("relative σ on PAR (%)", "PAR bias against the reference (%)",
                                "buds' R:FR bias against the reference")):
        ax.set_xscale("log")
        ax.set_xlabel("seconds a step (2 threads)")
        ax.set_title(title)
        ax.legend(fontsize=7)
    axes[0].axhline(3, color="grey", lw=0.5)
    axes[1].axhline(0, color="grey", lw=0.5)
    axes[2].axhline(0, color="grey", lw=0.5)
    fig.suptitle("benchmarks/reuse.py: the procedural rose (516 organs), full kernel (nee) against the stored chamber "
                 "(reuse)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
