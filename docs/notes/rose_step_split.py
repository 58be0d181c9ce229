"""The rose step's last stage taken apart (twenty-first session): its cost, and its buds' variance by the vertex
the next events leave from.

One rose step (benchmarks/rose.py's procedural bush at its last stage, 516 organs; next events aimed at leaves and
buds; seed 1) traced ``reps`` times after a warm-up step, each printed as: wall and CPU seconds, photon rays and
shadow rays per photon, the leaves' 90th-percentile and the buds' median σ on PAR, and σ²·CPU (%²·s; 3 % in 1 s
on 2 cores asks ≤ 18):

    .venv/bin/python docs/notes/rose_step_split.py run 1.15e6 2 [knob=value ...]

``knob=value`` sets a LightModel attribute or a next-event setting first (e.g. ``cones=4``, ``mirror_events=0.0``).
``DUMP=/tmp/x`` saves the organs' incident photons per band and their covariances (``/tmp/x.npz``: no lamp
normalisation, which a masked kernel would change).

By vertex: apply ``docs/notes/variance-by-vertex.patch`` to a copy of the tree (``KEEP`` keeps the deposits of
the vertices whose nee_stats rows it lists: 13 the Makrolon, 25-26 the leaves, 0-12,14-24 the other chamber
materials), give each setting a NUMBA_CACHE_DIR of its own (``KEEP`` is a constant of the compiled kernel), dump
each, then compare:

    for v in all:0-255 M:13 L:25-26 W:0-12,14-24; do KEEP=${v#*:} DUMP=/tmp/split/${v%%:*} \\
        NUMBA_CACHE_DIR=/tmp/split/nc_${v%%:*} PYTHONPATH=<copy> .venv/bin/python docs/notes/rose_step_split.py run 1.15e6 1; done
    .venv/bin/python docs/notes/rose_step_split.py split /tmp/split all M L W

which prints, per part, the buds' and leaves' median share of PAR light and of its variance.
"""
import os
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))


def run(photons, reps, knobs):
    from rose import LEAF_MATERIAL, rose

    from lpy_light.run import simulate
    from lpy_light.plant.light import LightModel
    model = LightModel("angers-12bands", photons=int(photons), plant_unit="cm", estimator="nee",
                       targets=["Leaf", "Bud"],
                       organs={"Leaf": LEAF_MATERIAL, "Internode": LEAF_MATERIAL[0], "Bud": LEAF_MATERIAL[0]})
    for knob in knobs:
        name, value = knob.split("=")
        if hasattr(model, name):
            setattr(model, name, eval(value))
        else:
            model.kscene.configure(**{name: eval(value)})
    plant = rose(4, 4)
    organs = model.organs_from_meshes(plant)
    kept = {}
    trace = simulate.run

    def keep(*a, **k):
        kept["r"] = trace(*a, **k)
        return kept["r"]

    simulate.run = keep
    model.run(organs)                       # warm-up: compile, pilot
    for _ in range(reps):
        cpu, wall = time.process_time(), time.perf_counter()
        step = model.run(organs)
        cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
        r = kept["r"]
        leaf = [o.par_std / o.par for o in step.organs.values() if o.module == "Leaf" and o.par > 0]
        bud = [o.par_std / o.par for o in step.organs.values() if o.module == "Bud" and o.par > 0]
        lp, bm = 100 * np.percentile(leaf, 90), 100 * np.median(bud)
        print("wall %.2f s  CPU %.2f s  rays/photon %.2f  shadow/photon %.2f  leaves p90 %.2f %%  buds median %.2f %%"
              "  σ²·CPU leaves %.1f buds %.1f" % (wall, cpu, r.counters[0] / r.photons, r.counters[4] / r.photons,
                                                  lp, bm, lp * lp * cpu, bm * bm * cpu))
    if os.environ.get("DUMP"):
        rows = model.kscene.n_chamber_receivers + np.arange(len(organs))
        inc, _ = r.receivers_incident()
        np.savez(os.environ["DUMP"] + ".npz", inc=inc[rows], cov=r.covariance(r.n_sensors + rows),
                 bands=np.array(model.chamber.bands, float), module=np.array([o.module for o in organs]))


def split(folder, names):
    def par(name):
        d = np.load(os.path.join(folder, name + ".npz"))
        b = d["bands"]
        sel = (b[:, 0] >= 400) & (b[:, 1] <= 700)
        return d["inc"][:, sel].sum(1), d["cov"][:, sel][:, :, sel].sum(axis=(1, 2)), d["module"]

    total, var, module = par(names[0])
    for name in names[1:]:
        x, v, _ = par(name)
        for kind in ("Bud", "Leaf"):
            s = (module == kind) & (total > 0)
            print("%-4s %-4s share of PAR: median %.3f;  of its variance: median %.3f, mean %.3f" % (
                name, kind, np.median(x[s] / total[s]), np.median(v[s] / var[s]), np.mean(v[s] / var[s])))


if __name__ == "__main__":
    if sys.argv[1] == "run":
        run(float(sys.argv[2]), int(sys.argv[3]), sys.argv[4:])
    else:
        split(sys.argv[2], sys.argv[3:])
