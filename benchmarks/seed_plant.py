"""The seed's plant run (the report's section 3.4) redone, and what explains each difference.

The report lit the rose group's own model, ``lsystems/rose-simple4.lpy`` (unchanged), derived over its 150
steps and placed at (1280, 860, 980) mm in the Angers chamber, with 1e7 photons in each of two bands (600-655
and 655-665 nm), and wrote the photons each organ received
(``lpy_light/data/angers-chamber/reference-seed-plant/face_captor_res.csv.csv``; id = the organ module's index
in the lstring).  This script derives the same model with the real L-Py, lights it with :class:`LightModel` in
the built-in scene ``angers-seed-plant`` (those two bands, that position) and compares per organ kind and per
organ, both as photon hits per 1e7 photons emitted in the band (our ``photons``: the expected hits on an organ
for the photons emitted; the seed's: every arrival of a photon on an organ's triangle, counted one by one).

Variants, each adding one of the seed's choices to the previous one:

* ``ours``       — our physics: organs two-sided, the Angers leaf tables (leaves ``FeuilleVieille_Sup`` /
  ``_Inf``; stems and buds that green tissue, opaque; the flower ``FeuilleVieille_Sup``);
* ``one-sided``  — organs seen from their front only (``LightModel(one_sided_organs=True)``): the seed's run
  culled back faces (``simulation.ini``: ``$BACKFACE_CULLING yes``), so a photon reaching an organ's back face
  went through it, uncounted;
* ``mapping``    — the seed's organ mapping: ``LoadCaptor.addFaceCaptors`` maps its face ids to organs with
  ``for j in triangles: dict[lastTriangleId + j] = captor_id`` where ``triangles`` is the flattened index list,
  so it maps ids ``lastTriangleId + vertex index``: a shape's first n_vertices triangles, not its n_triangles
  (the rest count for no organ, or for an earlier shape whose vertices outnumber its triangles);
* ``seed``       — the seed's organ materials: an L-Py colour's ambient red / 255 as a diffuse reflectance,
  opaque (``Captor.getOpticalProperties``; the default palette's specular is 0, transparency 0).

The model's phyllotaxy is random (``uniform(-20, 20)`` degrees per node, unseeded), so the seed's plant is one
draw that cannot be re-derived: ``--plants`` draws are lit (``random.seed(k)``), and σ plant, the spread of one
plant about their mean, enters the comparison beside our σ and the seed's Poisson σ.

    .venv-lpy/bin/python benchmarks/seed_plant.py [--photons 1000000] [--plants 4] [--threads 2] [--organs]
"""
from __future__ import annotations

import argparse
import csv
import logging
import math
import random
import time
from pathlib import Path

import numpy as np

from lpy_light.report import reference
from lpy_light.run import simulate
from lpy_light.plant.light import LightModel
from lpy_light.plant.organs import organ_from_mesh
from lpy_light.chamber.scene import load_scene, resolve_scene

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "lsystems" / "rose-simple4.lpy"
SEED_RESULT = ROOT / "lpy_light" / "data" / "angers-chamber" / "reference-seed-plant" / "face_captor_res.csv.csv"
SEED_SENSORS = SEED_RESULT.with_name("virtual_captor_res_2aba3d5.csv.csv")
SEED_PHOTONS = 1e7                       # per band ($NB_PHOTONS 10000000)
POSITION = (1280.0, 860.0, 980.0)        # mm (planglRadScene.py)
KINDS = ("Leaf", "Internode", "Bud", "Flower")
MATERIALS = {"Leaf": ("FeuilleVieille_Sup", "FeuilleVieille_Inf"),
             "Internode": {"reflectance": "FeuilleVieille_Sup"},
             "Bud": {"reflectance": "FeuilleVieille_Sup"},
             "Flower": "FeuilleVieille_Sup"}
VARIANTS = ("ours", "one-sided", "mapping", "seed")
UNCOUNTED = " (uncounted)"               # module suffix of the triangles the seed's mapping gives no organ


def read_seed(path=SEED_RESULT) -> dict:
    """``{id: (2,) counts}`` of the seed's file (columns id, N_sim_600_655, N_sim_655_665)."""
    with open(path, newline="") as fh:
        return {int(r["id"]): np.array([float(r["N_sim_600_655"]), float(r["N_sim_655_665"])])
                for r in csv.DictReader(fh)}


def read_seed_sensors(path=SEED_SENSORS) -> list:
    """The seed's earlier run's 240 sensors (``captors_expe1``), one :class:`Reference` per band."""
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    out = []
    for column in ("N_sim_600_655", "N_sim_655_665"):
        counts = np.array([float(r[column]) for r in sorted(rows, key=lambda r: int(r["id"]))])
        out.append(reference.Reference(counts, np.sqrt(counts), SEED_PHOTONS, "%s:%s" % (path.name, column)))
    return out


def sensors_check(model, photons, threads, seed):
    """Our 240 sensors with the plant in place (next events on), against the seed's earlier run: a
    :class:`Comparison` per band.  Checks that a photon emitted means the same in both engines, in both bands."""
    ks = model.kscene
    ks.configure(sensors=True)
    ks.retarget()
    try:
        result = simulate.run(ks, photons, seed=seed + 104729, threads=threads)
    finally:
        ks.configure(sensors=False)
        ks.retarget()
    ours, std = result.sensors()
    return [reference.compare(ours[:, b], std[:, b], result.photons, ref) for b, ref in enumerate(read_seed_sensors())]


def derive(plant: int):
    """The model derived over its derivation length with ``random.seed(plant)``, interpreted and tessellated.

    Returns ``(shapes, modules)``: shapes in the scene's order (the order the seed added them), each
    ``(id, vertices (v, 3) cm, faces (f, 3), ambient red / 255)``; modules ``{id: module name}``.
    """
    import openalea.plantgl.all as pgl
    from openalea.lpy import Lsystem

    from lpy_light.plant.lpy import _points

    random.seed(plant)
    lsystem = Lsystem(str(MODEL))
    lstring = lsystem.derive(lsystem.axiom, lsystem.derivationLength)
    lscene = lsystem.sceneInterpretation(lstring)
    shapes, modules = [], {}
    tess = pgl.Tesselator()
    for shape in lscene:
        shape.apply(tess)
        mesh = tess.result
        faces = np.array([tuple(f) for f in mesh.indexList], dtype=np.int64).reshape(-1, 3)
        shapes.append((shape.id, _points(mesh.pointList), faces, shape.appearance.ambient.red / 255.0))
        modules[shape.id] = lstring[shape.id].name
    return shapes, modules


def seed_attribution(shapes) -> tuple:
    """Which organ the seed counted each triangle for: ``(per shape (f,) int64 ids, -1 for none), spill``.

    ``LoadCaptor.addFaceCaptors`` (commit 56c5fab), shape after shape::

        for j in triangles:            # the flattened index list: vertex indices
            face_captor_triangle_dict[lastTriangleId + j] = captor.captor_id
        lastTriangleId = scene.nFaces()

    ``spill`` counts the ids mapped past the last shape's last triangle: in the seed's scene the sensors'
    triangles come next, and a photon crossing one would have counted for that organ.
    """
    face_of, base = {}, 0
    for sid, _, faces, _ in shapes:
        for j in faces.reshape(-1):
            face_of[base + int(j)] = sid
        base += len(faces)
    out, base = [], 0
    for _, _, faces, _ in shapes:
        out.append(np.array([face_of.get(base + i, -1) for i in range(len(faces))], dtype=np.int64))
        base += len(faces)
    return out, sum(1 for k in face_of if k >= base)


def organs_of(model, shapes, modules, variant):
    """The organs of one variant (chamber units): one per module id, plus, with the seed's mapping, the triangles
    it counted for no organ (module ``'<name> (uncounted)'``: in the scene, shading only)."""
    groups = {}
    attribution = seed_attribution(shapes)[0] if variant in ("mapping", "seed") else None
    for s, (sid, vertices, faces, red) in enumerate(shapes):
        module = modules[sid]
        material = {"reflectance": round(red, 6), "transmittance": 0.0} if variant == "seed" else MATERIALS[module]
        front, back = model._materials_of(material)
        owners = np.full(len(faces), sid) if attribution is None else attribution[s]
        for owner in np.unique(owners):
            key = (int(owner), module, front, back) if owner >= 0 else (sid, module + UNCOUNTED, front, back)
            groups.setdefault(key, []).append((vertices, faces[owners == owner]))
    organs = []
    for (owner, module, front, back), parts in groups.items():
        v = np.concatenate([p[0] for p in parts])
        offsets = np.cumsum([0] + [len(p[0]) for p in parts[:-1]])
        f = np.concatenate([p[1] + o for p, o in zip(parts, offsets)])
        organs.append(organ_from_mesh((owner, module, front), (v, f), (front, back), module, model.scale,
                                      model.position))
    return organs


def light(models, shapes, modules, variant):
    """``{id: (photons (2,), σ (2,))}`` per 1e7 photons emitted in each band, and the run's seconds."""
    model = models["one" if variant != "ours" else "two"]
    with model.warnings_once():
        organs = organs_of(model, shapes, modules, variant)
        step = model.run(organs)
    k = SEED_PHOTONS / step.photons
    per_id = {}
    for (owner, module, _), lit in step.organs.items():
        if module.endswith(UNCOUNTED):
            continue
        x, s = per_id.get(owner, (np.zeros(2), np.zeros(2)))
        per_id[owner] = (x + k * lit.photons, np.sqrt(s ** 2 + (k * lit.photons_std) ** 2))
    return per_id, step.seconds


def make_models(photons, threads, seed):
    chamber = load_scene(resolve_scene("angers-seed-plant"))
    common = dict(organs=MATERIALS, photons=photons, seed=seed, threads=threads, plant_unit="cm",
                  position=POSITION, parameter=None, lamp_flux=np.ones(chamber.n_bands), targets=KINDS)
    return {"two": LightModel(chamber, **common), "one": LightModel(chamber, one_sided_organs=True, **common)}


def collect(photons=1_000_000, plants=4, threads=None, seed=1, variants=VARIANTS, progress=print, check_sensors=True):
    """Light ``plants`` draws of the model in each variant.

    Returns ``{"modules": {id: name}, "results": {variant: [per plant {id: (photons, σ)}]}, "seconds": ...,
    "spill": [...], "counted_area": {kind: share}}``.
    """
    models = make_models(photons, threads, seed)
    results = {v: [] for v in variants}
    seconds = {v: 0.0 for v in variants}
    spill, counted = [], {}
    modules = down = None
    for plant in range(plants):
        shapes, modules = derive(plant)
        if down is None:
            down = facing(shapes, modules)
        spill.append(seed_attribution(shapes)[1])
        _counted_area(shapes, modules, counted)
        for v in variants:
            per_id, s = light(models, shapes, modules, v)
            results[v].append(per_id)
            seconds[v] += s
            if progress:
                progress("  plant %d, %-9s %5.1f s" % (plant, v, s))
    share = {k: a[0] / a[1] for k, a in counted.items()}
    sensors = sensors_check(models["one"], photons, threads, seed) if check_sensors else None
    return {"modules": modules, "results": results, "seconds": seconds, "spill": spill, "counted_area": share,
            "sensors": sensors, "facing_down": down}


def facing(shapes, modules) -> dict:
    """Per organ kind: (area projected on the floor whose front faces down, whole projected area), cm².

    The seed's culling hides an organ's back faces: light from the lamps above meets the front of a
    surface facing up, the back of one facing down."""
    out = {}
    for sid, v, f, _ in shapes:
        tri = v[f]
        nz = 0.5 * np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])[:, 2]    # projected area, signed
        a = out.setdefault(modules[sid], [0.0, 0.0])
        a[0] += -nz[nz < 0].sum()
        a[1] += np.abs(nz).sum()
    return out


def _counted_area(shapes, modules, acc):
    """Add, per organ kind, (area the seed's mapping counts, total area) of these shapes to ``acc``."""
    attribution = seed_attribution(shapes)[0]
    for (sid, v, f, _), owner in zip(shapes, attribution):
        tri = v[f]
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        a = acc.setdefault(modules[sid], [0.0, 0.0])
        a[0] += area[owner == sid].sum()
        a[1] += area.sum()


def kind_totals(per_plant, modules, ids, bands=(0, 1)):
    """Per kind: (mean over plants, σ of that mean, σ plant, our σ of one plant) of the sum over ``ids`` of
    that kind and over ``bands``.  Our σ of a sum over bands is taken as if the bands were fully correlated
    (they share their photons): an upper bound."""
    out = {}
    for kind in KINDS:
        members = [i for i in ids if modules[i] == kind]
        totals = np.array([sum(p[i][0][list(bands)].sum() for i in members) for p in per_plant])
        ours = np.array([math.sqrt(sum(p[i][1][list(bands)].sum() ** 2 for i in members)) for p in per_plant])
        spread = totals.std(ddof=1) if len(totals) > 1 else math.nan
        out[kind] = (totals.mean(), spread / math.sqrt(len(totals)) if len(totals) > 1 else ours[0],
                     spread, float(np.sqrt(np.mean(ours ** 2))))
    return out


def compare(mean, sigma_mean, sigma_plant, seed):
    """ratio, its σ, and z of ``mean`` against one plant's seed count (Poisson σ √seed, one plant's spread)."""
    s_seed = math.sqrt(seed)
    plant = sigma_plant if math.isfinite(sigma_plant) else 0.0
    sigma = math.sqrt(sigma_mean ** 2 + plant ** 2 + s_seed ** 2)
    ratio = mean / seed if seed > 0 else math.nan
    r_sigma = ratio * math.sqrt((math.sqrt(sigma_mean ** 2 + plant ** 2) / mean) ** 2 + (s_seed / seed) ** 2) \
        if seed > 0 and mean > 0 else math.nan
    return ratio, r_sigma, (mean - seed) / sigma


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--photons", type=float, default=1e6, help="photons per run (each variant, each plant)")
    ap.add_argument("--plants", type=int, default=4, help="draws of the model's random phyllotaxy")
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--seed", type=int, default=1, help="seed of our photons")
    ap.add_argument("--organs", action="store_true", help="also print every organ (ours and one-sided)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="lpy-light: %(message)s")

    t0 = time.perf_counter()
    got = collect(int(args.photons), args.plants, args.threads, args.seed)
    seed = read_seed()
    modules, results = got["modules"], got["results"]
    ids = sorted(seed)
    missing = sorted(set(ids) ^ set(i for i in modules if modules[i] in KINDS))
    print("\nseed_plant: %s, %d plant draw(s), %.3g photons per run, %.0f s in all; the seed's %d organs%s"
          % (MODEL.name, args.plants, args.photons, time.perf_counter() - t0, len(ids),
             "" if not missing else " (ids not matched: %s)" % missing))
    print("  the seed's mapping counts these shares of each kind's area: %s; ids mapped past the last triangle "
          "(into the sensors): %s" % (", ".join("%s %.1f %%" % (k, 100 * got["counted_area"][k]) for k in KINDS),
                                       got["spill"]))
    print("  projected area facing down (front normal downwards; plant 0): %s"
          % ", ".join("%s %.0f of %.0f cm²" % (k, *got["facing_down"][k]) for k in KINDS))
    print("\nPer organ kind, both bands summed (photon hits per 1e7 photons emitted in each band): ours = mean "
          "over the plants; σ MC = our σ of one plant's run; σ plant = the spread between plants (MC included); "
          "ratio = ours / seed; z with σ plant / √plants, σ plant (the seed's plant is one draw) and √seed")
    print("| variant | kind | seed | ours | σ MC | σ plant | ratio ± σ | z |")
    print("|---|---|---|---|---|---|---|---|")
    for v in VARIANTS:
        totals = kind_totals(results[v], modules, ids)
        for kind in KINDS:
            s = sum(seed[i].sum() for i in ids if modules[i] == kind)
            mean, sm, sp, mc = totals[kind]
            ratio, rs, z = compare(mean, sm, sp, s)
            print("| %s | %s | %.0f | %.1f | %.1f | %.1f | %.3f ± %.3f | %+.1f |" % (v, kind, s, mean, mc, sp, ratio, rs, z))
    print("\nPer band (variant seed): kind, band, seed, ours ± σ mean (σ plant), ratio")
    totals_b = [kind_totals(results["seed"], modules, ids, bands=(b,)) for b in (0, 1)]
    for kind in KINDS:
        for b, label in enumerate(("600-655", "655-665")):
            s = sum(seed[i][b] for i in ids if modules[i] == kind)
            mean, sm, sp, _ = totals_b[b][kind]
            ratio, rs, z = compare(mean, sm, sp, s)
            print("  %-9s %s  %5.0f  %7.1f ± %5.1f (%5.1f)  %.3f ± %.3f  z %+.1f" % (kind, label, s, mean, sm, sp, ratio, rs, z))
    print("\nPer organ (29), both bands: share within 4σ and the largest |z| (σ: ours over √plants, σ plant, √seed)")
    for v in VARIANTS:
        zs = []
        for i in ids:
            x = np.array([p[i][0].sum() for p in results[v]])
            spread = x.std(ddof=1) if len(x) > 1 else 0.0
            zs.append(compare(x.mean(), spread / math.sqrt(len(x)), spread, seed[i].sum())[2])
        zs = np.abs(zs)
        print("  %-9s within 4σ %2d of %d, max |z| %.1f" % (v, int((zs < 4).sum()), len(zs), zs.max()))
    if args.organs:
        print("\nPer organ, both bands (ours: mean over plants ± σ plant)")
        print("| id | module | seed | ours | one-sided | mapping | seed variant |")
        print("|---|---|---|---|---|---|---|")
        for i in ids:
            cells = []
            for v in VARIANTS:
                x = np.array([p[i][0].sum() for p in results[v]])
                cells.append("%.1f ± %.1f" % (x.mean(), x.std(ddof=1) if len(x) > 1 else 0.0))
            print("| %d | %s | %.0f | %s |" % (i, modules[i], seed[i].sum(), " | ".join(cells)))
    if got["sensors"]:
        print("\nThe 240 sensors (captors_expe1, the last plant in place, one-sided) against the seed's earlier run of "
              "the same scene (commit 2aba3d5, 1e7 photons per band):")
        for label, c in zip(("600-655", "655-665"), got["sensors"]):
            print("  %s nm: %s" % (label, c.line()))
    print("\nseconds per variant (all plants): %s" % ", ".join("%s %.1f" % kv for kv in got["seconds"].items()))
    return got


if __name__ == "__main__":
    main()
