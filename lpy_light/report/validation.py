"""Validation of the Angers chamber against SEC2's runs (``reference-sec2/``) and the
photon-mapping engine's (``reference-photon-mapping/``).

Each built-in Angers scene has the SEC2 file it is compared with (:data:`SEC2_SCENES`), and
:data:`VARIANTS` holds the physics ablations used to settle what SEC2 did where its
behaviour is undocumented (see docs/validation.md).  :func:`validate` runs one scene (and
optionally one variant) and compares it with its references::

    from lpy_light.report import validation
    row = validation.validate("angers", 10_000_000, estimator="nee", threads=2)
    print(row["sec2"].line())
"""
from __future__ import annotations

import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import reference
from ..run import simulate
from ..chamber.materials import DIFFUSE_R, DIFFUSE_T, SPECULAR_R, SPECULAR_T, ABSORB
from ..chamber.scene import load_scene

ANGERS = Path(__file__).parents[1] / "data" / "angers-chamber"
PHOTON_MAPPING = ANGERS / "reference-photon-mapping" / "captor_result-1000000000-655-665-nm.csv"

#: the table's ten Aquanappe polygons: top, underside, four sides of two opposite windings each
TABLE = ["tableAMaree", "soustableAMaree", "coteGtableAMaree", "coteGtableAMareer", "coteDtableAMaree",
         "coteDtableAMareer", "coteAVtableAMaree", "coteAVtableAMareer", "coteARtableAMaree", "coteARtableAMareer"]
#: the aluminium cornices around the false ceiling: tops (facing up, coplanar with the Makrolon) ...
CORNICE_TOPS = ["cornicheG", "cornicheD", "cornicheAV", "cornicheAR"]
#: ... and undersides (facing down)
CORNICE_UNDERSIDES = ["cornicheGr", "cornicheDr", "cornicheAVr", "cornicheARr"]


@dataclass
class ValidationScene:
    """A built-in scene and the SEC2 result it must reproduce."""

    toml: str                 # file in ANGERS
    sec2: str                 # file in ANGERS/reference-sec2
    geometry: str             # the .rad file SEC2 used
    removed: list = field(default_factory=list)   # primitives the scene leaves out of ``geometry``
    photon_mapping: bool = False                   # also compared with the photon-mapping run

    @property
    def path(self) -> Path:
        return ANGERS / self.toml

    @property
    def sec2_path(self) -> Path:
        return ANGERS / "reference-sec2" / self.sec2


#: scene name -> what it is compared with
SEC2_SCENES = {
    "angers": ValidationScene("angers.toml", "mesures.txt", "testChamber.rad", [], photon_mapping=True),
    "angers-onlylamps": ValidationScene("angers-onlylamps.toml", "mesures_onlyLamps.txt",
                                        "testChamber_onlyLamps.rad", []),
    "angers-sansmakrolon": ValidationScene("angers-sansmakrolon.toml", "mesures_sansMakrolon.txt",
                                           "testChamber.rad", ["fauxPlafondInf"]),
    "angers-sanstable": ValidationScene("angers-sanstable.toml", "mesures_sansTABLE.txt", "testChamber.rad",
                                        list(TABLE)),
}


# ---------------------------------------------------------------------------------------------
# ablation variants: each changes one modelling choice of the default (SEC2's) semantics

def _set_makrolon(chamber, events):
    for m in chamber.materials:
        if m.type == "trans":
            m.events = events(m.events.copy(), m)


def _trans_specular(chamber):
    """The Makrolon's transmitted part goes straight through (tspec = 1) instead of diffusely."""
    def f(e, m):
        e[SPECULAR_T] += e[DIFFUSE_T]
        e[DIFFUSE_T] = 0.0
        return e
    _set_makrolon(chamber, f)


def _trans_radiance(chamber):
    """Radiance's own reading of ``trans C s rough t ts``: specular reflection s, diffuse
    reflection C(1-s)(1-t), diffuse transmission C(1-s)t(1-ts), specular transmission C(1-s)t·ts."""
    from ..chamber.radiance import read_rad
    prims = {p.identifier: p for p in read_rad(ANGERS / "geometry" / "testChamber.rad") if p.type == "trans"}

    def f(e, m):
        r = prims[m.name].reals
        c, s, t, ts = float(np.mean(r[:3])), r[3], r[5], r[6]
        e[:] = 0.0
        e[SPECULAR_R] = s
        e[DIFFUSE_R] = c * (1 - s) * (1 - t)
        e[DIFFUSE_T] = c * (1 - s) * t * (1 - ts)
        e[SPECULAR_T] = c * (1 - s) * t * ts
        e[ABSORB] = 1 - e[:ABSORB].sum(axis=0)
        return e
    _set_makrolon(chamber, f)


def _two_sided(names):
    def f(chamber):
        surf = np.array([chamber.surfaces[i][0] for i in chamber.tri_source])
        chamber.tri_two_sided[np.isin(surf, names)] = True
    return f


def _makrolon_clipped(x0, y0, x1, y1):
    """A spec patch: the Makrolon clipped to x0..x1 x y0..y1, so that where a cornice top is left
    alone at z = 1970 the cornice is hit."""
    def patch(spec):
        rad = (ANGERS / "geometry" / "testChamber.rad").read_text(encoding="latin-1")
        old = ("Makrolon polygon fauxPlafondInf\n0\n0\n12\n0.0 0.0 1970\n2400.0 0.0 1970\n2400.0 1840.0 1970\n"
               "0.0 1840.0 1970")
        new = "Makrolon polygon fauxPlafondInf\n0\n0\n12\n%g %g 1970\n%g %g 1970\n%g %g 1970\n%g %g 1970" % (
            x0, y0, x1, y0, x1, y1, x0, y1)
        if old not in rad:
            raise RuntimeError("testChamber.rad: Makrolon polygon not found where expected")
        tmp = Path(tempfile.mkdtemp(prefix="lpy-light-ablation-"))
        (tmp / "testChamber.rad").write_text(rad.replace(old, new), encoding="latin-1")
        spec["geometry"] = str(tmp / "testChamber.rad")
    return patch


#: the cornices win in all four strips (x 40..2360, y 40..1800): the physical order, the sheet resting on
#: the cornices' flanges, which let nothing through
_makrolon_inside_cornices = _makrolon_clipped(40, 40, 2360, 1800)


@dataclass
class Variant:
    """One modelling choice changed: ``overrides`` for the scene TOML (physics, remove), then
    ``patch(chamber)`` on the loaded chamber; ``spec_patch(overrides)`` may replace the geometry."""

    description: str
    overrides: dict = field(default_factory=dict)
    patch: object = None
    spec_patch: object = None
    scenes: tuple = ("angers",)      # the scenes it is run on by the ablation benchmark
    replace_remove: bool = False     # ``remove`` replaces the scene's own removals (else adds to them)


VARIANTS = {
    "default": Variant("SEC2 semantics: one-sided, isotropic line lamps, mirror specular, diffuse trans, "
                       "fair choice between coincident surfaces",
                       scenes=("angers", "angers-onlylamps", "angers-sansmakrolon", "angers-sanstable")),
    "lamps=lambertian": Variant("lamps: Lambertian emission from the cylinder surface (Radiance)",
                                {"physics": {"lamps": "lambertian"}}, scenes=("angers", "angers-onlylamps")),
    "specular=phong": Variant("specular part: Phong lobe from the roughness (only the Makrolon has one, 0.5)",
                              {"physics": {"specular": "phong"}}, scenes=("angers",)),
    "one_sided=false": Variant("every surface seen from both sides", {"physics": {"one_sided": False}},
                               scenes=("angers", "angers-sansmakrolon")),
    "makrolon two-sided": Variant("only the Makrolon seen from both sides",
                                  patch=_two_sided(["fauxPlafondInf"])),
    "trans specular": Variant("Makrolon: transmitted part straight through (tspec = 1) instead of diffuse",
                              patch=_trans_specular),
    "trans radiance": Variant("Makrolon: Radiance's trans (T = C(1-s)·trans = 0.085, not 0.755)",
                              patch=_trans_radiance),
    "coplanar=arbitrary": Variant("coincident coplanar surfaces (cornice tops / Makrolon at z = 1970): whichever "
                                  "Embree's float32 arithmetic finds (~76 % Makrolon), not a fair choice",
                                  {"physics": {"coplanar": "arbitrary"}}, scenes=("angers", "angers-sanstable")),
    "cornices under makrolon": Variant("coplanar tie at z = 1970: the Makrolon wins (cornice tops removed)",
                                       {"remove": list(CORNICE_TOPS)}, scenes=("angers", "angers-sanstable")),
    "cornices over makrolon": Variant("coplanar tie at z = 1970: the cornices win (Makrolon clipped to 40..2360 x "
                                      "40..1800)", spec_patch=_makrolon_inside_cornices,
                                      scenes=("angers", "angers-sanstable")),
    "strip G: cornice wins": Variant("coplanar tie at z = 1970 in the strip along the wall y = 1840 (y 1800..1840, "
                                     "above the sensors' last row) only: the cornice wins there (Makrolon clipped "
                                     "to y <= 1800), a fair choice in the other three strips",
                                     spec_patch=_makrolon_clipped(0, 0, 2400, 1800),
                                     scenes=("angers", "angers-sanstable")),
    "repeated_names=all": Variant("both surfaces of each repeated name kept (Radiance's reading, lpy-light's before "
                                  "issue 21): the lamp-box mirror wall at x = 50, which SEC2's reading loses, is there",
                                  {"physics": {"repeated_names": "all"}},
                                  scenes=("angers", "angers-sansmakrolon", "angers-sanstable")),
    "table top only": Variant("sansTABLE: only the top and underside removed, the four sides kept",
                              {"remove": ["tableAMaree", "soustableAMaree"]}, scenes=("angers-sanstable",),
                              replace_remove=True),
    "table sides kept facing one way": Variant(
        "sansTABLE: top, underside and the four sides' twins ending in 'r' removed (the other winding kept)",
        {"remove": ["tableAMaree", "soustableAMaree"] + [t for t in TABLE if t.startswith("cote") and t.endswith("r")]},
        scenes=("angers-sanstable",), replace_remove=True),
    "table sides kept facing the other way": Variant(
        "sansTABLE: top, underside and the four sides not ending in 'r' removed (the 'r' twins kept)",
        {"remove": ["tableAMaree", "soustableAMaree"]
         + [t for t in TABLE if t.startswith("cote") and not t.endswith("r")]},
        scenes=("angers-sanstable",), replace_remove=True),
    "no cornice tops": Variant("sansMakrolon: the cornice tops (facing up, the Makrolon's coplanar partners) "
                               "removed with the Makrolon", {"remove": ["fauxPlafondInf"] + CORNICE_TOPS},
                               scenes=("angers-sansmakrolon",)),
    "no cornice undersides": Variant("sansMakrolon: the cornice undersides (facing down) removed with the Makrolon",
                                     {"remove": ["fauxPlafondInf"] + CORNICE_UNDERSIDES},
                                     scenes=("angers-sansmakrolon",)),
    "no cornices": Variant("sansMakrolon: the cornices removed with the Makrolon",
                           {"remove": ["fauxPlafondInf"] + CORNICE_TOPS + CORNICE_UNDERSIDES},
                           scenes=("angers-sansmakrolon",)),
}


def load(scene: str = "angers", variant: str = "default"):
    """The chamber of ``scene`` (a key of :data:`SEC2_SCENES`) with ``variant`` applied."""
    vs = SEC2_SCENES[scene]
    v = VARIANTS[variant]
    overrides = {k: (dict(val) if isinstance(val, dict) else val) for k, val in v.overrides.items()}
    if "remove" in overrides and not v.replace_remove:
        overrides["remove"] = sorted(set(vs.removed) | set(overrides["remove"]))
    if v.spec_patch is not None:
        v.spec_patch(overrides)
    chamber = load_scene(vs.path, **overrides)
    if v.patch is not None:
        v.patch(chamber)
    return chamber


def kernel_scene(chamber, estimator: str = "nee", threads: int = 2) -> simulate.KernelScene:
    """A KernelScene ready to run: next events pruned for ``nee`` (as ``lpy-light run`` does)."""
    ks = simulate.KernelScene(chamber, estimator=estimator)
    ks.prune_next_events(threads=threads)         # (nothing to prune without next events)
    return ks


def compare_result(result, scene: str = "angers") -> dict:
    """``{"sec2": Comparison, "photon_mapping": Comparison or None}`` for a run of ``scene``."""
    vs = SEC2_SCENES[scene]
    photons, std = result.sensors()
    out = {"sec2": reference.compare(photons[:, 0], std[:, 0], result.photons, reference.read_sec2(vs.sec2_path)),
           "photon_mapping": None}
    if vs.photon_mapping:
        out["photon_mapping"] = reference.compare(photons[:, 0], std[:, 0], result.photons,
                                                  reference.read_photon_mapping(PHOTON_MAPPING))
    return out


def validate(scene: str, photons: int, estimator: str = "nee", seed: int = 1, threads: int = 2,
             variant: str = "default", kscene=None) -> dict:
    """Run ``scene`` (with ``variant``) and compare it with its references.

    Returns a dict: scene, variant, estimator, photons, seconds (the run, after set-up and
    compilation), photons_per_s, result, sec2 (Comparison), photon_mapping (Comparison or None).
    """
    if kscene is None:
        kscene = kernel_scene(load(scene, variant), estimator, threads)
        simulate.run(kscene, 1000, seed=seed + 1, threads=threads)     # compile / warm up outside the timing
    t = time.perf_counter()
    result = simulate.run(kscene, int(photons), seed=seed, threads=threads)
    seconds = time.perf_counter() - t
    row = {"scene": scene, "variant": variant, "estimator": estimator, "photons": result.photons,
           "seconds": seconds, "photons_per_s": result.photons / seconds, "result": result}
    row.update(compare_result(result, scene))
    return row
