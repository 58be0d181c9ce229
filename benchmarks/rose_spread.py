"""Is the σ a rose's organs report honest?  Their PAR and R:FR spread over seeds against the σ each run reports.

Derives ``lsystems/rose.lpy`` (real L-Py, e.g. ``.venv-lpy`` from ``scripts/test-lpy.sh``) to ``--steps``
-- with ``PAR_MIN = RFR_MIN = 0`` (every bud bursts, so the plant does not depend on the light and every
build of the kernel lights the same plant), or with ``--grown`` as the model grows it under the lamps --
then lights that plant with ``LightModel`` for seeds 3, 4, ... and prints, for buds and leaves: the median
spread of PAR over the seeds (relative) against the median σ the runs reported, the same for R:FR
(absolute) and for the 655-665 and 725-735 nm bands, with the wall and CPU seconds per run.  A spread well
above the reported σ is a heavy tail: rare large deposits that most runs do not see.

``--save FILE.npz`` keeps the derived organs, and ``--load FILE.npz`` lights them without L-Py (any venv):
the same plant measured on two checkouts of lpy-light.

    .venv-lpy/bin/python benchmarks/rose_spread.py [--steps 14] [--grown] [--photons 1e6] [--seeds 8] [--save F]
    .venv/bin/python benchmarks/rose_spread.py --load F [--photons 1e6] [--seeds 8]
"""
import argparse
import time
from pathlib import Path

import numpy as np

from lpy_light.plant.light import LightModel
from lpy_light.plant.organs import Organ

ROSE = Path(__file__).resolve().parents[1] / "lsystems" / "rose.lpy"
ORGANS = {"Leaf": ("FeuilleVieille_Sup", "FeuilleVieille_Inf"), "Bud": {"reflectance": "FeuilleVieille_Sup"},
          "Internode": {"reflectance": "FeuilleVieille_Sup"}}           # as lsystems/rose.lpy declares them
TARGETS = ("Leaf", "Bud")
RED, FAR_RED = "655-665", "725-735"


def rose_organs(steps, grown=False):
    """The rose's organs at ``steps`` (chamber units)."""
    from openalea.lpy import Lsystem

    from lpy_light.plant import lpy as adapter
    externs = {"STEPS": steps, "PHOTONS": 2e5, "PRECISION": 0}
    if not grown:
        externs.update(PAR_MIN=0.0, RFR_MIN=0.0)
    lsys = Lsystem(str(ROSE), externs)
    lstring = lsys.derive()
    scene = lsys.sceneInterpretation(lstring)
    model = lsys.context()["light"]
    materials = {name: model._materials_of(spec) for name, spec in model.organ_materials.items()}
    return adapter.plant_organs(lstring, scene, materials, model.scale, model.position, model.cache)


def save(path, organs):
    np.savez_compressed(path, keys=np.array([o.key for o in organs]), modules=np.array([o.module for o in organs]),
                        fronts=np.array([o.front for o in organs]), backs=np.array([o.back for o in organs]),
                        areas=np.array([o.area for o in organs]), counts=np.array([len(o.triangles) for o in organs]),
                        triangles=np.concatenate([o.triangles for o in organs]))


def load(path):
    d = np.load(path)
    ends = np.cumsum(d["counts"])
    return [Organ(int(k), str(m), d["triangles"][e - c:e], str(f), str(b), float(a))
            for k, m, f, b, a, c, e in zip(d["keys"], d["modules"], d["fronts"], d["backs"], d["areas"], d["counts"], ends)]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=14)
    ap.add_argument("--grown", action="store_true", help="the plant as the model grows it under the lamps")
    ap.add_argument("--photons", type=float, default=1e6)
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--save", help="keep the derived organs in this .npz")
    ap.add_argument("--load", help="light the organs of this .npz (no L-Py needed)")
    args = ap.parse_args()
    organs = load(args.load) if args.load else rose_organs(args.steps, args.grown)
    if args.save:
        save(args.save, organs)
    flux = None
    out = {kind: [] for kind in TARGETS}
    wall = cpu = 0.0
    for seed in range(3, 3 + args.seeds):
        model = LightModel("angers-12bands", organs=ORGANS, photons=args.photons, seed=seed, plant_unit="cm",
                           targets=TARGETS, lamp_flux=flux)
        flux = model.flux                              # measured once, then given: the runs differ by their seed
        t, c = time.perf_counter(), time.process_time()
        step = model.run(organs)
        wall, cpu = wall + time.perf_counter() - t, cpu + time.process_time() - c
        b_red, b_far = step.organs[organs[0].key].bands.index(RED), step.organs[organs[0].key].bands.index(FAR_RED)
        for kind in TARGETS:
            lights = sorted((str(k), light) for k, light in step.organs.items() if light.module == kind)
            out[kind].append([(x.par, x.par_std, x.rfr, x.rfr_std, x.ppfd[b_red], x.ppfd_std[b_red], x.ppfd[b_far],
                               x.ppfd_std[b_far]) for _, x in lights])
    plant = args.load or "rose.lpy step %d%s" % (args.steps, " (grown)" if args.grown else "")
    print("%s: %d organs, %g photons, %d seeds, %.2f s wall, %.2f CPU s per run (the first compiles)"
          % (plant, len(organs), args.photons, args.seeds, wall / args.seeds, cpu / args.seeds))
    print("%-5s %4s  %-22s  %-22s  %-22s  %-22s" % ("", "n", "PAR spread / reported", "R:FR spread / reported",
                                                    "655-665 spread / rep.", "725-735 spread / rep."))
    for kind, runs in out.items():
        a = np.array(runs)                    # seeds, organs, 8
        rel = lambda v, s: (np.median(a[..., v].std(0, ddof=1) / a[..., v].mean(0)),   # noqa: E731
                            np.median(a[..., s] / a[..., v]))
        par, red, far = rel(0, 1), rel(4, 5), rel(6, 7)
        rfr = (np.median(a[..., 2].std(0, ddof=1)), np.median(a[..., 3]))
        print("%-5s %4d  %8.1f %% / %5.1f %%    %8.3f / %6.3f      %8.1f %% / %5.1f %%    %8.1f %% / %5.1f %%"
              % (kind, a.shape[1], 100 * par[0], 100 * par[1], rfr[0], rfr[1], 100 * red[0], 100 * red[1],
                 100 * far[0], 100 * far[1]))


if __name__ == "__main__":
    main()
