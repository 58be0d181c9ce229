"""The Angers chamber from its OBJ against the same chamber from its .rad, sensor by sensor.

``obj/testChamber.obj`` was written by photon_mapping from ``geometry/testChamber.rad``; compared
primitive by primitive (``tests/test_sec2_scenes.py::test_angers_obj_is_the_rad_but_three_differences``)
it is the same geometry but for three things:

* ``anchor`` — a 130 × 120 mm ``substrat`` plate at z = 980.5 mm, facing up, only in the OBJ (it is in
  SEC2's original ``testChamber_original.rad``, not in the ``testChamber.rad`` of the references);
* ``refcaissonY0a`` / ``refcaissonY0n`` — the .rad has two copies of each name (lamp-box end walls at
  x = 50 and x = 2350 mm); the OBJ keeps only the x = 2350 pair (photon_mapping keyed shapes by name);
* the four lamps ``lamp2xStr`` — zero-area strips in the OBJ; they come from ``obj/lamps.rad``.

Three runs of ``--estimator nee`` (independent seeds) are compared with ``angers``:

* ``as-is``: ``angers-obj`` as shipped;
* ``same geometry``: ``angers-obj`` with ``anchor`` removed and the two x = 50 walls added back.

Prints, per comparison: the mean of (OBJ − RAD)/RAD over the sensors with its σ, the rms and largest
|z| (z = Δ / √(σ_obj² + σ_rad²)), and how many sensors have |z| > 4.

    python benchmarks/obj_vs_rad.py [--photons 2e6]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from lpy_light import simulate  # noqa: E402
from lpy_light.scene import load_scene  # noqa: E402

ANGERS = ROOT / "lpy_light" / "data" / "angers-chamber"


def missing_walls_rad() -> str:
    """Radiance text of the x = 50 mm copies of ``refcaissonY0a``/``refcaissonY0n`` (the first of each name in
    testChamber.rad), with their material, which the OBJ lost."""
    from lpy_light.radiance import read_rad
    prims = read_rad(ANGERS / "geometry" / "testChamber.rad")
    material = next(p for p in prims if p.identifier == "MiroirCaissonLampes")
    walls = [next(p for p in prims if p.identifier == name) for name in ("refcaissonY0a", "refcaissonY0n")]
    out = "void %s %s\n0\n0\n%d %s\n\n" % (material.type, material.identifier, len(material.reals),
                                          " ".join(repr(x) for x in material.reals))
    for w in walls:
        assert w.reals[0] == 50.0, w.reals    # the copy the OBJ lost
        out += "%s polygon %s\n0\n0\n%d %s\n\n" % (w.modifier, w.identifier, len(w.reals), " ".join(repr(x) for x in w.reals))
    return out


def obj_scene(folder: Path, same_geometry: bool) -> Path:
    """A scene file for the OBJ chamber (as shipped, or with the .rad's geometry) in ``folder``."""
    geometry = ['"%s"' % (ANGERS / "obj" / "lamps.rad")]
    extra = ""
    if same_geometry:
        (folder / "missing.rad").write_text(missing_walls_rad())
        geometry.append('"missing.rad"')
        extra = 'remove = ["anchor"]\n'
    geometry.append('"%s"' % (ANGERS / "obj" / "testChamber.obj"))
    text = ("geometry = [%s]\nsensors = \"%s\"\nunit = \"mm\"\noptical = \"%s\"\nspecularities = \"%s\"\n"
            "bands = [[655, 665]]\n%s" % (", ".join(geometry), ANGERS / "sensors" / "captors_expe1.csv",
                                          ANGERS / "optical", ANGERS / "optical" / "Specularities.xlsx", extra))
    path = folder / ("same.toml" if same_geometry else "asis.toml")
    path.write_text(text)
    return path


def run(path, photons, seed):
    chamber = load_scene(path)
    result = simulate.run(simulate.KernelScene(chamber, estimator="nee"), photons, seed=seed, threads=2)
    photons_, std = result.sensors()
    return photons_[:, 0], std[:, 0]


def compare(a, sa, b, sb):
    """Figures of (a − b) for two independent runs: mean relative difference and its σ, rms |z|, max |z|."""
    z = (a - b) / np.sqrt(sa ** 2 + sb ** 2)
    rel = (a - b) / b
    rel_std = np.sqrt((sa / b) ** 2 + (a * sb / b ** 2) ** 2)
    mean, mean_std = rel.mean(), np.sqrt((rel_std ** 2).sum()) / len(rel)
    return {"mean_rel": mean, "mean_rel_std": mean_std, "rms_z": float(np.sqrt(np.mean(z ** 2))),
            "max_abs_z": float(np.abs(z).max()), "n_over_4": int((np.abs(z) > 4).sum()), "z": z, "rel": rel}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--photons", type=float, default=2e6)
    args = parser.parse_args(argv)
    n = int(args.photons)
    rad, rad_std = run(ANGERS / "angers.toml", n, seed=1)
    with tempfile.TemporaryDirectory() as tmp:
        for label, same, seed in (("as-is", False, 2), ("same geometry", True, 3)):
            obj, obj_std = run(obj_scene(Path(tmp), same), n, seed=seed)
            c = compare(obj, obj_std, rad, rad_std)
            print("%-14s %d photons: mean (OBJ - RAD)/RAD = %+.3f %% ± %.3f %%, rms z = %.2f, max |z| = %.2f, "
                  "%d of %d sensors with |z| > 4" % (label, n, 100 * c["mean_rel"], 100 * c["mean_rel_std"],
                                                      c["rms_z"], c["max_abs_z"], c["n_over_4"], len(obj)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
