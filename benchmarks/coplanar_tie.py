"""The coplanar tie at z = 1970 in the Angers chamber (docs/validation.md, section 4.1).

1. Which surface Embree's float32 arithmetic returns when a ray from a lamp reaches one of the four
   40 mm strips where a cornice top and the Makrolon ceiling coincide (coplanar = "arbitrary").
2. The sensors' response to the tie, strip by strip: the Makrolon winning in one strip only (the
   cornices in the other three), and in none / all of them.
3. Mixing the two pure runs (cornices win everywhere / Makrolon wins everywhere, same seed) in
   proportion f: bias and rms against SEC2's mesures.txt and its "correctMoller" successor.
4. The sensors counted from both sides (a downward-facing twin of every disc added).

    .venv/bin/python benchmarks/coplanar_tie.py [--photons 1e7] [--threads 2] [--seed 1]
"""
import argparse
import dataclasses
import tempfile
from pathlib import Path

import numpy as np
from numba import njit

from lpy_light.report import reference, validation
from lpy_light.run import simulate
from lpy_light.kernel.embree import (ARGS, CAND_COUNT, DIR, GEOM_ID, INVALID_ID, MASK, ORG, PRIM_ID, RAYHIT, TFAR,
                                     TNEAR, new_scratch)
from lpy_light.kernel.ptr import call_ptr3, load_u32, store_f32, store_i64, store_u32
from lpy_light.chamber.scene import load_scene
from lpy_light.chamber.sensors import Sensors

STRIPS = {"G": ((0, 2400), (1800, 1840)), "D": ((0, 2400), (0, 40)), "AV": ((2360, 2400), (0, 1840)),
          "AR": ((0, 40), (0, 1840))}
OLD = "Makrolon polygon fauxPlafondInf\n0\n0\n12\n0.0 0.0 1970\n2400.0 0.0 1970\n2400.0 1840.0 1970\n0.0 1840.0 1970"


@njit(cache=False)     # not cached: numba would not see edits to the kernel functions it calls
def _cast(scene, fn, scratch, origins, dirs, out):
    rh = scratch + RAYHIT
    for i in range(origins.shape[0]):
        for a in range(3):
            store_f32(rh + ORG + 4 * a, origins[i, a])
            store_f32(rh + DIR + 4 * a, dirs[i, a])
        store_f32(rh + TNEAR, 0.0)
        store_f32(rh + DIR + 12, 0.0)
        store_f32(rh + TFAR, 3.0e38)
        store_u32(rh + MASK, 0xFFFFFFFF)
        store_u32(rh + GEOM_ID, INVALID_ID)
        store_i64(scratch + CAND_COUNT, 0)
        call_ptr3(fn, scene, rh, scratch + ARGS)
        out[i] = -1 if load_u32(rh + GEOM_ID) == INVALID_ID else load_u32(rh + PRIM_ID)


def embree_choice(n=20000, seed=0):
    """Share of the Makrolon among the rays from the lamps that reach each strip at z = 1970."""
    chamber = validation.load("angers")
    ks = simulate.KernelScene(chamber, "weighted")
    names = np.array([chamber.surfaces[chamber.tri_source[j]][0] for j in ks.order])
    lamps = np.array([(d[0] + d[1]) / 2 for d in chamber.emitters.data])
    rng = np.random.default_rng(seed)
    scratch = new_scratch()
    out = {}
    for strip, ((x0, x1), (y0, y1)) in STRIPS.items():
        target = np.c_[rng.uniform(x0, x1, n), rng.uniform(y0, y1, n), np.full(n, 1970.0)]
        origin = lamps[rng.integers(0, len(lamps), n)]
        d = target - origin
        d /= np.linalg.norm(d, axis=1)[:, None]
        prim = np.zeros(n, np.int64)
        _cast(ks.scene.handle, ks.intersect, scratch.ctypes.data, origin, d, prim)
        hit = names[prim[prim >= 0]]
        mak, cor = np.sum(hit == "fauxPlafondInf"), np.sum(np.char.startswith(hit.astype(str), "corniche"))
        out[strip] = (mak, cor)
    return out


def strip_chamber(makrolon_strips):
    """The full chamber where the Makrolon wins in ``makrolon_strips`` and the cornices elsewhere."""
    rad = (validation.ANGERS / "geometry" / "testChamber.rad").read_text(encoding="latin-1")
    x0 = 0.0 if "AR" in makrolon_strips else 40.0
    x1 = 2400.0 if "AV" in makrolon_strips else 2360.0
    y0 = 0.0 if "D" in makrolon_strips else 40.0
    y1 = 1840.0 if "G" in makrolon_strips else 1800.0
    new = "Makrolon polygon fauxPlafondInf\n0\n0\n12\n%g %g 1970\n%g %g 1970\n%g %g 1970\n%g %g 1970" % (
        x0, y0, x1, y0, x1, y1, x0, y1)
    tmp = Path(tempfile.mkdtemp(prefix="lpy-light-tie-"))
    (tmp / "testChamber.rad").write_text(rad.replace(OLD, new), encoding="latin-1")
    remove = ["corniche" + s for s in makrolon_strips]
    return load_scene(validation.SEC2_SCENES["angers"].path, geometry=str(tmp / "testChamber.rad"),
                      remove=remove or None)


def run(chamber, args):
    ks = validation.kernel_scene(chamber, "nee", args.threads)
    res = simulate.run(ks, int(args.photons), seed=args.seed, threads=args.threads)
    p, s = res.sensors()
    return p[:, 0], s[:, 0], res.photons


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--photons", type=float, default=1e7)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    sec2 = reference.read_sec2(validation.SEC2_SCENES["angers"].sec2_path)
    moller = reference.read_sec2(validation.ANGERS / "reference-sec2" / "mesures_correctMoller.txt")

    print("1. Embree's choice (coplanar = arbitrary), rays from the lamps to each strip:")
    for strip, (mak, cor) in embree_choice().items():
        print("   %-3s Makrolon %5d, cornice %5d: Makrolon %.1f %%" % (strip, mak, cor, 100 * mak / (mak + cor)))

    print("2. Makrolon winning in these strips (cornices elsewhere), %g photons, vs mesures.txt:" % args.photons)
    runs = {}
    for strips in ((), ("G",), ("D",), ("AV",), ("AR",), ("G", "D", "AV", "AR")):
        runs[strips] = run(strip_chamber(strips), args)
        print("   %-14s %s" % ("+".join(strips) or "none", reference.compare(*runs[strips], sec2).line()))

    print("3. Mixing 'none' and 'all' in proportion f (f = share of hits on the Makrolon):")
    (p0, s0, n), (p1, s1, _) = runs[()], runs[("G", "D", "AV", "AR")]
    for f in (0.0, 0.25, 0.5, 0.58, 0.76, 1.0):
        p, s = (1 - f) * p0 + f * p1, np.sqrt((1 - f) * s0 ** 2 + f * s1 ** 2)
        print("   f = %.2f  mesures.txt: %s" % (f, reference.compare(p, s, n, sec2).line()))
        print("             correctMoller: %s" % reference.compare(p, s, n, moller).line())

    print("4. Sensors counted from both sides (default physics):")
    for scene in ("angers", "angers-sansmakrolon"):
        chamber = validation.load(scene)
        up = chamber.sensors
        chamber.sensors = Sensors.concat([up, dataclasses.replace(up, normal=-up.normal)])
        p, s, n = run(chamber, args)
        ref = reference.read_sec2(validation.SEC2_SCENES[scene].sec2_path)
        S = len(up)
        print("   %-20s front only: %s" % (scene, reference.compare(p[:S], s[:S], n, ref).line()))
        print("   %-20s both sides: %s" % (scene, reference.compare(p[:S] + p[S:], np.hypot(s[:S], s[S:]), n,
                                                                   ref).line()))


if __name__ == "__main__":
    main()
