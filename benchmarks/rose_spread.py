"""Is the σ a rose's buds report honest?  Their PAR and R:FR spread over seeds against the σ each run reports.

Derives ``lsystems/rose.lpy`` (real L-Py, e.g. ``.venv-lpy`` from ``scripts/test-lpy.sh``) to ``--steps``
with ``PAR_MIN = RFR_MIN = 0`` (every bud bursts, so the plant does not depend on the light and every
build of the kernel lights the same plant), then lights that plant with ``LightModel`` for seeds 3, 4, ...
and prints, over the buds: the median spread of PAR over the seeds (relative) against the median σ the
runs reported, and the same for R:FR (absolute), with the CPU seconds per run.  A spread well above the
reported σ is a heavy tail: rare large deposits that most runs do not see.

    .venv-lpy/bin/python benchmarks/rose_spread.py [--steps 14] [--photons 1e6] [--seeds 8]
"""
import argparse
import time
from pathlib import Path

import numpy as np

from lpy_light import lpy as adapter
from lpy_light.light import LightModel

ROSE = Path(__file__).resolve().parents[1] / "lsystems" / "rose.lpy"


def rose_organs(steps):
    """The rose's organs at ``steps`` (chamber units) and the model's own LightModel."""
    from openalea.lpy import Lsystem
    lsys = Lsystem(str(ROSE), {"STEPS": steps, "PHOTONS": 2e5, "PRECISION": 0, "PAR_MIN": 0.0, "RFR_MIN": 0.0})
    lstring = lsys.derive()
    scene = lsys.sceneInterpretation(lstring)
    model = lsys.context()["light"]
    meshes, modules = adapter.shapes_by_module(lstring, scene, set(model.organ_materials), model.cache)
    return adapter.organs_from_meshes_by_id(meshes, modules, model), model


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=14)
    ap.add_argument("--photons", type=float, default=1e6)
    ap.add_argument("--seeds", type=int, default=8)
    args = ap.parse_args()
    organs, base = rose_organs(args.steps)
    par, par_std, rfr, rfr_std, cpu = [], [], [], [], 0.0
    for seed in range(3, 3 + args.seeds):
        model = LightModel(base.chamber, organs=base.organ_materials, photons=args.photons, seed=seed,
                           plant_unit="cm", targets=base.targets)
        model.position, model.scale = base.position, base.scale
        t = time.process_time()
        step = model.run(organs)
        cpu += time.process_time() - t
        buds = sorted((str(k), light) for k, light in step.organs.items() if light.module == "Bud" and light.role == "target")
        par.append([b.par for _, b in buds])
        par_std.append([b.par_std for _, b in buds])
        rfr.append([b.rfr for _, b in buds])
        rfr_std.append([b.rfr_std for _, b in buds])
    par, par_std, rfr, rfr_std = map(np.array, (par, par_std, rfr, rfr_std))
    spread = par.std(axis=0, ddof=1) / par.mean(axis=0)
    reported = np.median(par_std / par, axis=0)
    print("rose.lpy step %d: %d buds, %g photons, %d seeds, %.2f CPU s per run"
          % (args.steps, par.shape[1], args.photons, args.seeds, cpu / args.seeds))
    print("buds' PAR : spread over seeds median %.3f, reported σ median %.3f (spread / reported %.2f)"
          % (np.median(spread), np.median(reported), np.median(spread / reported)))
    print("buds' R:FR: spread over seeds median %.3f, reported σ median %.3f"
          % (np.median(rfr.std(axis=0, ddof=1)), np.median(rfr_std)))


if __name__ == "__main__":
    main()
