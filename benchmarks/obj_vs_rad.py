"""The Angers chamber from its OBJ against the same chamber from its .rad, sensor by sensor.

``obj/testChamber.obj`` was written by photon_mapping from ``geometry/testChamber.rad``; compared
primitive by primitive (``tests/test_sec2_scenes.py::test_angers_obj_is_the_rad_but_three_differences``)
it is the same geometry but for three things:

* ``anchor`` — a 130 × 120 mm ``substrat`` plate at z = 980.5 mm, facing up, only in the OBJ (it is in
  SEC2's original ``testChamber_original.rad``, not in the ``testChamber.rad`` of the references);
* ``refcaissonY0a`` / ``refcaissonY0n`` — the .rad has two copies of each name (lamp-box end walls at
  x = 50 and x = 2350 mm); the OBJ keeps only the x = 2350 pair (photon_mapping keyed shapes by name);
* the four lamps ``lamp2xStr`` — zero-area strips in the OBJ; they come from ``obj/lamps.rad``.

Each configuration runs ``--batches`` independent seeds of ``--nee`` photons, against ``angers`` run the
same way:

* ``as-is``: ``angers-obj`` as shipped;
* ``anchor only``: the two lost walls restored (``anchor`` is the one difference left);
* ``walls only``: ``anchor`` removed (the lost walls are the one difference left);
* ``same geometry``: both.

Prints, per configuration: the total over the sensors, (OBJ − RAD)/RAD, with its σ from the spread of
the batches (the sensors of one run are correlated: the σ of a mean over them is not the σ of one sensor
over √240), the rms and largest per-sensor |z| (z = Δ / √(σ_obj² + σ_rad²)), how many sensors have
|z| > 4, and the sensors with |z| > 3.

    python benchmarks/obj_vs_rad.py [--photons 1e7] [--batches 5]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lpy_light.run import simulate  # noqa: E402
from lpy_light.chamber.scene import load_scene  # noqa: E402

ANGERS = ROOT / "lpy_light" / "data" / "angers-chamber"


def missing_walls_rad() -> str:
    """Radiance text of the x = 50 mm copies of ``refcaissonY0a``/``refcaissonY0n`` (the first of each name in
    testChamber.rad), with their material, which the OBJ lost."""
    from lpy_light.chamber.radiance import read_rad
    prims = read_rad(ANGERS / "geometry" / "testChamber.rad")
    material = next(p for p in prims if p.identifier == "MiroirCaissonLampes")
    walls = [next(p for p in prims if p.identifier == name) for name in ("refcaissonY0a", "refcaissonY0n")]
    out = "void %s %s\n0\n0\n%d %s\n\n" % (material.type, material.identifier, len(material.reals),
                                          " ".join(repr(x) for x in material.reals))
    for w in walls:
        assert w.reals[0] == 50.0, w.reals    # the copy the OBJ lost
        out += "%s polygon %s\n0\n0\n%d %s\n\n" % (w.modifier, w.identifier, len(w.reals), " ".join(repr(x) for x in w.reals))
    return out


def obj_scene(folder: Path, restore_walls: bool, remove_anchor: bool) -> Path:
    """A scene file for the OBJ chamber in ``folder``: as shipped, or with the lost walls restored and/or
    ``anchor`` removed."""
    geometry = ['"%s"' % (ANGERS / "obj" / "lamps.rad")]
    if restore_walls:
        (folder / "missing.rad").write_text(missing_walls_rad())
        geometry.append('"missing.rad"')
    geometry.append('"%s"' % (ANGERS / "obj" / "testChamber.obj"))
    text = ("geometry = [%s]\nsensors = \"%s\"\nunit = \"mm\"\noptical = \"%s\"\nspecularities = \"%s\"\n"
            "bands = [[655, 665]]\n%s" % (", ".join(geometry), ANGERS / "sensors" / "captors_expe1.csv",
                                          ANGERS / "optical", ANGERS / "optical" / "Specularities.xlsx",
                                          'remove = ["anchor"]\n' if remove_anchor else ""))
    path = folder / ("obj-%d%d.toml" % (restore_walls, remove_anchor))
    path.write_text(text)
    return path


def run(path, photons, seed):
    chamber = load_scene(path)
    result = simulate.run(simulate.KernelScene(chamber, estimator="nee"), photons, seed=seed, threads=2)
    photons_, std = result.sensors()
    return photons_[:, 0], std[:, 0]


def batches(path, photons, k, seed):
    """``k`` independent runs of ``photons``: (k, S) photons per sensor and their σ."""
    runs = [run(path, photons, seed + i) for i in range(k)]
    return np.array([r[0] for r in runs]), np.array([r[1] for r in runs])


def compare(obj, obj_std, rad, rad_std):
    """Figures of OBJ against RAD from batches (k, S) of each, the batches independent: the relative difference
    of the sensors' total and its σ (from the spread of the k batch pairs), per-sensor z of the batch means."""
    k = len(obj)
    a, b = obj.mean(axis=0), rad.mean(axis=0)
    sa, sb = np.sqrt((obj_std ** 2).sum(axis=0)) / k, np.sqrt((rad_std ** 2).sum(axis=0)) / k
    z = (a - b) / np.sqrt(sa ** 2 + sb ** 2)
    ratio = obj.sum(axis=1) / rad.sum(axis=1) - 1          # one value per batch pair
    return {"total_rel": float(ratio.mean()), "total_rel_std": float(ratio.std(ddof=1) / np.sqrt(k)),
            "rms_z": float(np.sqrt(np.mean(z ** 2))), "max_abs_z": float(np.abs(z).max()),
            "n_over_4": int((np.abs(z) > 4).sum()), "z": z}


CONFIGS = (("as-is", False, False), ("anchor only", True, False), ("walls only", False, True),
           ("same geometry", True, True))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--photons", type=float, default=1e7, help="photons per configuration (all batches)")
    parser.add_argument("--batches", type=int, default=5)
    args = parser.parse_args(argv)
    k = args.batches
    n = int(args.photons) // k
    centers = load_scene(ANGERS / "angers.toml").sensors.center
    rad, rad_std = batches(ANGERS / "angers.toml", n, k, seed=100)
    with tempfile.TemporaryDirectory() as tmp:
        for i, (label, walls, anchor) in enumerate(CONFIGS):
            obj, obj_std = batches(obj_scene(Path(tmp), walls, anchor), n, k, seed=200 + 100 * i)
            c = compare(obj, obj_std, rad, rad_std)
            far = np.flatnonzero(np.abs(c["z"]) > 3)
            print("%-14s %d x %d photons: sensors' total (OBJ - RAD)/RAD = %+.3f %% ± %.3f %%, rms z = %.2f, "
                  "max |z| = %.2f, %d of %d sensors with |z| > 4%s"
                  % (label, k, n, 100 * c["total_rel"], 100 * c["total_rel_std"], c["rms_z"], c["max_abs_z"],
                     c["n_over_4"], len(c["z"]), "".join("; z = %+.1f at (%g, %g, %g)" % ((c["z"][s],) + tuple(centers[s]))
                                                        for s in far)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
