"""Could one material parameter explain the Angers variants that disagree with SEC2?

docs/validation.md, section 5: the chamber without the Makrolon ceiling is ~1.8 % below SEC2 and the
chamber without the table ~0.9 % above it, while the full chamber agrees.  This script asks whether a
single measured optical value being off (in our tables, or in what SEC2 used) could explain the three
scenes at once.  For each material and each of its parameters it perturbs that parameter alone —
reflectance R × 1.1, specular fraction s + 0.2 (clipped to [0, 1]), for the Makrolon also T × 1.05 —
runs the three scenes (same seed as the unperturbed run) and records every sensor.  Then it fits
SEC2's residuals (in σ units, 720 sensors) with each perturbation alone and with every pair, by least
squares, and prints the χ² each leaves and the coefficient it needs (1 = the perturbation above).

    .venv/bin/python benchmarks/material_sensitivity.py [--photons 1e7] [--out runs/material_sensitivity.npz]

About 50 runs: ~10-13 min at 1e7 photons on 2 threads.  Prints one line per run, then the fits.
"""
import argparse
import itertools

import numpy as np

from lpy_light.report import reference, validation as V
from lpy_light.chamber.materials import ABSORB, DIFFUSE_R, DIFFUSE_T, SPECULAR_R, SPECULAR_T

SCENES = ["angers", "angers-sansmakrolon", "angers-sanstable"]
#: the materials of testChamber.rad that cover a surface (those with none change nothing)
MATERIALS = ["Aquanappe", "CentrePlafond", "CorniereAlu", "MiroirCaissonLampes", "Sol", "MurBlanc", "MurMetal",
             "Makrolon"]


def perturb(material: str, param: str):
    """A chamber patch changing one parameter of one material, keeping the others."""
    def patch(chamber):
        for m in chamber.materials:
            if m.name != material:
                continue
            e = m.events
            R = e[DIFFUSE_R] + e[SPECULAR_R]
            s = np.divide(e[SPECULAR_R], R, out=np.zeros_like(R), where=R > 0)
            if param == "R":
                R = R * 1.1
            elif param == "s":
                s = np.clip(s + 0.2, 0.0, 1.0)
            elif param == "T":
                e[DIFFUSE_T] *= 1.05
            e[DIFFUSE_R], e[SPECULAR_R] = R * (1 - s), R * s
            e[ABSORB] = 1 - e[DIFFUSE_R] - e[SPECULAR_R] - e[DIFFUSE_T] - e[SPECULAR_T]
            if (e[ABSORB] < -1e-12).any():
                raise ValueError("%s %s: reflectance + transmittance above 1" % (material, param))
    return patch


def variants():
    yield "default", None
    for m in MATERIALS:
        for p in ("R", "s") + (("T",) if m == "Makrolon" else ()):
            yield "%s:%s" % (m, p), perturb(m, p)


def run_all(photons: float, out: str) -> dict:
    counts = {}
    for name, patch in variants():
        if patch is not None:
            V.VARIANTS[name] = V.Variant(name, patch=patch)
        for scene in SCENES:
            if name.startswith("Makrolon") and scene == "angers-sansmakrolon":
                continue
            r = V.validate(scene, photons, variant=name)
            ph, sd = r["result"].sensors()
            counts[name + "|" + scene] = np.stack([ph[:, 0], sd[:, 0]]) / r["result"].photons
            print("%-24s %-20s %s" % (name, scene, r["sec2"].line()), flush=True)
            np.savez(out, **counts)
    return counts


def fit(counts: dict) -> None:
    refs = {s: reference.read_sec2(V.SEC2_SCENES[s].sec2_path) for s in SCENES}

    def relative(name, s):
        return counts[name + "|" + s][0] * refs[s].n_photons / refs[s].photons - 1

    sigma = {s: np.hypot(counts["default|" + s][1] * refs[s].n_photons, refs[s].photons_std) / refs[s].photons
             for s in SCENES}
    need = np.concatenate([-relative("default", s) / sigma[s] for s in SCENES])
    names = sorted({k.split("|")[0] for k in counts} - {"default"})
    cols = {n: np.concatenate([(relative(n, s) - relative("default", s)) / sigma[s] for s in SCENES])
            for n in names if all(n + "|" + s in counts for s in SCENES)}
    print("\nresiduals vs SEC2 over %d sensors: chi2 %.0f unperturbed" % (len(need), need @ need))
    print("%-24s %s   %-6s %s" % ("perturbation", "mean change per scene (%): " + " ".join(SCENES), "coef", "chi2"))
    for n, c in cols.items():
        a = c @ need / (c @ c)
        means = [100 * float(np.mean(relative(n, s) - relative("default", s))) for s in SCENES]
        print("%-24s %s   %+6.2f %.0f" % (n, " ".join("%+6.2f" % m for m in means), a, ((need - a * c) ** 2).sum()))
    pairs = []
    for pair in itertools.combinations(cols, 2):
        A = np.stack([cols[p] for p in pair], 1)
        x, *_ = np.linalg.lstsq(A, need, rcond=None)
        pairs.append((float(((need - A @ x) ** 2).sum()), pair, x))
    print("\nbest pairs (chi2, perturbations, coefficients):")
    for chi2, pair, x in sorted(pairs, key=lambda t: t[0])[:8]:
        print("%.0f  %s  %s" % (chi2, " + ".join(pair), np.round(x, 2)))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--photons", type=float, default=1e7)
    ap.add_argument("--out", default="runs/material_sensitivity.npz")
    ap.add_argument("--fit-only", action="store_true", help="refit the counts saved in --out")
    args = ap.parse_args()
    if args.fit_only:
        counts = dict(np.load(args.out))
    else:
        counts = run_all(args.photons, args.out)
    fit(counts)


if __name__ == "__main__":
    main()
