"""The chamber as the kernel needs it: :class:`Chamber` (triangles, materials, lamps, sensors, receivers, in scene
units), :class:`Physics` (the modelling choices) and :func:`build_chamber` (Radiance primitives → a Chamber).

Reading a scene file (which files, which unit, which tables) is :mod:`lpy_light.chamber.scene`'s; this module turns what
was read into arrays.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np

from . import geometry as geo
from .emitters import EmitterBuilder, Emitters
from ..errors import InputError
from .materials import EMITTING, Material, build_material
from .radiance import MATERIAL_TYPES, SEC2_TYPES, SURFACE_TYPES, UNSUPPORTED_TYPES
from .sensors import Sensors

log = logging.getLogger("lpy_light")

#: metres per unit of each unit a scene may be written in
UNITS = {"mm": 1e-3, "cm": 1e-2, "dm": 1e-1, "m": 1.0, "km": 1e3}
MAX_COORDINATE = geo.MAX_COORDINATE


@dataclass
class Physics:
    """Modelling choices; the defaults are SEC2's (see docs/physics.md)."""

    one_sided: bool = True
    lamps: str = "line"
    specular: str = "mirror"
    coplanar: str = "random"     # coincident coplanar surfaces: "random" (fair choice per hit) | "arbitrary"
    materials: str = "sec2"      # .rad material parameters without tables: "sec2" | "radiance" (materials.py)
    # surfaces of the geometry that share an identifier: "all" kept (Radiance) | only the "last" one (SEC2 and
    # the photon-mapping engine read a .rad into a table by name, where a repeated name replaces the earlier
    # surface; the Angers chamber's lamp-box mirror at x = 50 is lost that way: docs/validation.md, section 8)
    repeated_names: str = "all"
    max_depth: int = 50
    offset: float = 2.0 ** -21   # ray offset, relative to the hit's round-off scale (docs/stability.md)


@dataclass
class Chamber:
    """Everything the kernel needs, in scene units.

    ``triangles`` (T, 3, 3) with ``tri_material`` (T, 2) (front, back material
    index), ``tri_receiver`` (T,) (receiver index or -1) and ``tri_two_sided`` (T,).
    """

    triangles: np.ndarray
    tri_material: np.ndarray
    tri_receiver: np.ndarray
    tri_two_sided: np.ndarray
    tri_source: list            # per triangle: index into ``surfaces``
    surfaces: list              # (identifier, type, "file:line") of each surface primitive
    materials: list             # Material
    emitters: Emitters
    sensors: Sensors
    receivers: list             # names of opaque receivers
    receiver_area: np.ndarray   # (R,) one-sided area, scene units²
    bands: list | None
    unit: str = "mm"
    physics: Physics = field(default_factory=Physics)
    skipped: list = field(default_factory=list)
    spectrum: object = None     # lamp spectrum (units.read_lamp_spectrum) or None
    optical: object = None      # optical.OpticalLibrary, for organ materials, or None
    plant_position: list | None = None   # where a plant's origin goes, scene units
    calibration: tuple | None = None     # (measured csv Path, tolerance or None): units.read_measured
    lamp_flux: np.ndarray | None = None  # (B,) µmol s-1 the lamps emit per band (a scene's lamp_flux), or None
    overrides: dict = field(default_factory=dict)  # what the scene's [lamps.*] / [materials.*] tables changed
    surveyed: dict | None = None  # the region a calibration's survey constrains ([surveyed]: lower, upper, margin, sigma)
    inputs: list = field(default_factory=list)   # the files the scene was read from (Paths)
    source: str = ""

    @property
    def band_labels(self) -> list:
        if self.bands is None:
            return ["rad"]
        return ["%g-%g" % (a, b) for a, b in self.bands]

    @property
    def metres_per_unit(self) -> float:
        return UNITS[self.unit]

    @property
    def n_bands(self) -> int:
        return 1 if self.bands is None else len(self.bands)


def _check_arguments(prim):
    """Radiance's own rule for the types we read: no integer arguments, and no string arguments except a
    mirror's one (its alternate material, which lpy-light does not use)."""
    if prim.ints:
        raise InputError("%s %s takes no integer arguments, got %d" % (prim.type, prim.identifier, len(prim.ints)),
                         prim.path, prim.line)
    allowed = 1 if prim.type == "mirror" else 0
    if len(prim.strings) > allowed:
        raise InputError("%s %s takes %s string arguments, got %d (%s)"
                         % (prim.type, prim.identifier, "no" if not allowed else "at most %d" % allowed,
                            len(prim.strings), " ".join(prim.strings)), prim.path, prim.line)


def _point_light(prim, materials, current, emit, is_receiver):
    """SEC2's ``point`` (its radius ignored, as SEC2 does) or ``point_light``: an isotropic point at the
    centre with its light material's power; ``spot_light`` is refused (its cone is not documented)."""
    t, name = prim.type, prim.identifier
    if is_receiver:
        raise InputError("%s %s: a light source cannot be a solid sensor" % (t, name), prim.path, prim.line)
    if t == "spot_light":
        raise InputError("spot_light %s: SEC2's spot lights are not supported: how SEC2 spreads their light in "
                         "the cone (half or full angle, uniform or not) is not known from any file or document at "
                         "hand; use a point_light (isotropic) or a light polygon" % name, prim.path, prim.line)
    if prim.modifier not in current:
        raise InputError("%s %s uses undefined modifier %r (a light material defined before it)"
                         % (t, name, prim.modifier), prim.path, prim.line)
    material = materials[current[prim.modifier]]
    if material.type not in EMITTING:
        raise InputError("%s %s uses %r, a %s: a point light needs a light (or glow) material"
                         % (t, name, prim.modifier, material.type), prim.path, prim.line)
    big = max(abs(x) for x in prim.reals[:3])
    if big > MAX_COORDINATE:
        raise InputError("%s %s: coordinate %g is beyond ±%g scene units (the tracer works in single precision); "
                         "is the unit right?" % (t, name, big, MAX_COORDINATE), prim.path, prim.line)
    if material.radiance > 0:
        emit.point(prim.reals[:3], material.radiance, name)


def build_chamber(prims, sensors=None, bands=None, optical=None, specularities=None, physics=None,
                  unit="mm", solid=(), remove=(), flip=False) -> Chamber:
    """Turn Radiance primitives into a :class:`Chamber`.

    Materials are looked up as Radiance does: the latest definition before the
    surface that uses it.  ``solid`` primitives become opaque receivers (one per
    surface).  ``remove`` leaves out every primitive with one of these
    identifiers (and errors if one matches nothing).  ``flip``: every surface of
    ``prims`` faces the other way (not ``solid``).  SEC2's ``point`` and
    ``point_light`` are isotropic points (:meth:`EmitterBuilder.point`).  With
    ``physics.repeated_names = "last"`` a surface of ``prims`` whose identifier a
    later surface of ``prims`` repeats is left out (SEC2's reading).
    """
    physics = physics or Physics()
    materials: list[Material] = []
    current: dict[str, int] = {}
    skipped_types: dict[str, object] = {}
    emit = EmitterBuilder(physics.lamps)
    tris, mats, recv, source, surfaces = [], [], [], [], []
    receivers, receiver_area = [], []
    skipped = []
    remove = set(remove)
    removed = set()

    stream = [(p, False) for p in prims] + [(p, True) for p in solid]
    last = {}      # identifier -> the last surface of the geometry that has it
    if physics.repeated_names == "last":
        for i, (prim, is_receiver) in enumerate(stream):
            if not is_receiver and prim.type in SURFACE_TYPES:
                last[prim.identifier] = i
    for i, (prim, is_receiver) in enumerate(stream):
        if prim.identifier in remove:
            removed.add(prim.identifier)
            continue
        if last.get(prim.identifier, i) != i and prim.type in SURFACE_TYPES:
            log.info("%s: %s %s left out: the %s of the same name at %s replaces it (physics.repeated_names = "
                     "'last')", prim.where, prim.type, prim.identifier, stream[last[prim.identifier]][0].type,
                     stream[last[prim.identifier]][0].where)
            continue
        t = prim.type
        if t in MATERIAL_TYPES or t in SURFACE_TYPES:
            _check_arguments(prim)
        if t in MATERIAL_TYPES:
            if prim.modifier != "void":
                raise InputError("material %s %s: modifier %r not supported (materials must be modified by "
                                 "'void')" % (t, prim.identifier, prim.modifier), prim.path, prim.line)
            if prim.identifier == "void":
                raise InputError("%s void: 'void' is Radiance's name for no modifier, not a material's name" % t,
                                 prim.path, prim.line)
            materials.append(build_material(prim, bands, optical, specularities, physics.materials))
            current[prim.identifier] = len(materials) - 1
            continue
        if t in SEC2_TYPES:
            _point_light(prim, materials, current, emit, is_receiver)
            continue
        if t in UNSUPPORTED_TYPES:
            raise InputError("Radiance type %r is not supported by lpy-light (%s %s)" % (t, t, prim.identifier),
                             prim.path, prim.line)
        if t not in SURFACE_TYPES and prim.modifier != "void":
            raise InputError("unknown primitive type %r (%s %s %s): expected a surface (%s) or a material "
                             "(%s)" % (t, prim.modifier, t, prim.identifier, ", ".join(SURFACE_TYPES),
                                       ", ".join(MATERIAL_TYPES)), prim.path, prim.line)
        if t not in SURFACE_TYPES:
            msg = "unknown primitive type %r (%s %s %s): skipped" % (t, prim.modifier, t, prim.identifier)
            log.warning("%s: %s", prim.where, msg)
            skipped.append("%s: %s" % (prim.where, msg))
            skipped_types[prim.identifier] = prim
            continue
        # a surface
        if prim.modifier not in current:
            if prim.modifier in skipped_types:
                raise InputError("surface %s uses modifier %r, which was skipped (%s)"
                                 % (prim.identifier, prim.modifier, skipped_types[prim.modifier].where),
                                 prim.path, prim.line)
            hint = (" (an OBJ's usemtl names a material defined in a .rad file listed before the OBJ in "
                    "'geometry', or one the optical tables have)" if prim.path.lower().endswith(".obj") else "")
            raise InputError("surface %s %s uses undefined modifier %r%s" % (t, prim.identifier, prim.modifier, hint),
                             prim.path, prim.line)
        m = current[prim.modifier]
        material = materials[m]
        r = prim.reals
        expected = SURFACE_TYPES[t]
        if expected is None:
            if len(r) < 9 or len(r) % 3:
                raise InputError("polygon %s needs 3·n reals (n >= 3 vertices), got %d" % (prim.identifier, len(r)),
                                 prim.path, prim.line)
        elif len(r) != expected:
            raise InputError("%s %s needs %d real arguments, got %d" % (t, prim.identifier, expected, len(r)),
                             prim.path, prim.line)
        emitting = material.type in EMITTING and material.radiance > 0 and not is_receiver
        big = max((abs(x) for x in r), default=0.0)
        if big > MAX_COORDINATE:
            raise InputError("%s %s: coordinate %g is beyond ±%g scene units (the tracer works in single "
                             "precision); is the unit right?" % (t, prim.identifier, big, MAX_COORDINATE),
                             prim.path, prim.line)
        if emitting and t in ("tube", "bubble") and physics.lamps == "lambertian":
            raise InputError("%s %s: a %s faces inward, and so would its light; lamps = 'lambertian' emits from "
                             "cylinders and spheres outward only (use a cylinder or sphere)" % (t, prim.identifier, t),
                             prim.path, prim.line)
        try:
            if t == "polygon":
                surf = geo.triangulate_polygon(np.reshape(r, (-1, 3)))
            elif t in ("cylinder", "tube"):
                if not r[6] > 0 or np.allclose(r[0:3], r[3:6]):
                    raise ValueError("cylinder needs a radius > 0 and two distinct end points")
                if emitting:
                    emit.cylinder(r[0:3], r[3:6], r[6], material.radiance, prim.identifier)
                    surf = None   # a lamp is not an obstacle (radius ~0.1 mm)
                else:
                    surf = geo.cylinder(r[0:3], r[3:6], r[6], inward=(t == "tube"))
            elif t in ("sphere", "bubble"):
                if not r[3] > 0:
                    raise ValueError("sphere needs a radius > 0")
                if emitting:
                    emit.sphere(r[0:3], r[3], material.radiance, prim.identifier)
                    surf = None
                else:
                    surf = geo.sphere(r[0:3], r[3], inward=(t == "bubble"))
            else:  # ring
                if not (0 <= r[6] < r[7]) or not np.linalg.norm(r[3:6]) > 0:
                    raise ValueError("ring needs 0 <= inner radius < outer radius and a non-zero normal")
                surf = geo.ring(r[0:3], r[3:6], r[6], r[7])
        except ValueError as exc:
            raise InputError("%s %s: %s" % (t, prim.identifier, exc), prim.path, prim.line) from None
        if surf is None:
            continue
        if flip and not is_receiver:
            surf = surf[:, ::-1].copy()
        if emitting:
            emit.triangles(surf, material.radiance, prim.identifier)
        surfaces.append((prim.identifier, t, prim.where))
        tris.append(surf)
        mats.append(np.full(len(surf), m))
        source.append(np.full(len(surf), len(surfaces) - 1))
        if is_receiver:
            receivers.append(prim.identifier)
            receiver_area.append(geo.triangle_areas(surf).sum())
            recv.append(np.full(len(surf), len(receivers) - 1))
        else:
            recv.append(np.full(len(surf), -1))

    missing = remove - removed
    if missing:
        error = InputError("'remove' names identifiers not in the geometry: %s" % ", ".join(sorted(missing)))
        error.key = "remove"
        raise error
    emitters = emit.build()
    points = [p for p in prims if p.type in SEC2_TYPES and p.identifier in emitters.name]
    if points and len(points) < len(set(emitters.name)):
        log.warning("%s: the scene has SEC2 point lights and other lamps: photons are shared by power, a point "
                    "light's r g b read as a radiant intensity I (power 4πI), a lamp surface's as a radiance L "
                    "(power πLA); SEC2's own share between them is not known", points[0].where)
    if len(emitters) == 0:
        dark = [p for p in prims if p.type in ("light", "glow") and not any(x > 0 for x in p.reals[:3])]
        if dark:       # a lamp whose radiance is zero or negative: point at it
            raise InputError("the scene has no light source: %s %s has radiance %s (must be > 0)"
                             % (dark[0].type, dark[0].identifier, " ".join("%g" % x for x in dark[0].reals[:3])),
                             dark[0].path, dark[0].line)
        error = InputError("the scene has no light source (no light/glow surface with radiance > 0)")
        error.key = "geometry"        # named on the scene file's geometry line (chamber_from_spec)
        raise error
    total = float(np.sum(emitters.power))
    if not (math.isfinite(total) and total > 0):
        strongest = int(np.argmax(np.nan_to_num(emitters.power, nan=np.inf)))
        where = [p for p in prims if p.identifier == emitters.name[strongest]]
        raise InputError("the lamps' total power %g is not a finite positive number (radiance x area overflows); "
                         "scale the light's radiance down" % total,
                         where[0].path if where else None, where[0].line if where else None)
    if not tris:
        tris = [np.zeros((0, 3, 3))]
        mats, recv, source = [np.zeros(0, int)], [np.zeros(0, int)], [np.zeros(0, int)]
    triangles = np.concatenate(tris)
    front = np.concatenate(mats).astype(np.int32)
    return Chamber(triangles=triangles, tri_material=np.stack([front, front], 1),
                   tri_receiver=np.concatenate(recv).astype(np.int32),
                   tri_two_sided=np.full(len(triangles), not physics.one_sided),
                   tri_source=np.concatenate(source), surfaces=surfaces, materials=materials,
                   emitters=emitters, sensors=sensors if sensors is not None else Sensors(),
                   receivers=receivers, receiver_area=np.array(receiver_area, float),
                   bands=bands, unit=unit, physics=physics, skipped=skipped)
