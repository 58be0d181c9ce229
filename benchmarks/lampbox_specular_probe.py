"""Probe: how the Angers scenes move with the lamp-box mirrors' specular fraction (docs/validation.md, section 5).

    .venv/bin/python benchmarks/lampbox_specular_probe.py [--fractions 0 0.2 0.4 1] [--photons 1e7]
"""
import argparse

from lpy_light.report import validation as V
from lpy_light.chamber.materials import DIFFUSE_R, SPECULAR_R


def mirrors(frac):
    """A patch setting the specular part of MiroirCaissonLampes to ``frac`` of its reflectance."""
    def f(chamber):
        for m in chamber.materials:
            if m.name == "MiroirCaissonLampes":
                R = m.events[DIFFUSE_R] + m.events[SPECULAR_R]
                m.events[SPECULAR_R] = R * frac
                m.events[DIFFUSE_R] = R * (1 - frac)
    return f


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--fractions", type=float, nargs="+", default=[0.0, 0.2, 0.4, 1.0])
    ap.add_argument("--photons", type=float, default=1e7)
    ap.add_argument("--scenes", nargs="+", default=["angers-sansmakrolon", "angers", "angers-sanstable"])
    args = ap.parse_args()
    for frac in args.fractions:
        name = "lamp-box mirrors s=%g" % frac
        V.VARIANTS[name] = V.Variant(name, patch=mirrors(frac))
        for scene in args.scenes:
            r = V.validate(scene, args.photons, variant=name)
            print("%-20s s = %-4g %s" % (scene, frac, r["sec2"].line()), flush=True)


if __name__ == "__main__":
    main()
