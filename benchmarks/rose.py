"""The rose in the Angers chamber without L-Py: a procedural rose bush (trimesh organs, cm) lit step by step.

Prints, per growth step: organs, triangles, time per step (conversion + trace; wall clock, and the
process's CPU seconds, steadier on a shared machine: with 2 threads ≈ 2 × wall when nothing else runs), the leaves' median
and 90th-percentile relative σ on PAR, the buds' median, and what the geometry cache saved.  The same LightModel path
as lsystems/rose.lpy runs in L-Py, minus PlantGL's tessellation.

    .venv/bin/python benchmarks/rose.py [--photons 300000] [--steps 5] [--estimator nee] [--targets all] [--images 0.2]
                                        [--cones 4]

With ``--lpy`` (in a venv with L-Py and PlantGL, e.g. ``.venv-lpy`` from ``scripts/test-lpy.sh``), the same
growth through the real L-Py: ``lsystems/rose.lpy`` derived ``--steps`` steps (default 36: ≥ 500 organs), and per
step the share of its time spent in L-Py (derivation and PlantGL's scene), in tessellation and conversion of
the organs' shapes, and in tracing:

    .venv-lpy/bin/python benchmarks/rose.py --lpy --steps 36 --photons 1e6
"""
import argparse
import math
import time

import numpy as np
import trimesh

from lpy_light.estimators.registry import DEFAULT_ESTIMATOR, ESTIMATORS
from lpy_light.plant.light import LightModel

LEAF_MATERIAL = ("FeuilleVieille_Sup", "FeuilleVieille_Inf")


def _frame(heading):
    h = _unit(heading)
    a = np.array([1.0, 0, 0]) if abs(h[0]) < 0.9 else np.array([0, 1.0, 0])
    l = _unit(np.cross(h, a))
    return h, l, np.cross(h, l)


def _rot(axis, angle):
    """Rotation matrix by ``angle`` about ``axis`` (Rodrigues), written out: no BLAS call (np.dot, @, a 1-d
    np.linalg.norm), whose rounding depends on the machine's BLAS kernel, so the bush is the same bit for bit
    everywhere (tests/test_kernel_digests.py pins its light)."""
    x, y, z = np.asarray(axis, float) / math.sqrt(sum(float(c) * float(c) for c in axis))
    c, s = math.cos(angle), math.sin(angle)
    t = 1.0 - c
    return np.array([[c + x * x * t, x * y * t - z * s, x * z * t + y * s],
                     [y * x * t + z * s, c + y * y * t, y * z * t - x * s],
                     [z * x * t - y * s, z * y * t + x * s, c + z * z * t]])


def _apply(R, v):
    """``R @ v`` for a (3, 3) matrix and a (3,) vector, without BLAS (see :func:`_rot`)."""
    return R[:, 0] * v[0] + R[:, 1] * v[1] + R[:, 2] * v[2]


def _unit(v):
    return v / math.sqrt(float(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]))


def blade(length, width=0.43):
    """A flat leaf blade (lens) of ``length`` along +x, normal +z, 14 triangles."""
    top = [(0.0, 0.0), (0.15, 0.16), (0.4, 0.225), (0.65, 0.19), (0.85, 0.1), (1.0, 0.0)]
    ring = top + [(x, -y) for x, y in reversed(top[1:-1])]
    v = np.array([(0.5, 0.0, 0.0)] + [(x, y * width / 0.45, 0.0) for x, y in ring]) * length
    n = len(ring)
    return v, np.array([(0, 1 + i, 1 + (i + 1) % n) for i in range(n)])


def _place(vertices, origin, h, l, u):
    return origin + vertices[:, :1] * h + vertices[:, 1:2] * l + vertices[:, 2:3] * u


def rose(stage: int, max_stage: int):
    """Organs of the bush at ``stage``: {key: (mesh (v, f), material, module)}; sizes grow with the stage."""
    organs = {}
    key = [0]
    grow = min(1.0, 0.4 + 0.6 * stage / max(max_stage, 1))
    nodes = [12, 6, 3]

    def axis(origin, heading, order, first_node):
        pos = np.array(origin, float)
        h, l, u = _frame(np.array(heading, float))
        for rank in range(nodes[order]):
            if first_node + rank > stage * 4:       # the axis is still growing
                return
            length = 3.0 * grow
            cyl = trimesh.creation.cylinder(radius=0.25 / (order + 1), height=length, sections=8)
            v = _place(cyl.vertices, pos + h * length / 2, l, u, h)    # cylinder's z axis along the heading
            organs[key[0]] = ((v, cyl.faces), LEAF_MATERIAL[0], "Internode")
            key[0] += 1
            pos = pos + h * length
            roll = _rot(h, math.radians(144 * (rank + 1)))
            side = _apply(roll, l)
            leaf_dir = _apply(_rot(np.cross(h, side), math.radians(55)), h)
            lh, ll, lu = _frame(leaf_dir)
            bv, bf = blade(7.0 * grow)
            organs[key[0]] = ((_place(bv, pos, lh, ll, lu), bf), LEAF_MATERIAL, "Leaf")
            key[0] += 1
            bud = trimesh.creation.icosphere(subdivisions=1, radius=0.2)
            organs[key[0]] = ((bud.vertices + pos + 0.3 * side, bud.faces), LEAF_MATERIAL[0], "Bud")
            key[0] += 1
            if order < 2 and rank >= 2:
                branch = _apply(_rot(np.cross(h, side), math.radians(40)), h)
                axis(pos, branch, order + 1, first_node + rank + 1)

    axis((0, 0, 0), (0, 0, 1), 0, 0)
    return organs


def lpy_growth(args):
    """``--lpy``: lsystems/rose.lpy in the real L-Py, timed per step by where the time goes."""
    from pathlib import Path

    from openalea.lpy import Lsystem

    from lpy_light.plant import light as lightmod

    model_path = Path(args.model) if args.model else Path(__file__).parent.parent / "lsystems" / "rose.lpy"
    t0 = time.perf_counter()
    externs = {"PHOTONS": int(args.photons)} if args.model else {"STEPS": args.steps, "PHOTONS": int(args.photons),
                                                                  "PRECISION": 0}
    lsys = Lsystem(str(model_path), externs)
    model = lightmod.MODELS[-1]
    if args.threads:
        model.threads = args.threads
    print("model + chamber + normalisation: %.2f s (once)" % (time.perf_counter() - t0))
    steps = []
    model.on_step = lambda step, organs: steps.append(step)
    print("%4s %7s %9s %8s %8s %10s %10s %8s %8s %10s %10s" % (
        "step", "organs", "triangles", "step s", "CPU s", "L-Py s", "convert s", "trace s", "convert", "leaf σ med",
        "bud σ med"))
    totals = np.zeros(4)
    lstring = lsys.axiom
    for i in range(args.steps):
        t, cpu = time.perf_counter(), time.process_time()
        lstring = lsys.derive(lstring, i, 1)
        total, cpu = time.perf_counter() - t, time.process_time() - cpu
        step = steps[-1]
        convert = step.extra.get("convert_seconds", 0.0)
        lpy_s = total - convert - step.seconds
        leaf = [l.par_std / l.par for l in step.organs.values() if l.module == "Leaf" and l.par > 0]
        bud = [l.par_std / l.par for l in step.organs.values() if l.module == "Bud" and l.par > 0]
        totals += (total, lpy_s, convert, step.seconds)
        print("%4d %7d %9d %8.2f %8.2f %10.3f %10.3f %8.2f %7.0f%% %9.1f%% %9.1f%%" % (
            i, len(step.organs), step.triangles, total, cpu, lpy_s, convert, step.seconds, 100 * convert / total,
            100 * np.median(leaf) if leaf else float("nan"), 100 * np.median(bud) if bud else float("nan")))
    print("all steps: %.1f s; L-Py %.0f %%, tessellation and conversion %.0f %%, tracing %.0f %%; last step %d organs"
          % (totals[0], 100 * totals[1] / totals[0], 100 * totals[2] / totals[0], 100 * totals[3] / totals[0],
             len(steps[-1].organs)))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--photons", type=float, default=300_000)
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--estimator", default=DEFAULT_ESTIMATOR, choices=tuple(ESTIMATORS) + ("auto",))
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--targets", nargs="+", default=["Leaf", "Bud"],
                    help="modules next events aim at (default: Leaf Bud, as lsystems/rose.lpy; 'all': every organ)")
    ap.add_argument("--images", type=float, default=None,
                    help="next events through a mirror per vertex, on average (default: LightModel's, 0.2)")
    ap.add_argument("--cones", type=float, default=None,
                    help="rays into far organ clusters' cones per vertex (default: LightModel's: none below 1,000 targets)")
    ap.add_argument("--local", type=float, default=None,
                    help="local rays per vertex near a cluster (default: LightModel's: none below 1,000 targets)")
    ap.add_argument("--lpy", action="store_true",
                    help="grow lsystems/rose.lpy in the real L-Py (needs L-Py/PlantGL) and time where a step goes")
    ap.add_argument("--model", default=None,
                    help="with --lpy: another .lpy model that creates a LightModel (e.g. lsystems/rose-simple4-light.lpy)")
    args = ap.parse_args()
    if args.lpy:
        if "--steps" not in " ".join(__import__("sys").argv):
            args.steps = 36
        return lpy_growth(args)
    t0 = time.perf_counter()
    model = LightModel("angers-12bands", photons=int(args.photons), plant_unit="cm", estimator=args.estimator,
                       threads=args.threads,
                       targets=None if args.targets == ["all"] else args.targets,
                       organs={"Leaf": LEAF_MATERIAL, "Internode": LEAF_MATERIAL[0], "Bud": LEAF_MATERIAL[0]})
    if args.images is not None:
        model.mirror_events = args.images
    if args.cones is not None:
        model.kscene.configure(cones=args.cones)
    if args.local is not None:
        model.kscene.configure(local=args.local)
    print("chamber + normalisation: %.2f s (once)" % (time.perf_counter() - t0))
    print("%4s %7s %9s %8s %9s %9s %9s %10s %10s %10s %10s" % ("step", "organs", "triangles", "step s", "CPU s",
                                                                 "convert s", "trace s", "leaf σ med", "leaf σ p90",
                                                                 "leaf σ rms", "bud σ med"))
    for stage in range(args.steps):
        plant = rose(stage, args.steps - 1)
        t, cpu = time.perf_counter(), time.process_time()
        organs = model.organs_from_meshes({k: (m, mat, mod) for k, (m, mat, mod) in plant.items()})
        t_convert = time.perf_counter() - t
        step = model.run(organs)
        total, cpu = time.perf_counter() - t, time.process_time() - cpu
        rel = np.array([l.par_std / l.par for l in step.organs.values() if l.module == "Leaf" and l.par > 0])
        bud = np.array([l.par_std / l.par for l in step.organs.values() if l.module == "Bud" and l.par > 0])
        print("%4d %7d %9d %8.2f %9.2f %9.3f %9.2f %9.1f%% %9.1f%% %9.1f%% %9.1f%%" % (
            stage, len(organs), step.triangles, total, cpu, t_convert, step.seconds, 100 * np.median(rel),
            100 * np.percentile(rel, 90), 100 * np.sqrt(np.mean(rel ** 2)),
            100 * np.median(bud) if len(bud) else float("nan")))
        if "auto" in step.extra:
            print("     estimator auto: %s -- %s %s" % (step.extra["auto"]["estimator"], step.extra["auto"]["why"], step.extra["auto"]["cpu_s"]))
    # what building once and caching save
    t = time.perf_counter()
    model.cache = type(model.cache)()
    model.organs_from_meshes({k: (m, mat, mod) for k, (m, mat, mod) in plant.items()})
    cold = time.perf_counter() - t
    t = time.perf_counter()
    model.organs_from_meshes({k: (m, mat, mod) for k, (m, mat, mod) in plant.items()})
    warm = time.perf_counter() - t
    from lpy_light.run import simulate
    t = time.perf_counter()
    simulate.KernelScene(model.chamber, model.kscene.estimator)
    chamber_build = time.perf_counter() - t
    t = time.perf_counter()
    model.kscene.set_organs(organs, model.materials)
    organ_update = time.perf_counter() - t
    print("organ conversion: %.3f s cold, %.3f s from the cache (%.0fx)" % (cold, warm, cold / max(warm, 1e-9)))
    print("chamber scene build %.3f s (done once) vs organ update %.3f s per step" % (chamber_build, organ_update))


if __name__ == "__main__":
    main()
