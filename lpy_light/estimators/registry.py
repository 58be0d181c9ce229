"""The estimators, registered once: each one's name, what it does, and its settings as one frozen record.

A run's estimator is chosen by name (``lpy-light run --estimator``, ``LightModel(estimator=...)``,
:class:`lpy_light.estimators.kernel_scene.KernelScene`), always from :data:`ESTIMATORS`, with :data:`DEFAULT_ESTIMATOR`
the default everywhere.  Its next-event settings are a :class:`NextEventSettings`: checked where they are built (a
misspelt or out-of-range setting is an :class:`~lpy_light.errors.InputError` naming it), never changed in place -- a
changed setting is a new record (:meth:`NextEventSettings.replace`, :meth:`KernelScene.configure`).

Adding an estimator: one :class:`Estimator` entry here; the kernel tells estimators apart by what the records
built from it say (:meth:`KernelScene.records`), so a new one that the kernel already knows how to trace needs
nothing else (``docs/architecture.md``).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from ..errors import InputError
from ..kernel.organ_zones import ZONE_WALK

#: most targets per next event that may be asked (0, every target, is the way to ask for more)
MAX_PICKS = 4096
#: most events or rays per vertex any rate setting may ask
MAX_RATE = 64.0


@dataclass(frozen=True)
class NextEventSettings:
    """How next events are drawn (the ``nee`` estimator).  Rates are per photon vertex, on average.

    Parameters
    ----------
    sensors, receivers : bool
        Next events aim at the sensors, at the receivers (solid sensors, organs).
    picks : int
        Targets per next event, drawn at random by importance (0: every target at every vertex).
    control : bool
        With picks: the control variate -- every sensor's point-source value at every vertex, the picks carry
        only the difference.
    batch : int
        Photons per batch of the control variate's products between bands.
    images, images2 : float
        Next events through one, two planar perfect mirrors (0: that light is counted).
    zones : float
        Two-step next events through the surface right beside a disc sensor.
    importance : bool
        Organs: picks by importance (:mod:`lpy_light.kernel.importance`) and organ zone events.
    organ_zones : float or None
        Two-step next events through the organ surface beside a bud (None: by the buds' kind,
        :func:`lpy_light.estimators.kernel_scene.organ_zone_rate`).
    zone_walk : int
        Short legs an organ zone event walks on inside the bud's zone, at most.
    open_zones : bool
        An open bud's own surface is in its zone.
    closed_zones : bool
        A closed bud's own surface is in its zone too (with ``open_zones``): the light that enters it through its
        skin and bounces inside is estimated from every vertex by organ zone events, not left to the few photons
        that land on it (their own events from the bud itself held ~85 % of a bud's far-red variance).
    pick_share : bool
        Picks to organs follow each vertex's pick share (:func:`lpy_light.kernel.nee.pick_share`), its mean from a
        pilot; False: ``picks`` at every vertex.
    cones, local : float or None
        Rays into the cones of the organ clusters a vertex is far from; local rays to the large organs near it
        (None: by the number of organ targets, :func:`lpy_light.estimators.kernel_scene.cones_for`, ``local_for``).
    facing : bool
        Next events to a closed organ draw their point among its triangles facing the vertex
        (:func:`lpy_light.kernel.nee.facing_triangle`); False, an ablation: over the whole mesh.
    """

    sensors: bool = True
    receivers: bool = True
    picks: int = 1
    control: bool = True
    batch: int = 8
    images: float = 0.5
    images2: float = 0.25
    zones: float = 0.3
    importance: bool = True
    organ_zones: float | None = None
    zone_walk: int = ZONE_WALK
    open_zones: bool = True
    closed_zones: bool = True
    pick_share: bool = True
    cones: float | None = None
    local: float | None = None
    facing: bool = True

    def __post_init__(self):
        for name in ("sensors", "receivers", "control", "importance", "open_zones", "closed_zones", "pick_share", "facing"):
            if not isinstance(getattr(self, name), (bool, int)) or getattr(self, name) not in (0, 1):
                raise InputError("next-event setting %r must be True or False, got %r" % (name, getattr(self, name)))
            object.__setattr__(self, name, bool(getattr(self, name)))
        _whole(self, "picks", 0, MAX_PICKS, "0 = every target at every vertex")
        _whole(self, "batch", 1, 1 << 20, "photons per batch of the control variate")
        _whole(self, "zone_walk", 0, 1024, "short legs a zone event walks on")
        for name in ("images", "images2", "zones", "organ_zones", "cones", "local"):
            _rate(self, name, optional=name in ("organ_zones", "cones", "local"))

    def replace(self, **changes) -> NextEventSettings:
        """A copy with ``changes`` (names as the fields), checked; an unknown name is an InputError naming it."""
        fields = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(changes) - fields)
        if unknown:
            raise InputError("unknown next-event setting%s %s (the settings: %s)"
                             % ("s" if len(unknown) > 1 else "", ", ".join(map(repr, unknown)), ", ".join(sorted(fields))))
        return dataclasses.replace(self, **changes)


def _whole(settings, name, lo, hi, what):
    value = getattr(settings, name)
    if isinstance(value, bool) or not isinstance(value, (int, float)) or value != int(value) or not lo <= value <= hi:
        raise InputError("next-event setting %r must be a whole number in %d..%d (%s), got %r"
                         % (name, lo, hi, what, value))
    object.__setattr__(settings, name, int(value))


def _rate(settings, name, optional=False):
    value = getattr(settings, name)
    if value is None and optional:
        return
    try:
        ok = not isinstance(value, bool) and 0 <= float(value) <= MAX_RATE
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise InputError("next-event setting %r must be a rate in 0..%g per vertex%s, got %r"
                         % (name, MAX_RATE, " (or None: the default rule)" if optional else "", value))
    object.__setattr__(settings, name, float(value))


#: no next events: what ``weighted`` and ``analog`` trace with
NO_NEXT_EVENTS = NextEventSettings(sensors=False, receivers=False)


@dataclass(frozen=True)
class Estimator:
    """One estimator: its ``name``, a one-line ``summary`` (the command line's help), whether photons carry a
    weight through the bands (``weighted``: False for ``analog``, SEC2's counting) and its default
    :class:`NextEventSettings` (``settings``)."""

    name: str
    summary: str
    weighted: bool
    settings: NextEventSettings
    stored: bool = False       # the chamber's light stored once, a plant's organs lit from it
                               # (lpy_light.estimators.reuse, .field)

    @property
    def next_events(self) -> bool:
        return self.settings.sensors or self.settings.receivers


ESTIMATORS: dict = {e.name: e for e in (
    Estimator("nee", "expected absorption at every hit plus next-event tallies on sensors and receivers: the "
                     "most precise per second", True, NextEventSettings()),
    Estimator("weighted", "no next events: every photon's own hits, bands share events; for the energy closure "
                          "per material", True, NO_NEXT_EVENTS),
    Estimator("analog", "SEC2's counting: one photon, one event, raw hit counts", False, NO_NEXT_EVENTS),
    Estimator("reuse", "plants only (LightModel, grow): the chamber's light traced once into a store, gathered at "
                       "every organ each step through the current plant", True, NextEventSettings(), stored=True),
    Estimator("field", "plants only (LightModel, grow): the light entering the plant's region traced once into a "
                       "field; each step's rays stay in the region and read it where they leave", True,
              NextEventSettings(), stored=True),
)}
DEFAULT_ESTIMATOR = "nee"


def estimator(name: str) -> Estimator:
    """The registered estimator ``name``, or an InputError listing them."""
    try:
        return ESTIMATORS[name]
    except (KeyError, TypeError):
        raise InputError("unknown estimator %r (one of %s)" % (name, ", ".join(ESTIMATORS))) from None
