"""Where one rose step's next events come from: shadow rays and light deposited on the organs, per source.

The 516-organ rose of ``benchmarks/rose.py`` (its last stage) lit once as ``benchmarks/rfr_bias.py`` lights it;
prints the run's extension rays and, per material and lamp element that makes next events, the shadow rays it
cast, those that found their target, and the weight it deposited on the organs (``Result.nee_stats``).  The sizes
of issue 46's reuse (docs/notes/chamber-light-reuse.md): the chamber's vertices' share of the rays and of the light.

    .venv/bin/python benchmarks/step_sources.py [--photons 1.15e6] [--threads 2]
"""
import argparse
import time

import numpy as np

from lpy_light.run import simulate
from lpy_light.kernel.tallies import C_RAYS
from lpy_light.plant.light import LightModel
from rose import LEAF_MATERIAL, rose


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--photons", type=float, default=1.15e6)
    ap.add_argument("--threads", type=int, default=2)
    a = ap.parse_args()
    results = []
    run = simulate.run

    def keep(*args, **kwargs):
        results.append(run(*args, **kwargs))
        return results[-1]

    simulate.run = keep
    model = LightModel("angers-12bands", plant_unit="cm", threads=a.threads, targets=["Leaf", "Bud"],
                       organs={"Leaf": LEAF_MATERIAL, "Internode": LEAF_MATERIAL[0], "Bud": LEAF_MATERIAL[0]})
    organs = model.organs_from_meshes({k: (m, mat, mod) for k, (m, mat, mod) in rose(4, 4).items()})
    t = time.perf_counter()
    model.run(organs, photons=int(a.photons))
    result = results[-1]
    print("%d organs, %.3g photons in %.1f s: %.3g extension rays" % (len(organs), result.photons,
                                                                     time.perf_counter() - t, result.counters[C_RAYS]))
    stats = result.nee_stats
    n_lamps = len(model.kscene.emit_nee)
    names = (list(result.materials) + ["lamp element %d" % i for i in range(n_lamps)]
             + ["through mirror plane %d" % i for i in range(len(stats) - len(result.materials) - n_lamps)])
    total = stats.sum(axis=0)
    print("%-30s %12s %7s %12s %12s %7s" % ("source", "shadow rays", "share", "found", "deposited", "share"))
    for i in np.argsort(-stats[:, 0]):
        if stats[i, 0] > 0:
            print("%-30s %12.3g %6.1f%% %12.3g %12.3g %6.1f%%" % (names[i][:30], stats[i, 0], 100 * stats[i, 0] / total[0],
                                                                stats[i, 1], stats[i, 2], 100 * stats[i, 2] / total[2]))


if __name__ == "__main__":
    main()
