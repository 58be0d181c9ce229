"""Which next-event estimator carries a bud's variance (fifteenth session; with docs/notes/variance-by-event.patch).

Apply the patch to a copy of the tree (it adds per-photon sums of one tally row's deposits, by the event that
made them, to the kernel's counters), then, from that tree:

    .venv/bin/python docs/notes/variance_by_event.py 4.6e6                 # lists buds: the row and band to watch
    THR=2 LPYL_DBGROW=263 LPYL_DBGBAND=10 NUMBA_CACHE_DIR=/tmp/nbc-263 .venv/bin/python docs/notes/variance_by_event.py 4.6e6

(WL=660 picks the 655-665 nm band and the median and worst buds by PAR σ instead of the worst by R:FR σ.)  The
row and band are module constants of the compiled kernel: give each setting a NUMBA_CACHE_DIR of its own.  The
procedural rose of benchmarks/rose.py at its last step, seed 7.  Prints each event kind's share of the row's sum
and of its per-photon variance (next events split into own events and picks).
"""
import sys, os, time; sys.path.insert(0, str(__import__('pathlib').Path(__file__).resolve().parents[2] / 'benchmarks'))
import numpy as np
from rose import rose, LEAF_MATERIAL
from lpy_light.plant.light import LightModel, organ_lights
from lpy_light.run import simulate
model = LightModel("angers-12bands", photons=int(1.15e6), plant_unit="cm", estimator="nee", threads=2,
                   targets=["Leaf", "Bud"], organs={"Leaf": LEAF_MATERIAL, "Internode": LEAF_MATERIAL[0], "Bud": LEAF_MATERIAL[0]})
organs = model.organs_from_meshes(rose(4, 4))
model.run(organs, photons=20000)
ks = model.kscene
N = int(float(sys.argv[1]))
r = simulate.run(ks, N, seed=7, threads=int(os.environ.get("THR", "2")))
read = np.array([o.module in ("Leaf", "Bud") for o in organs])
L = organ_lights(ks, r, organs, model.flux, model.flux_std, model.chamber, read)
bands = model.chamber.bands
fr = [i for i, b in enumerate(bands) if b[0] <= float(os.environ.get("WL", "730")) <= b[1]][0]
buds = [(k, l) for k, l in L.items() if l.module == "Bud" and l.par > 0]
rows = {o.key: ks.n_sensors + i for i, o in enumerate(organs)}  # receiver rows: assumption checked below
srt = sorted(buds, key=lambda kl: -kl[1].par_std / kl[1].par); worst = [srt[len(srt) // 2]] + srt[:1]
for k, l in worst:
    row = rows[k]
    print("bud", k, "row", row, "band", fr, bands[fr], "tally", r.tally[row, fr], "photons", l.photons[fr], "±", l.photons_std[fr], "rfr %.3f ± %.3f" % (l.rfr, l.rfr_std))
c = r.counters
names = {1: "next_event", 2: "image", 3: "image2", 4: "organ zone", 5: "counted hit", 6: "cones", 7: "own events", 8: "picks"}
if os.environ.get("LPYL_DBGROW"):
    print("row", os.environ["LPYL_DBGROW"], "band", os.environ["LPYL_DBGBAND"], "N", N)
    tot, tot2 = c[80] / 1e9, c[60] / 1e9
    print("all (per photon)  sum %.4f  var of the sum %.4f (σ %.4f)" % (tot, tot2 - tot * tot / N, (tot2 - tot * tot / N) ** 0.5))
    for t in range(1, 9):
        s1, s2 = c[80 + t] / 1e9, c[60 + t] / 1e9
        print("%-12s sum %9.4f  per-photon var %.4f  (share of σ² %.0f %%)" % (names[t], s1, s2 - s1 * s1 / N, 100 * (s2 - s1 * s1 / N) / max(tot2 - tot * tot / N, 1e-30)))
