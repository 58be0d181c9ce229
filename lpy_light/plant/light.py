"""The light model a growth simulation calls at every step: :class:`LightModel`.

It holds the chamber (read and built into Embree once), the lamps' photon flux
per band (from one normalisation run of the empty chamber against the
measured lamp spectrum), and the organ materials.  Each step it receives the
plant as organs, places them in the chamber, runs the kernel and returns each
organ's light:

* ``ppfd`` (B,) — incident photon flux density, µmol m⁻² s⁻¹: photons hitting
  the organ (either side) per second, divided by its one-sided area;
* ``absorbed`` (B,) — µmol s⁻¹ absorbed by the organ, and ``absorbed_par`` (µmol s⁻¹, 400-700 nm);
* ``par`` (µmol m⁻² s⁻¹, when the bands tile 400-700 nm) and ``rfr`` = ppfd
  655-665 / ppfd 725-735 (when both bands are present), without the bias of a ratio of
  two estimates, NaN where the far red is too uncertain for that (:mod:`lpy_light.chamber.ratios`);
* and the standard error of each (``ppfd_std``, ...).

With L-Py, one line in the model's ``EndEach`` does it all
(:meth:`LightModel.intercept`); without L-Py, pass organs as a mapping
``key -> mesh`` or ``key -> (mesh, material)`` (trimesh meshes or
``(vertices, faces)``), in the plant's unit.

Units: the plant's coordinates are in ``plant_unit`` (L-Py models usually
work in cm); the chamber's in its scene unit (Angers: mm).  The plant's origin
is put at ``position`` (chamber units; by default the scene's
``plant_position``, else the centre of the floor).
"""
from __future__ import annotations

import logging
import math
import time
from collections.abc import Mapping
from contextlib import contextmanager
from dataclasses import replace

import numpy as np

from ..run import simulate
from . import ide
from ..chamber import units
from .precision import organs_sigma_over_goal, parse_goal, sigma_over_goal
from ..errors import InputError
from ..estimators.registry import estimator as estimator_named
from ..messages import OncePerKind
from .organ_light import (NOT_REACHED, ORGAN_COLUMNS, OrganLight, StepResult, for_rules, not_reached, organ_lights,
                          organ_rows, shading_only)
from .organs import TessellationCache, mesh_key, organ_from_mesh, plant_material
from . import verify as verifying
from ..process_state import preserved_locale
from ..estimators.field import FieldKeeper, field_settings
from .auto import AUTO, PILOT_SEED, Chooser
from ..estimators.reuse import StoreKeeper, reuse_settings
from ..chamber.scene import UNITS, load_scene, resolve_scene

log = logging.getLogger("lpy_light")

#: what a model imports from here: the light model, and an organ's light (:mod:`lpy_light.plant.organ_light`)
__all__ = ["LightModel", "LEAF", "MODELS", "MIRROR_EVENTS", "lamp_factors", "OrganLight", "StepResult", "NOT_REACHED",
           "ORGAN_COLUMNS", "organ_lights", "organ_rows", "for_rules", "not_reached", "shading_only"]

LEAF = ("FeuilleVieille_Sup", "FeuilleVieille_Inf")   # upper side, lower side (Angers optical tables)
MODELS: list = []      # every LightModel made in this process, newest last (``lpy-light grow`` finds the model's)
#: next events through a mirror per vertex by default (:class:`LightModel`'s ``mirror_events``): on the rose 0.05-1
#: give the same σ; where cone rays are on (a canopy) half of it, 16 roses' cost to leaves' p90 3 % 76.5 / 80.0 →
#: 70.0 / 73.4 CPU s (seeds 3 / 5), same σ (``benchmarks/canopy.py``)
MIRROR_EVENTS = 0.2
#: with the ``reuse`` estimator and a precision goal a first gather misses, the most its draws are multiplied by
REUSE_SCALE = 16.0


class LightModel:
    """A growth chamber ready to light a plant at every step.

    Every parameter states its unit first ("Unit: ...").  Lengths are in the chamber's unit (the scene's
    ``unit``; Angers: mm), but for the plant's own coordinates, which are in ``plant_unit``.

    Parameters
    ----------
    scene : str or path
        Unit: none (a path or a name).
        Scene TOML or a built-in name (default ``angers-12bands``: 12 SEC2 bands,
        PAR and R:FR available).
    organs : mapping module name -> material
        Unit: none (names of modules and materials).
        Which modules are organs and their optical material: a name from the
        scene's optical tables, a ``(front, back)`` pair (a leaf's upper and lower
        side), or ``{"reflectance": R, "transmittance": T}``.  Default: ``Leaf``
        with the Angers leaf tables (:data:`LEAF`).
    photons : int
        Unit: photons, a count.
        Photons per step (per band: all bands travel together); with ``precision``, the most a step may trace.
    seed : int
        Unit: none (a random seed).  Step k traces with ``seed + k``, the lamps' normalisation run with
        ``seed + 7919``: the numbers depend on the seed alone (``docs/physics.md``, "Determinism").
    threads : int or None
        Unit: threads, a count.  Threads that trace a step (None, the default: all cores).
    plant_unit : str
        Unit: none (it names one).  The unit of the plant's coordinates ('mm', 'cm', 'm', ...).
    position : (3,) or None
        Unit: the chamber's unit (the scene's ``unit``; Angers: mm).
        Where the plant's origin goes; default: the scene's ``plant_position``, else the centre of the floor.
    parameter : str, int, mapping or None
        Unit: none (a module parameter's name or position).
        The module parameter that receives each organ's :class:`OrganLight`: its name (``"light"``), its
        position (``2``: the third parameter, for models with positional parameters), a mapping module
        name → name or position (``{"Leaf": 3, "Bud": 2}``), or None (nothing written: lighting a model
        from outside, ``lpy-light grow --organs``).
    estimator : str
        Unit: none (a registered estimator's name).
        ``"nee"`` (default): every step traces the chamber's photons again, next events to the organs from every
        vertex (:mod:`lpy_light.kernel.nee`).  ``"reuse"``: the chamber's light is traced once into a store with
        the plant in place and gathered at every organ each step through the current plant, ``photons`` then
        unused (:mod:`lpy_light.estimators.reuse`; every organ is a target; ``docs/performance.md`` says when to use
        which). ``"field"``: the light entering the plant's region is traced once into a field; each step's rays stay in
        the region and read it where they leave (:mod:`lpy_light.estimators.field`; every organ is a target).
        ``"auto"``: the first step traces a field and checks it against ``nee`` (the field's self-check), and that
        check chooses: the field where it passed and brings the read organs' 90th-percentile σ to a given value
        for less CPU (its tracing and check counted), else ``nee``; chosen again at each field's check, and a
        plant lit by ``nee`` piloted again once its organs or their area doubled (:mod:`lpy_light.plant.auto`;
        ``self.auto.choices``, ``summary.json``'s ``auto``).
    lamp_flux : (B,) or None
        Unit: µmol s⁻¹, one value per band (or one for every band).
        µmol s⁻¹ emitted per band; default: from the scene's lamp spectrum, by a
        ``normalisation_photons`` run on the scene's sensors once (σ ≈ 0.4% at 1e6).
    normalisation_photons : int
        Unit: photons, a count.  Photons of the one run of the empty chamber that finds the lamps' photon flux
        per band from the scene's lamp spectrum (without ``lamp_flux``, and unless the scene gives its
        ``lamp_flux``); default 10⁶, σ ≈ 0.4 %.
    progress : callable or None
        Unit: none (a function).  Called as ``progress(done, total, seconds)`` (photons traced, photons asked,
        wall-clock seconds) as a step's chunks finish; None (default): nothing is called.
    nee_picks : int
        Unit: targets per next event, on average over the vertices.
        With ``estimator="nee"``: targets per next event, on average over the vertices (default 2).  Each
        vertex draws as many as the light it can bring the organs asks, up to 4x that
        (:func:`lpy_light.kernel.nee.pick_share`: its photon's weight, its material's diffuse reflectance or
        transmittance, how near the organs are); on the procedural rose that lowers the leaves' variance per CPU
        second 1.2-1.5x and the buds' 1.3x against 2 at every vertex.  3 gives ~15 % more precision per second
        there, 4 no more than 2.
    targets : iterable of module names or None
        Unit: none (module names).
        With ``estimator="nee"``: the modules whose light the model reads and
        that next events aim at (default None: every organ).  The other organs
        still block, scatter and absorb light and still get their numbers, by
        counting the photons that reach them (larger σ, still unbiased); the
        shadow rays go to the organs that matter.
    mirror_events : float or None
        Unit: next events per photon vertex, on average.
        With ``estimator="nee"``: next events through a flat perfect mirror (the
        chamber's metal walls' specular part) per vertex, on average (0: none, that
        light is then counted).  Default None: 0.2 for a plant, 0.1 where cone rays
        are on (a canopy: each event through a mirror then sends cone rays too, and
        half as many events give the same σ for ~9 % less CPU on 16 roses).  On the
        rose, leaves get ~6 % of their light that way, and counting it held over half
        their variance: 0.05-1 events per vertex give the same σ, each 0.1 costing
        ~0.1 s per step (``benchmarks/rose.py --images``).
    precision : float, mapping or None
        Unit: a relative standard error (0.04: 4 %) for PAR and a band's ppfd; an absolute one for R:FR.
        What a step waits for before it stops (:mod:`lpy_light.plant.precision`): a number, the relative standard
        error to reach on every target organ's PAR and R:FR (each band's ppfd when the bands give neither),
        e.g. 0.04; or the quantities the rules read, ``{"par": 0.03, "rfr": 0.02}`` (PAR relative, R:FR
        absolute; a band label ``"655-665"``: that band's ppfd, relative).  Organs that receive no light are
        not waited for; an organ whose far red is too uncertain for its R:FR to be reported (NaN,
        :data:`lpy_light.chamber.ratios.MAX_DENOMINATOR_CV`) is.  None (default): exactly ``photons`` per step.
    lamp_scale : float or mapping
        Unit: a factor (dimensionless); the bands of a mapping's keys in nm.
        Multiplies the lamps' photon flux: a number (dimmer or brighter lamps, all bands), or
        ``{"LO-HI": factor}`` for the bands lying within LO-HI nm (``{"700-800": 2.0}``: a far-red
        supplement of the same lamps, which lowers R:FR).  Default 1.
    colour_top : float or None
        Unit: µmol m⁻² s⁻¹ (PAR).
        PAR (µmol m⁻² s⁻¹) drawn in yellow in ``lpy-light grow``'s pictures: give the scale the model's
        interpretation rules use in :func:`~lpy_light.plant.plant_view.par_colour`, so both agree.
    one_sided_organs : bool
        Unit: none (a switch).
        An ablation for comparisons, not physics (default False): organs are seen from their front only
        (the side their right-hand-rule normal points to), as engines that cull back faces see them (the
        seed's photon mapping with ``$BACKFACE_CULLING yes``): a photon reaching an organ's back face
        passes through it uncounted.  A leaf has two faces: leave it off to light a plant
        (``benchmarks/seed_plant.py``, ``docs/validation.md``).
    cone_rays : float or None
        Unit: rays per photon vertex.
        With ``estimator="nee"``: rays per vertex into the cones of the clusters of organs the vertex is far
        from, the first organ met tallied (:mod:`lpy_light.kernel.cones`; at a vertex whose photon's mean weight
        × the cones' share of its light is 0.5, more or fewer with it up to 4x, a quarter of that near a
        cluster; 0: picks serve those organs too).  Default None: 10 for scenes of 1,000 organ
        targets or more (a canopy), else 0 (:func:`lpy_light.estimators.kernel_scene.cones_for`: a single plant's few
        hundred targets gain less than the rays cost).  Leaves and other large targets
        get their light from across the chamber this way; a pick is one target in n, a cone ray is not, and it
        does not aim at an organ hidden behind others.  Rose (``benchmarks/rose.py --photons 1.15e6``): leaves'
        p90 σ 2.6 → 1.5 %, buds' median 4.4 → 3.3 %, a step 4.1 → 6.3 s; 16 roses (``benchmarks/canopy.py``):
        the cost to leaves' p90 3 % 697 → ~200 CPU s.
    local_rays : float or None
        Unit: rays per photon vertex.
        With ``estimator="nee"``: rays per vertex near a cluster of organs, drawn as the photon would leave
        the vertex, the first large organ (leaf) of a near cluster met tallied, in place of those leaves' own
        next events and picks (:func:`lpy_light.kernel.cones.local_events`; 0: own events and picks serve
        them; at a vertex whose photon's mean weight is 0.5, more or fewer with it up to 4x).  Default None: 8
        for scenes of 1,000 organ targets or more (a canopy), else 0
        (:func:`lpy_light.estimators.kernel_scene.local_for`).  Amid a canopy a vertex on a leaf is near dozens of
        leaves; rays meet those it sees, in proportion to its light.  16 roses: the cost to leaves' p90 3 % 67 → 48 CPU
        s (12 cone rays); on a single rose the own events serve the few leaves around a vertex as well or better.
    reuse : mapping or None
        Unit: each setting's own, as its class states (``store_photons``: photons; ``renew``: steps).
        With ``estimator="reuse"``: its settings (:class:`lpy_light.estimators.reuse.ReuseSettings`: ``store_photons``,
        ``batches``, ``samples``, ``zone_samples``, ``image_draws``, ``paths``, ``renew``).
    field : mapping or None
        Unit: each setting's own, as its class states (``store_photons``: photons; ``renew``: steps).
        With ``estimator="field"``: its settings (:class:`lpy_light.estimators.field.FieldSettings`: ``store_photons``,
        ``batches``, ``cells``, ``rings``, ``sectors``, ``rays``, ``shading_rays``, ``piece_rays``, ``pieces``,
        ``bounces``, ``growth``, ``margin``, ``renew``, ``check_photons``: the ``nee`` run that checks each field
        as it is traced, :mod:`lpy_light.plant.verify`; a field that fails is not used, its steps are lit by
        ``nee``).
    verify : int
        Unit: steps, a count.  The first ``verify`` lit steps are also lit by an independent ``nee`` run at
        ``photons``, every read organ compared (``StepResult.comparison``, ``extra["verify"]``; ``lpy-light grow
        --verify``: ``verify.csv``), :mod:`lpy_light.plant.verify`.  Default 0: none.
    """

    def __init__(self, scene="angers-12bands", organs=None, photons: int = 300_000, seed: int = 1,
                 threads: int | None = None, plant_unit: str = "cm", position=None, parameter: str = "light",
                 estimator: str = "nee", lamp_flux=None, normalisation_photons: int = 1_000_000,
                 progress=None, nee_picks: int = 2, targets=None, mirror_events: float | None = None,
                 precision=None, lamp_scale=1.0, colour_top: float | None = None,
                 one_sided_organs: bool = False, cone_rays: float | None = None, local_rays: float | None = None,
                 reuse=None, field=None, verify: int = 0):
        self._pending = None          # a step's worker that Stop in the L-Py IDE left running (lpy_light.plant.ide)
        live = ide.live(doing="reading the chamber")        # None outside a GUI: plain calls
        self.chamber = scene if hasattr(scene, "triangles") else _call(live, load_scene, resolve_scene(str(scene)))
        if plant_unit not in UNITS:
            raise InputError("unknown plant_unit %r (use one of %s)" % (plant_unit, ", ".join(UNITS)))
        self.scale = UNITS[plant_unit] / self.chamber.metres_per_unit
        self.position = np.asarray(self._default_position() if position is None else position, dtype=float)
        self.organ_materials = dict(organs) if organs is not None else {"Leaf": LEAF}
        self.photons, self.seed, self.threads = _photons(photons), int(seed), threads
        self.precision = precision          # checked against the scene's bands (:func:`precision.parse_goal`)
        self.parameter = parameter
        self.progress = progress
        self.auto = Chooser(field) if estimator == AUTO else None     # estimator="auto" (lpy_light.plant.auto)
        estimator = "field" if self.auto is not None else estimator
        self.estimator = estimator_named(estimator).name
        # a stored estimator traces with nee's records: the store's trace, the gather and the paths are its events
        self.kscene = _call(live, simulate.KernelScene, self.chamber,
                            estimator="nee" if estimator_named(estimator).stored else estimator,
                            one_sided_organs=one_sided_organs)
        self.keeper = _keeper(self.estimator, reuse, field, seed)
        self._auto_needs_a_check()
        self.verify, self.verification = verifying.verify_count(verify), verifying.Verification()
        self.kscene.configure(**_plant_settings(nee_picks=nee_picks, cone_rays=cone_rays, local_rays=local_rays))
        _plant_settings(mirror_events=mirror_events)         # checked here, used at each step (_mirror_events)
        self.mirror_events = None if mirror_events is None else float(mirror_events)
        self.targets = None if targets is None else {str(t) for t in ([targets] if isinstance(targets, str) else targets)}
        if self.targets is not None and not self.targets <= set(self.organ_materials):
            raise InputError("targets %s are not organ modules (organs: %s)"
                             % (", ".join(sorted(self.targets - set(self.organ_materials))),
                                ", ".join(sorted(self.organ_materials))))
        self._pruned = False
        self.materials: dict = {}
        for spec in self.organ_materials.values():
            self._materials_of(spec)
        self.cache = TessellationCache()
        self.step = 0
        self.on_step = None          # callback(step: StepResult, organs: list) after each L-Py step
        self.last_step = None
        self.last_organs = []
        self.colour_top = colour_top      # PAR shown in yellow in the pictures (the viewer's par_colour scale)
        self.messages = OncePerKind()     # each kind of warning once per model (a growth run), then counted
        if live is not None:
            live.show("the lamps' normalisation run")
        self.flux, self.flux_std = _call(live, self._lamp_flux, lamp_flux, normalisation_photons, live)
        factor = lamp_factors(lamp_scale, self.chamber)
        self.flux, self.flux_std = self.flux * factor, self.flux_std * factor
        self._chamber_box = (self.chamber.triangles.min(axis=(0, 1)), self.chamber.triangles.max(axis=(0, 1)))
        MODELS.append(self)

    # -- set-up -------------------------------------------------------------------------
    @property
    def precision(self):
        """The precision goal as given: None, a number (relative σ of PAR and R:FR) or a mapping
        (``{"par": 0.03, "rfr": 0.02}``); set it to change the goal (checked, :func:`precision.parse_goal`)."""
        return None if self.goal is None else self.goal.given

    @precision.setter
    def precision(self, value):
        self.goal = parse_goal(value, self.chamber.bands, self.chamber.band_labels)

    def _default_position(self):
        pos = getattr(self.chamber, "plant_position", None)
        if pos is not None:
            return pos
        lo, hi = self.chamber.triangles.min(axis=(0, 1)), self.chamber.triangles.max(axis=(0, 1))
        return [(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]]

    def _materials_of(self, spec) -> tuple:
        """(front, back) material names for an organ material spec; builds them once."""
        if isinstance(spec, (tuple, list)):
            if len(spec) != 2:
                raise InputError("organ material %r: expected a name or a (front, back) pair" % (spec,))
            return self._materials_of(spec[0])[0], self._materials_of(spec[1])[0]
        try:
            name = spec if isinstance(spec, str) else "const(%s)" % ",".join(
                ("%s=%s" if isinstance(v, str) else "%s=%g") % (k, v) for k, v in sorted(dict(spec).items()))
        except (TypeError, ValueError):
            raise InputError("organ material %r: expected a table name, a (front, back) pair or "
                             "{'reflectance': R, 'transmittance': T}" % (spec,)) from None
        if name not in self.materials:
            self.materials[name] = plant_material(spec, name, self.chamber)
        return name, name

    def _lamp_flux(self, lamp_flux, n, live=None):
        B = self.chamber.n_bands
        if lamp_flux is not None:
            flux = np.broadcast_to(np.asarray(lamp_flux, dtype=float), (B,)).copy()
            return flux, np.zeros(B)
        ch = self.chamber
        if ch.lamp_flux is not None:          # a fitted chamber: the lamps' flux is known, nothing to trace
            norm = units.from_lamp_flux(ch, n)
            self.normalisation = norm
            return norm.scale * n, np.zeros(B)
        if ch.spectrum is None or ch.bands is None or len(ch.sensors) == 0:
            raise InputError("the light model needs the lamps' photon flux: give lamp_flux=[µmol/s per band] or "
                             "a scene with 'spectrum', 'bands' and reference sensors", ch.source or None)
        self.kscene.prune_next_events(threads=self.threads)
        result = simulate.run(self.kscene, n, seed=self.seed + 7919, threads=self.threads, **_live_arguments(live))
        photons, std = result.sensors()
        norm = units.from_spectrum(photons, std, ch.sensors.area * ch.metres_per_unit ** 2, ch.spectrum, ch.bands)
        self.normalisation = norm
        return norm.scale * result.photons, norm.scale_std * result.photons

    # -- one step -----------------------------------------------------------------------
    def organs_from_meshes(self, meshes: Mapping, module: str = "") -> list:
        """Organs from ``key -> mesh``, ``key -> (mesh, material)`` or ``key -> (mesh, material, module)``,
        in the plant's unit; the material defaults to the first entry of ``organs``."""
        out = []
        default = next(iter(self.organ_materials.values()))
        for key, item in meshes.items():
            mat, mod = default, module
            if isinstance(item, tuple) and len(item) in (2, 3) and not isinstance(item[0], np.ndarray):
                mesh, mat = item[0], item[1]
                mod = item[2] if len(item) == 3 else module
            else:
                mesh = item
            front, back = self._materials_of(mat)
            try:
                v, f = (mesh.vertices, mesh.faces) if hasattr(mesh, "faces") else mesh
                cache_key = (mesh_key(v, f), front, back, mod)
            except (TypeError, ValueError):
                cache_key = None     # organ_from_mesh explains what is wrong
            organ = self.cache.get(cache_key, lambda: organ_from_mesh(key, mesh, (front, back), mod, self.scale,
                                                                      self.position))
            out.append(replace(organ, key=key))
        self.cache.end_step()
        return out

    @contextmanager
    def warnings_once(self):
        """Within the block, each kind of warning is printed once for this model and counted (``messages``)."""
        logger = logging.getLogger("lpy_light")
        added = self.messages not in logger.filters
        if added:
            logger.addFilter(self.messages)
        try:
            yield self.messages
        finally:
            if added:
                logger.removeFilter(self.messages)

    def run(self, organs: list, photons: int | None = None) -> StepResult:
        """Light ``organs`` (list of :class:`~lpy_light.plant.organs.Organ`, chamber units) for one step."""
        with self.warnings_once():
            return self._run(organs, photons)

    def _run(self, organs, photons, live=None):
        n = _photons(photons) if photons is not None else self.photons
        t0 = time.perf_counter()
        compiled = getattr(self.kscene, "compile_seconds", 0.0)
        if not organs:                         # nothing to light yet (a seedling before its first organ)
            self.step += 1
            return StepResult(self.step - 1, {}, 0, time.perf_counter() - t0, 0, 0, 0)
        self._pilot_again(organs)
        outside = self._outside(organs)
        self._beyond_survey(organs)
        targets = None if self.targets is None else [o.module in self.targets for o in organs]
        if self.keeper is not None:
            targets = None               # the gather serves the organs it aims at only: every organ is one
        self.kscene.configure(sensors=False)  # steps report organs; sensors are counted, not targeted
        self.kscene.set_organs(organs, self.materials, targets)
        if self.estimator != "field":         # a field step makes no next event (nor builds their targets)
            self.kscene.configure(images=self._mirror_events())
        if not self._pruned and organs:       # once, with the first plant: which vertices see organs
            self.kscene.prune_next_events(threads=self.threads, keep=self.materials)   # organs' materials stay on
            self._pruned = True
        read = (np.ones(len(organs), bool) if self.targets is None
                else np.array([o.module in self.targets for o in organs], bool))
        precision_of = None
        if self.goal is not None and read.any():
            def precision_of(partial):          # the largest σ / goal: the goal is reached at 1
                return step_sigma_over_goal(self.kscene, partial, np.flatnonzero(read), self.chamber, self.goal,
                                            self.flux)
        self.kscene.size_pilots(n)
        checks = len(getattr(self.keeper, "checks", ()))
        result = self._reuse_step(organs, precision_of, read) if self.keeper is not None else None
        if result is None:          # nee; or a field that failed its self-check (lpy_light.plant.verify)
            if self.keeper is not None:
                self.kscene.configure(images=self._mirror_events())
            result = simulate.run(self.kscene, n, seed=self.seed + self.step, threads=self.threads,
                                  precision=None if precision_of is None else 1.0, precision_of=precision_of,
                                  **_live_arguments(live, self.progress))
        if live is not None and live.stop_asked():
            raise ide.Stopped("stopped in the L-Py IDE: step %d's light not written" % self.step)
        if result.interrupted:
            raise KeyboardInterrupt      # Ctrl-C ends the growth (cmd_grow keeps the steps done), not one step
        lights = organ_lights(self.kscene, result, organs, self.flux, self.flux_std, self.chamber, read)
        step = StepResult(self.step, lights, result.photons, time.perf_counter() - t0,
                          sum(len(o.triangles) for o in organs), 0, 0)
        if self.precision is not None:
            step.extra["precision"] = self.precision
            step.extra["precision_reached"] = bool(result.extra.get("precision_reached", not read.any()))
            if not step.extra["precision_reached"]:
                self._warn_precision_short(result, organs, read)
        if outside:
            step.extra["outside_chamber"] = outside
        for key in ("store", "sigma_over_goal"):
            if key in result.extra:
                step.extra[key] = result.extra[key]
        verifying.after_step(self, step, result, organs, read, checks)     # field_check, lit_by, verify
        if self.auto is not None and "field_check" in step.extra:
            self._choose(step, organs)
        compiled = getattr(self.kscene, "compile_seconds", 0.0) - compiled
        if compiled > 0:              # the kernel compiled for these organs (first run only), within the step's time
            step.extra["compile_seconds"] = compiled
        self.step += 1
        return step

    def use_estimator(self, name: str, reuse=None, field=None):
        """Light the next steps with estimator ``name`` (``nee``, ``field``, ``reuse`` or ``auto``, all trace with
        nee's records; ``reuse``, ``field``: their settings, as the constructor's): ``lpy-light grow --estimator``."""
        self.auto = Chooser(field) if name == AUTO else None
        name = "field" if self.auto is not None else name
        est = estimator_named(name)
        if self.kscene.estimator != "nee" or not (est.stored or est.name == "nee"):
            raise InputError("a light model of estimator %s cannot switch to %s (nee, field and reuse switch)"
                             % (self.estimator, est.name))
        self.estimator = est.name
        self.keeper = _keeper(est.name, reuse, field, self.seed)
        self._auto_needs_a_check()

    def _auto_needs_a_check(self):
        if self.auto is not None and self.keeper.settings.check_photons <= 0:
            raise InputError("estimator auto chooses from the field's self-check: field check_photons must be > 0")

    def _choose(self, step, organs):
        """``estimator="auto"``: a choice from the field's self-check of this step (:class:`lpy_light.plant.auto.
        Chooser`), in the step's ``extra["auto"]``; ``nee`` chosen, the next steps are ``nee``'s."""
        choice = self.auto.decide(step.extra["field_check"], self.keeper.settings.renew, step.step, len(organs),
                                  sum(o.area for o in organs), self.goal)
        step.extra["auto"] = choice
        logging.getLogger("lpy_light").info("estimator auto: %s (%s)", choice["estimator"], choice["why"])
        if choice["estimator"] == "nee":
            self.estimator, self.keeper = "nee", None

    def _pilot_again(self, organs):
        """``estimator="auto"`` on ``nee``: the plant grew :data:`lpy_light.plant.auto.REPILOT` times (its organs or
        their area) since the last pilot, so this step traces a field and checks it again (:meth:`_choose` decides
        after it)."""
        if self.auto is not None and self.auto.repilot(len(organs), sum(o.area for o in organs)):
            self.estimator = "field"
            self.keeper = _keeper("field", None, self.auto.field, self.seed + PILOT_SEED * len(self.auto.choices))

    def _reuse_step(self, organs, precision_of, read):
        """A step of the ``reuse`` estimator (:class:`lpy_light.estimators.reuse.StoreKeeper`): one gather, and with a
        precision goal not met, one more that replaces it, each organ's draws scaled by its own (σ / goal)²
        (1.1 times, at most :data:`REUSE_SCALE`; an organ at its goal keeps its draws): a budget per organ, spent
        where the goal is not met.  The store's own error is not lowered by draws: a goal below it is reported as
        not met."""
        seed = self.seed + self.step
        check = verifying.field_self_check(self, organs, read) if self.estimator == "field" else None
        result = self.keeper.step(self.kscene, organs, seed, self.flux, self.threads, read=read,
                                  **({} if check is None else {"check": check}))
        if result is None:          # the field failed its self-check: the caller lights the step by nee
            return None
        if precision_of is not None:
            rows = np.flatnonzero(read)
            r = self.kscene.n_sensors + self.kscene.n_chamber_receivers + rows
            ratio = organs_sigma_over_goal(self.goal, result.tally[r], result.covariance(r), self.flux,
                                           self.chamber.bands, self.chamber.band_labels)
            if not np.all(ratio <= 1.0):
                scale = np.ones(len(organs))
                scale[rows] = np.clip(1.1 * np.where(np.isfinite(ratio), ratio, math.inf) ** 2, 1.0, REUSE_SCALE)
                result = self.keeper.step(self.kscene, organs, seed + (1 << 32), self.flux, self.threads, scale, read)
            worst = float(precision_of(result))
            result.extra["precision_reached"] = bool(worst <= 1.0)
            result.extra["sigma_over_goal"] = worst
        if self.progress:
            self.progress(result.photons, result.photons, result.seconds)
        return result

    def _warn_precision_short(self, result, organs, read):
        """A step that stopped at its photon cap before the precision asked of its targets says so (once per run,
        counted): a rule comparing those organs' numbers with a threshold reads noise, and grows differently
        with the cap (``benchmarks/rose_bursts.py``)."""
        rows = np.flatnonzero(read)
        r = self.kscene.n_sensors + self.kscene.n_chamber_receivers + rows
        ratio = organs_sigma_over_goal(self.goal, result.tally[r], result.covariance(r), self.flux, self.chamber.bands,
                                       self.chamber.band_labels)
        short = np.isfinite(ratio) & (ratio > 1.0)
        if not short.any():
            return
        modules = sorted({organs[i].module for i in rows[short]})
        log.warning("step %d stopped at its cap of %d photons before the precision asked (%s): %d of %d target "
                    "organs short of it (%s), the worst at %.1fx its σ goal -- a rule that compares their numbers "
                    "with a threshold reads that noise; more photons (photons=), or a looser precision",
                    self.step, result.photons, _goal_text(self.precision), int(short.sum()), len(rows),
                    ", ".join(modules), float(np.nanmax(ratio)))

    def _mirror_events(self) -> float:
        """Next events through a mirror per vertex: ``mirror_events``, or by default :data:`MIRROR_EVENTS`, halved
        where cone rays are on (they go through the mirrors too, :func:`lpy_light.kernel.images.image_cones`)."""
        if self.mirror_events is not None:
            return self.mirror_events
        ks = self.kscene
        cones = simulate.cones_for(len(ks.targets.kind)) if ks.settings.cones is None else ks.settings.cones
        return MIRROR_EVENTS / 2 if cones > 0 else MIRROR_EVENTS

    def _outside(self, organs) -> list:
        """Organs not inside the chamber's bounding box (warned once, in the plant's unit): a plant drawn in mm
        but declared in cm, or placed at the wrong ``position``, would otherwise read 0 ± 0 without a word."""
        if not organs:
            return []
        lo, hi = self._chamber_box
        pad = 1e-6 * float(np.max(hi - lo))
        out = []
        for organ in organs:
            olo, ohi = organ.triangles.min(axis=(0, 1)), organ.triangles.max(axis=(0, 1))
            if (olo < lo - pad).any() or (ohi > hi + pad).any():
                out.append(organ.key)
        if out:
            to_plant = lambda x: (np.asarray(x) - self.position) / self.scale      # noqa: E731
            tri = np.concatenate([o.triangles.reshape(-1, 3) for o in organs if o.key in set(out)])
            log.warning("%d organ(s) lie outside the chamber (keys %s): their bounding box is %s to %s, the "
                        "chamber's %s to %s (plant units, plant origin at position %s chamber units): check "
                        "plant_unit and position", len(out), ", ".join(map(str, out[:8])) + (" ..." if len(out) > 8 else ""),
                        _xyz(to_plant(tri.min(axis=0))), _xyz(to_plant(tri.max(axis=0))), _xyz(to_plant(lo)),
                        _xyz(to_plant(hi)), _xyz(self.position))
        return out

    def _beyond_survey(self, organs) -> None:
        """Warn (once) when the plant reaches beyond the region a fitted chamber's survey constrains
        (``[surveyed]``, written by ``lpy-light calibrate``): its light there is the fit's extrapolation."""
        surveyed = getattr(self.chamber, "surveyed", None)
        if not surveyed or not organs:
            return
        from ..chamber.overrides import outside_survey
        lo = np.min([o.triangles.min(axis=(0, 1)) for o in organs], axis=0)
        hi = np.max([o.triangles.max(axis=(0, 1)) for o in organs], axis=0)
        text = outside_survey(surveyed, lo, hi, self.chamber.unit)
        if text:
            log.warning("calibrated chamber: %s", text)

    def intercept(self, organs, lscene=None):
        """Light the plant of this step.

        * ``intercept(lstring, lscene)`` from an ``.lpy`` file's ``EndEach``:
          tessellates the organ modules' shapes (cached by geometry), runs the
          kernel, writes each organ's :class:`OrganLight` into the module
          parameter ``parameter`` and returns ``(lstring, lscene)`` — return that
          from ``EndEach``.  ``lscene`` must not be None: call
          ``frameDisplay(True)`` in ``StartEach`` (see :mod:`lpy_light.plant.lpy`).
        * ``intercept({key: mesh or (mesh, material)})``: returns ``{key: OrganLight}`` (None for an organ
          no sample of the step reached, as the rules get it).

        In the L-Py IDE (a Qt application's GUI thread, or its "use thread"), the step keeps the window alive, names
        itself in the status bar and ends at once on Stop, its light then not written (for meshes: raises
        :class:`lpy_light.plant.ide.Stopped`): :mod:`lpy_light.plant.ide`.  The numbers are the same.
        """
        with self.warnings_once(), preserved_locale():     # PlantGL sets the C locale and leaves it so
            live = ide.live(ide.step_label())       # in the L-Py IDE (a Qt GUI): the window stays alive; else None
            if live is None:
                _wait(getattr(self, "_pending", None))
                if isinstance(organs, Mapping):
                    return for_rules(self.run(self.organs_from_meshes(organs)).organs)
                return self._intercept_lstring(organs, lscene)
            with live:
                live.wait(getattr(self, "_pending", None))
                self._pending = None
                try:
                    if isinstance(organs, Mapping):
                        live.show("lighting %d organs" % len(organs))
                        return for_rules(live.call(self._live_run, self.organs_from_meshes(organs), live).organs)
                    return self._intercept_lstring(organs, lscene, live)
                except ide.Stopped:
                    if live.worker is not None and live.worker.is_alive():
                        self._pending = live.worker       # told to stop: the next step waits for it
                    live.show("stopped: this step's light is not written")
                    if isinstance(organs, Mapping):
                        raise
                    log.warning("stopped in the L-Py IDE during step %d: its organs' light was not written "
                                "(they keep the light they had)", self.step)
                    return organs, lscene

    def _live_run(self, organs, live):
        """:meth:`run` in the worker of a step with the GUI alive (:mod:`lpy_light.plant.ide`)."""
        with self.warnings_once():
            return self._run(organs, None, live)

    def _intercept_lstring(self, lstring, lscene, live=None):
        """One L-Py step: the scene's organ shapes → organs → a run → each organ's light in its module (``live``:
        with the GUI alive, :mod:`lpy_light.plant.ide`)."""
        from . import lpy
        hits, misses = self.cache.hits, self.cache.misses
        t0 = time.perf_counter()
        materials = {name: self._materials_of(spec) for name, spec in self.organ_materials.items()}
        if live is not None:
            live.show("reading the plant's organs")
        organs = lpy.plant_organs(lstring, lscene, materials, self.scale, self.position, self.cache,
                                  tick=None if live is None else live.tick)
        convert = time.perf_counter() - t0
        if live is None:
            step = self.run(organs)
        else:
            live.show("lighting %d organs" % len(organs))
            step = live.call(self._live_run, organs, live)
        step.reused, step.tessellated = self.cache.hits - hits, self.cache.misses - misses
        step.extra["convert_seconds"] = convert
        self.last_step, self.last_organs = step, organs
        if self.parameter is not None:
            lpy.write_parameters(lstring, for_rules(step.organs), self.parameter)
        if live is not None:
            live.show("lit %d organs in %.1f s" % (len(organs), step.seconds))
        if self.on_step is not None:
            self.on_step(step, organs)
        return lstring, lscene


def _call(live, fn, *args, **kwargs):
    """``fn(*args, **kwargs)``: in a worker with the GUI alive where ``live`` (:mod:`lpy_light.plant.ide`), else
    here."""
    return fn(*args, **kwargs) if live is None else live.call(fn, *args, **kwargs)


def _live_arguments(live, progress=None) -> dict:
    """A kernel run's ``progress`` (and, with the GUI alive, its ``stop``): ``progress`` alone outside a GUI."""
    if live is None:
        return {"progress": progress}
    return {"progress": live.progress(progress), "stop": live.stop_asked}


def _wait(worker):
    """Wait for a step's worker that Stop in the L-Py IDE left running (it uses the light model's kernel scene)."""
    if worker is not None:
        worker.join()


#: LightModel's arguments that are next-event settings (:class:`lpy_light.estimators.registry.NextEventSettings`)
PLANT_SETTINGS = {"nee_picks": "picks", "mirror_events": "images", "cone_rays": "cones", "local_rays": "local"}


def _keeper(name, reuse, field, seed):
    """What keeps a stored estimator's chamber between steps (:class:`~lpy_light.estimators.field.FieldKeeper`,
    :class:`~lpy_light.estimators.reuse.StoreKeeper`), with its settings; None for ``nee``."""
    if name == "field":
        return FieldKeeper(field_settings(field), seed)
    if name == "reuse":
        return StoreKeeper(reuse_settings(reuse), seed)
    return None


def _plant_settings(**arguments) -> dict:
    """Next-event settings from :class:`LightModel`'s arguments (None: the default rule), each checked; an error
    names the argument."""
    from ..estimators.registry import NextEventSettings
    out = {}
    for argument, value in arguments.items():
        name = PLANT_SETTINGS[argument]
        if value is None and name in ("picks", "images"):
            continue
        try:
            NextEventSettings(**{name: value})
        except InputError as exc:
            raise InputError(str(exc).replace("next-event setting %r" % name, argument)) from None
        out[name] = value
    return out


def _photons(n) -> int:
    """Photons per step, checked where they are given (a whole number ≥ 1)."""
    try:
        value = float(n)
    except (TypeError, ValueError):
        value = math.nan
    if isinstance(n, bool) or not (value >= 1 and value == int(value) and value <= 1e15):
        raise InputError("photons must be a whole number >= 1, got %r" % (n,))
    return int(value)


def _xyz(p) -> str:
    return "(%s)" % ", ".join("%.4g" % x for x in p)


def lamp_factors(lamp_scale, chamber) -> np.ndarray:
    """(B,) factors on the lamps' flux per band from ``lamp_scale``: a number, or ``{"LO-HI": factor}``
    applied to the bands lying within LO-HI nm (see :class:`LightModel`)."""
    B = chamber.n_bands
    if isinstance(lamp_scale, Mapping):
        factor = np.ones(B)
        if chamber.bands is None:
            raise InputError("lamp_scale by band needs a scene with 'bands'")
        for span, k in lamp_scale.items():
            try:
                lo, hi = (float(x) for x in str(span).split("-"))
            except ValueError:
                raise InputError("lamp_scale: expected keys 'LO-HI' in nm (e.g. '700-800'), got %r" % (span,)) from None
            inside = [(b0 >= lo and b1 <= hi) for b0, b1 in chamber.bands]
            if not any(inside):
                raise InputError("lamp_scale: no band of the scene lies within %s nm (bands: %s)"
                                 % (span, ", ".join(chamber.band_labels)))
            factor[np.array(inside)] *= _factor(k)
        return factor
    return np.full(B, _factor(lamp_scale))


def _factor(k) -> float:
    try:
        k = float(k)
    except (TypeError, ValueError):
        k = math.nan
    if not (math.isfinite(k) and k >= 0):
        raise InputError("lamp_scale: expected a factor >= 0, got %r" % (k,))
    return k


def _goal_text(precision) -> str:
    """``{"par": 0.03, "rfr": 0.02}`` → ``"par 0.03, rfr 0.02"``; a number as it is."""
    if hasattr(precision, "items"):
        return ", ".join("%s %g" % (k, v) for k, v in precision.items())
    return "%g" % precision


def step_sigma_over_goal(kscene, result, rows, chamber, goal, flux) -> float:
    """The largest σ / goal among organs ``rows`` (indices into the step's organs) for the quantities ``goal``
    asks (:func:`lpy_light.plant.precision.sigma_over_goal`; ≤ 1: reached), from a run's photons so far."""
    r = kscene.n_sensors + kscene.n_chamber_receivers + np.asarray(rows)
    if len(r) == 0 or result.photons < 2:
        return math.inf
    return sigma_over_goal(goal, result.tally[r], result.covariance(r), flux, chamber.bands, chamber.band_labels)


