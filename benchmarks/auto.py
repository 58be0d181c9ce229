"""What ``estimator="auto"`` chooses, and what its pilot costs: the procedural rose and a canopy of them.

For each case, a ``LightModel(estimator="auto")`` lights the plant twice: the first step traces a field, checks it
against ``nee`` (the pilot) and chooses (:mod:`lpy_light.plant.auto`); the second is lit by the chosen estimator.
Then a ``nee`` model lights the same plant once.  Prints the choice and why, the field's gain (how many times
cheaper than ``nee`` it brings the organs' 90th-percentile σ to a given value; all read organs and per kind), and
the CPU seconds of the pilot step, of the chosen estimator's step and of ``nee``'s: what ``auto`` costs over
``nee`` is the pilot step minus a chosen step, once per pilot.

Cases (``--cases``): ``rose`` (516 organs, leaves and buds read, no precision goal: PAR weighed),
``rose-rfr`` (the same with ``precision={"par": 0.03, "rfr": 0.02}``: R:FR weighed too; each step then runs to
that goal, ``--photons`` its cap), ``rose-leaves`` (leaves read: ``targets``), ``canopy`` (16 roses, 8,256
organs, leaves and buds read; ~3 min on 2 cores).

    .venv/bin/python benchmarks/auto.py [--cases rose,rose-rfr,rose-leaves,canopy] [--photons 300000]
"""
from __future__ import annotations

import argparse
import time

import canopy as canopy_bench
import rose as bush
from lpy_light.plant.light import LightModel

ORGANS = {"Leaf": bush.LEAF_MATERIAL, "Internode": bush.LEAF_MATERIAL[0], "Bud": bush.LEAF_MATERIAL[0]}
#: name: (the plant, the organs read, the precision goal: what the choice weighs; photons per step stay the cap)
CASES = {"rose": (lambda: bush.rose(4, 4), ["Leaf", "Bud"], None),
         "rose-rfr": (lambda: bush.rose(4, 4), ["Leaf", "Bud"], {"par": 0.03, "rfr": 0.02}),
         "rose-leaves": (lambda: bush.rose(4, 4), ["Leaf"], None),
         "canopy": (lambda: canopy_bench.canopy(16), ["Leaf", "Bud"], None)}


def cpu_of(model, organs):
    c = time.process_time()
    step = model.run(organs)
    return time.process_time() - c, step


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", default="rose,rose-rfr,rose-leaves,canopy")
    ap.add_argument("--photons", type=float, default=300_000, help="nee's photons per step (LightModel's default)")
    ap.add_argument("--seed", type=int, default=3)
    args = ap.parse_args()
    for name in args.cases.split(","):
        plant, targets, goal = CASES[name]
        plant = plant()
        auto = LightModel("angers-12bands", photons=int(args.photons), plant_unit="cm", estimator="auto",
                          seed=args.seed, targets=targets, organs=ORGANS, precision=goal)
        organs = auto.organs_from_meshes(plant)
        pilot_cpu, pilot = cpu_of(auto, organs)
        chosen_cpu, _ = cpu_of(auto, organs)
        nee = LightModel("angers-12bands", photons=int(args.photons), plant_unit="cm", estimator="nee",
                         seed=args.seed, targets=targets, organs=ORGANS, precision=goal)
        nee_cpu, _ = cpu_of(nee, nee.organs_from_meshes(plant))
        choice = pilot.extra["auto"]
        stats = pilot.extra["field_check"]["gain"]
        print("\n## %s: %d organs, %s read, precision %s" % (name, len(organs), " and ".join(targets), goal))
        print("chose %s: %s" % (choice["estimator"], choice["why"]))
        for quantity in ("par", "rfr"):
            print("%s at the organs' p90: %s" % (quantity, ", ".join(
                "%s %.2fx (σ field %.3g, nee %.3g at %d photons)" % (
                    k, g["gain"], g["field_var"] ** 0.5, g["nee_var"] ** 0.5, choice["cpu_s"]["nee_check_photons"])
                for k, g in stats.get(quantity, {}).items())))
        c = choice["cpu_s"]
        print("pilot: field traced %.1f CPU s, its step %.1f, its check (nee) %.1f" % (
            c["field_trace"], c["field_step"], c["field_check"]))
        print("CPU s: pilot step %.1f, the chosen estimator's step %.1f, nee's step %.1f at %d photons; the pilot "
              "costs %.1f CPU s over a chosen step, once" % (pilot_cpu, chosen_cpu, nee_cpu, args.photons,
                                                             pilot_cpu - chosen_cpu), flush=True)


if __name__ == "__main__":
    main()
