"""Why the Angers references have the shape they have: the photon-mapping engine emulated from its source
(docs/validation.md, section 8).

The photon-mapping engine (github.com/minhlucky9/photon_mapping, the run in reference-photon-mapping/, made
at commit c67bdb7) is public, so what it did differently from lpy-light can be read and reproduced:

1. Its .rad reader (photonmap/Reader/ReadRADGeo.py) keeps the surfaces in a dict by name: of the two walls
   named refcaissonY0n / refcaissonY0a (lamp-box mirrors at x = 50 and x = 2350) only the last is kept.
   lpy-light reads the Angers scenes that way too (``[physics] repeated_names = "last"``).
2. It resolves the coplanar tie at z = 1970 (cornice tops / Makrolon, four 40 mm strips) by Embree's float32
   arithmetic and BVH order.  Printed here: the Makrolon's share per strip for rays from the lamps and from
   the lamp-box ceiling, in its scene (its triangles in its order, its 36-triangle sensor discs in the same
   geometry, build quality medium), and in the same scene without the discs (the share moves: an accident
   of traversal order wherever the two float32 distances are equal); then, for comparison, a textbook
   Möller-Trumbore test in float32 and float64 over the same triangles (how often the distances are equal).
3. Its discs are 36-triangle polygons, 0.5 % short of πr².

Then lpy-light's runs with the Makrolon winning in one strip (the cornices in the others), mixed with those
shares (f_G, f_D, f_AV, f_AR; the results are linear in them), scaled by 0.995 for the discs, are compared
with the engine's run: mean bias, χ² of the shape (240 sensors, both σ's; a scale fitted) and the change
across the rows and columns per plane -- with the fair choice (0.5 each, lpy-light's rule) for comparison,
and against SEC2.  Nothing is fitted: every number of the emulation comes from the engine's source.

    .venv/bin/python benchmarks/photon_mapping_emulation.py [--photons 2e7] [--threads 2]
"""
import argparse
import tempfile
from pathlib import Path

import numpy as np
from numba import njit

from lpy_light.report import reference, validation
from lpy_light.run import simulate
from lpy_light.kernel.embree import (ARGS, CAND_COUNT, DIR, GEOM_ID, INVALID_ID, MASK, ORG, PRIM_ID, RAYHIT, TFAR,
                                     TNEAR, EmbreeScene, intersect1_address, new_scratch)
from lpy_light.kernel.ptr import call_ptr3, load_u32, store_f32, store_i64, store_u32
from lpy_light.chamber.scene import load_scene

STRIPS = {"G": ((0, 2400), (1800, 1840)), "D": ((0, 2400), (0, 40)), "AV": ((2360, 2400), (0, 1840)),
          "AR": ((0, 40), (0, 1840))}
MAKROLON = ("Makrolon polygon fauxPlafondInf\n0\n0\n12\n0.0 0.0 1970\n2400.0 0.0 1970\n2400.0 1840.0 1970\n"
            "0.0 1840.0 1970")


def pm_triangles(path):
    """Triangles (n, 3, 3) and their surface names as photonmap/Reader/ReadRADGeo.py builds them: shapes in
    a dict by name (a repeated name keeps its first place and its last geometry), 4-gons as (0,1,2), (0,2,3),
    9-gons as a fan from vertex 0; light cylinders (zero-area quads there) left out."""
    lines = Path(path).read_text(encoding="latin-1").split("\n")
    materials, shapes = set(), {}
    i = 0
    while i < len(lines):
        w = lines[i].split()
        if len(w) >= 3 and w[0] == "void":
            materials.add(w[2])
        elif len(w) >= 3 and w[0] in materials and w[1] == "polygon":
            n = int(lines[i + 3]) // 3
            shapes[w[2]] = np.array([[float(x) for x in lines[i + 4 + k].split()[:3]] for k in range(n)])
            i += 4 + n
            continue
        i += 1
    tris, names = [], []
    for name, v in shapes.items():
        idx = [(0, k, k + 1) for k in range(1, len(v) - 1)] if len(v) == 9 else [(0, 1, 2), (0, 2, 3)]
        for t in idx:
            tris.append(v[list(t)])
            names.append(name)
    return np.array(tris), np.array(names)


def pm_discs(sensor_csv):
    """The engine's sensor discs: 36 triangles (k+1, k+2, centre) stepping 10° with π taken as 3.14285."""
    out = []
    step = 3.14285 / 180
    for x, y, z, r, *_ in np.loadtxt(sensor_csv, delimiter=",", skiprows=1):
        pts = np.array([(x, y, z), (x + r, y, z)] + [(x + r * np.cos((a + 10) * step), y + r * np.sin((a + 10) * step),
                                                      z) for a in range(0, 360, 10)])
        out.extend(pts[[k + 1, k + 2, 0]] for k in range(36))
    return np.array(out)


@njit(cache=False)     # not cached: numba would not see edits to the kernel functions it calls
def _cast(scene, fn, scratch, origins, dirs, out):
    """One Embree ray per origin (``rtcIntersect1`` through ``fn``): the primitive hit, or -1."""
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


def embree_shares(tris, names, lamps, n=20000, seed=0):
    """{source: {strip: Makrolon share}} for rays aimed at random points of each strip, Embree float32, back
    faces rejected, build quality medium (the engine's settings)."""
    from lpy_light.kernel import embree
    quality, embree._BUILD_QUALITY_HIGH = embree._BUILD_QUALITY_HIGH, 1      # RTC_BUILD_QUALITY_MEDIUM
    try:
        scene = EmbreeScene(one_sided=tris)
    finally:
        embree._BUILD_QUALITY_HIGH = quality
    scratch = new_scratch()
    rng = np.random.default_rng(seed)
    out = {}
    for source in ("lamps", "ceiling"):
        out[source] = {}
        for strip, ((x0, x1), (y0, y1)) in STRIPS.items():
            target = np.c_[rng.uniform(x0, x1, n), rng.uniform(y0, y1, n), np.full(n, 1970.0)]
            if source == "lamps":
                k = rng.integers(0, len(lamps), n)
                origin = lamps[k, 0] + (lamps[k, 1] - lamps[k, 0]) * rng.random((n, 1))
            else:
                origin = np.c_[rng.uniform(25, 2375, n), rng.uniform(25, 1815, n), np.full(n, 2179.9)]
            d = target - origin
            d /= np.linalg.norm(d, axis=1)[:, None]
            prim = np.zeros(n, np.int64)
            _cast(scene.handle, intersect1_address(), scratch.ctypes.data, origin, d, prim)
            hit = names[prim[prim >= 0]].astype(str)
            mak, cor = np.sum(hit == "fauxPlafondInf"), np.sum(np.char.startswith(hit, "corniche"))
            out[source][strip] = mak / (mak + cor)
    scene.close()
    return out


def moller_trumbore_shares(tris, names, lamps, dtype, n=100000, seed=1):
    """{source: {strip: (Makrolon share, share of equal distances)}} for a textbook Möller-Trumbore test in
    ``dtype`` over the tie's triangles in file order, back faces rejected, the first of equal distances kept
    (strict ``<``): one guess at what an engine without Embree, such as SEC2, does."""
    sel = np.isin(names, ["cornicheG", "cornicheD", "cornicheAV", "cornicheAR", "fauxPlafondInf"])
    tri, nm = tris[sel].astype(dtype), names[sel]
    rng = np.random.default_rng(seed)
    out = {}
    for source in ("lamps", "ceiling"):
        out[source] = {}
        for strip, ((x0, x1), (y0, y1)) in STRIPS.items():
            target = np.c_[rng.uniform(x0, x1, n), rng.uniform(y0, y1, n), np.full(n, 1970.0)]
            if source == "lamps":
                k = rng.integers(0, len(lamps), n)
                o = lamps[k, 0] + (lamps[k, 1] - lamps[k, 0]) * rng.random((n, 1))
            else:
                o = np.c_[rng.uniform(25, 2375, n), rng.uniform(25, 1815, n), np.full(n, 2179.9)]
            d = target - o
            d /= np.linalg.norm(d, axis=1)[:, None]
            o, d = o.astype(dtype), d.astype(dtype)
            ts = []
            for v0, v1, v2 in tri:
                e1, e2 = v1 - v0, v2 - v0
                p = np.cross(d, e2)
                det = (e1 * p).sum(-1)
                tv = o - v0
                u = (tv * p).sum(-1)
                q = np.cross(tv, e1)
                v = (d * q).sum(-1)
                t = (e2 * q).sum(-1) * (dtype(1) / det)
                ts.append(np.where((det > 0) & (u >= 0) & (u <= det) & (v >= 0) & (u + v <= det), t, np.inf))
            ts = np.array(ts)
            best, who = np.full(n, np.inf), np.full(n, -1)
            for i in range(len(tri)):
                better = ts[i] < best
                best, who = np.where(better, ts[i], best), np.where(better, i, who)
            hit = nm[who[who >= 0]]
            mak = ts[nm == "fauxPlafondInf"].min(axis=0)
            cor = ts[nm != "fauxPlafondInf"].min(axis=0)
            out[source][strip] = (np.mean(hit == "fauxPlafondInf"), np.mean(mak == cor))
    return out


def strip_run(strip, photons, threads, seed):
    """Per-photon sensor counts (S,), σ (S,) of the full chamber with the Makrolon winning in ``strip`` only
    (None: nowhere) and the cornices elsewhere."""
    rad = (validation.ANGERS / "geometry" / "testChamber.rad").read_text(encoding="latin-1")
    x0, x1 = (0 if strip == "AR" else 40), (2400 if strip == "AV" else 2360)
    y0, y1 = (0 if strip == "D" else 40), (1840 if strip == "G" else 1800)
    new = "Makrolon polygon fauxPlafondInf\n0\n0\n12\n%g %g 1970\n%g %g 1970\n%g %g 1970\n%g %g 1970" % (
        x0, y0, x1, y0, x1, y1, x0, y1)
    tmp = Path(tempfile.mkdtemp(prefix="lpy-light-pm-")) / "testChamber.rad"
    tmp.write_text(rad.replace(MAKROLON, new), encoding="latin-1")
    chamber = load_scene(validation.SEC2_SCENES["angers"].path, geometry=str(tmp),
                         remove=["corniche" + strip] if strip else None)
    ks = validation.kernel_scene(chamber, "nee", threads)
    res = simulate.run(ks, int(photons), seed=seed, threads=threads)
    p, s = res.sensors()
    return p[:, 0] / res.photons, s[:, 0] / res.photons


def report(label, m, s, refs, chamber):
    for name, ref in refs:
        y, sy = ref.photons / ref.n_photons, ref.photons_std / ref.n_photons
        s2 = sy ** 2 + s ** 2
        k = np.sum(m * y / s2) / np.sum(m * m / s2)
        chi2 = np.sum((y - k * m) ** 2 / s2)
        bias = reference.compare(m, s, 1.0, ref).bias
        changes = []
        for across in (1, 0):
            for p in reference.row_profiles(m, s, ref, chamber.sensors.center, chamber.sensors.normal, across=across):
                changes.append("%s along %s %+.2f%% ± %.2f%%" % (p.plane, p.axis, 100 * p.slope, 100 * p.slope_std))
        print("  %-44s vs %-14s bias %+.2f%%  shape χ² %4.0f  %s" % (label, name, 100 * bias, chi2, "; ".join(changes)))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--photons", type=float, default=2e7)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    rad = validation.ANGERS / "geometry" / "testChamber.rad"
    tris, names = pm_triangles(rad)
    from lpy_light.chamber.radiance import read_rad
    polygons = [p for p in read_rad(rad) if p.type == "polygon"]
    lost = [p for p in polygons if not any(np.array_equal(np.reshape(p.reals, (-1, 3))[:3], t[:3]) for t in
                                           tris[names == p.identifier])]
    print("1. The engine's reading keeps %d of the file's %d polygons; lost: %s" % (
        len(set(names)), len(polygons), ", ".join("%s (%s, x = %g)" % (p.identifier, p.where.split("/")[-1],
                                                                       p.reals[0]) for p in lost)))
    chamber = validation.load("angers")
    lamps = np.array([(d[0], d[1]) for d in chamber.emitters.data])      # line lamps: end points
    discs = pm_discs(validation.ANGERS / "sensors" / "captors_expe1.csv")
    shares = {}
    print("2. Makrolon's share of the tie per strip (Embree float32, the engine's triangles and order):")
    for label, t, nm in (("its scene (chamber + 240 discs)", np.concatenate([tris, discs]),
                          np.r_[names, np.full(len(discs), "captor")]), ("the chamber alone", tris, names)):
        sh = embree_shares(t, nm, lamps)
        for source, per in sh.items():
            print("   %-32s rays from the %-7s %s" % (label, source, "  ".join("%s %.2f" % kv for kv in per.items())))
        shares.setdefault(label, sh)
    scene_shares = shares["its scene (chamber + 240 discs)"]
    f_pm = {s: 0.5 * (scene_shares["lamps"][s] + scene_shares["ceiling"][s]) for s in STRIPS}
    print("   used below (mean of the two ray sources): %s" % "  ".join("f_%s %.2f" % kv for kv in f_pm.items()))

    for dtype in (np.float32, np.float64):
        print("   textbook Möller-Trumbore in %s, file order, first of equal distances kept:" % dtype.__name__)
        for source, per in moller_trumbore_shares(tris, names, lamps, dtype).items():
            print("   %-32s rays from the %-7s %s" % ("", source, "  ".join(
                "%s %.2f (equal %.2f)" % (k, a, b) for k, (a, b) in per.items())))

    print("3. lpy-light, %g photons per run (the Makrolon winning in no strip, then in each one):" % args.photons)
    base, base_s = strip_run(None, args.photons, args.threads, args.seed)
    col = {}
    for strip in STRIPS:
        col[strip] = strip_run(strip, args.photons, args.threads, args.seed)
    sec2 = reference.read_sec2(validation.SEC2_SCENES["angers"].sec2_path)
    pm = reference.read_photon_mapping(validation.PHOTON_MAPPING)
    refs = [("photon mapping", pm), ("SEC2", sec2)]

    def mix(f):     # base + Σ f_k (run_k - base); the runs share their random numbers (one seed), so the
        m = base + sum(f[k] * (col[k][0] - base) for k in STRIPS)     # differences are nearly noiseless and the
        return m, base_s                                                 # mixture has the base run's σ
    m, s = mix({k: 0.5 for k in STRIPS})
    report("fair choice (lpy-light)", m, s, refs, chamber)
    m, s = mix(f_pm)
    report("the engine's ties", m, s, refs, chamber)
    report("the engine's ties, discs 0.5 % short", 0.995 * m, 0.995 * s, refs, chamber)

    print("4. For comparison only (a fit, not a reading): the share in strip G that each reference's counts "
          "alone prefer, the other strips fair (0.5):")
    fair = {k: 0.5 for k in STRIPS}
    m0, s0 = mix(fair)
    for name, ref, scale in (("SEC2", sec2, 1.0), ("photon mapping (discs 0.5 % short)", pm, 0.995)):
        y, sy = ref.photons / ref.n_photons, ref.photons_std / ref.n_photons
        w = 1 / (sy ** 2 + (scale * s0) ** 2)      # the level and the shape together
        g = scale * (col["G"][0] - base)
        r = y - scale * m0
        var = 1 / np.sum(w * g * g)
        print("   %-36s f_G = %.2f ± %.2f" % (name, 0.5 + var * np.sum(w * g * r), np.sqrt(var)))


if __name__ == "__main__":
    main()
