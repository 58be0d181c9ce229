"""A growth chamber ready to trace: surfaces, materials, lamps, sensors, bands.

Scene files (TOML) name the inputs; paths are relative to the scene file::

    geometry = "geometry/testChamber.rad"        # or a list of .rad (and .obj) files
    sensors = "sensors/captors_expe1.csv"          # or a list; optional
    unit = "mm"                                    # mm (default, or the unit of SEC2's scale_factor), cm, m, km
    optical = "optical"                            # folder of measured tables; optional
    specularities = "optical/Specularities.xlsx"   # or .csv; optional
    bands = [[655, 665]]                           # nm, [start, end); optional
    spectrum = "spectrum/chambre1_spectrum.txt"    # lamp spectrum -> ppfd (µmol m-2 s-1); optional
    solid_sensors = "receivers.rad"                # opaque sensors with a material; optional
    remove = ["fauxPlafondInf"]                    # identifiers to leave out; optional
    plant_position = [1020, 920, 900]              # where a plant's origin goes (scene units); optional
    flip_normals = false                           # every geometry surface faces the other way; optional
    calibration = "measured.csv"                   # measured sensors -> ppfd scale per band; optional
                                                   # (or {file = "measured.csv", tolerance = 20})

    [physics]                                      # optional, SEC2's semantics by default
    one_sided = true          # a surface is seen only from its front (SEC2)
    lamps = "line"            # light cylinders: isotropic line sources (SEC2) | "lambertian"
    specular = "mirror"       # specular reflection: "mirror" (SEC2) | "phong" (lobe from roughness)
    coplanar = "random"       # a hit where surfaces coincide picks one at random (SEC2) | "arbitrary"
    materials = "sec2"        # .rad parameters of untabled materials: SEC2's reading | "radiance"
    repeated_names = "all"    # surfaces sharing an identifier: all kept (Radiance) | "last" (SEC2's reader)
    max_depth = 50            # scattering events before a photon is cut

Without ``bands`` the scene has one band, ``rad``, with the ``.rad`` values.

Geometry files are Radiance ``.rad`` files (SEC2's dialect included: :mod:`lpy_light.radiance`) and
Wavefront ``.obj`` files (:mod:`lpy_light.obj`), read in the order listed.  A ``.rad`` file that gives
SEC2's ``scale_factor N`` has its lengths in 1/N metre: without ``unit`` the scene takes that unit,
with one the file is converted to it.  An OBJ face's ``usemtl`` name is a material defined in a
``.rad`` file listed before the OBJ, else the scene's optical tables of that name (a ``trans``
material if there is a transmittance table, else ``plastic``; specular fraction from
``specularities``).  ``flip_normals = true`` turns every surface of ``geometry`` to face the other
way (photon_mapping's ``flip_normal``: for files written with their fronts facing out of the room).
"""
from __future__ import annotations

import logging
import math
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import geometry as geo
from .emitters import EmitterBuilder, Emitters
from .errors import InputError
from .materials import EMITTING, Material, build_material
from .optical import read_optical_folder, read_specularities
from .radiance import MATERIAL_TYPES, SEC2_TYPES, SURFACE_TYPES, UNSUPPORTED_TYPES, Primitive, RadFile, read_rad
from .sensors import Sensors, read_sensors

log = logging.getLogger("lpy_light")

UNITS = {"mm": 1e-3, "cm": 1e-2, "dm": 1e-1, "m": 1.0, "km": 1e3}
#: SEC2's scale_factor (file units per metre) of each unit
SCALE_FACTOR_UNITS = {1000.0: "mm", 100.0: "cm", 10.0: "dm", 1.0: "m", 0.001: "km"}
_SCENE_KEYS = {"geometry", "sensors", "unit", "optical", "specularities", "bands", "solid_sensors", "remove",
               "physics", "spectrum", "calibration", "name", "plant_position", "flip_normals"}
_PHYSICS_KEYS = {"one_sided": bool, "lamps": str, "specular": str, "max_depth": int, "offset": float,
                 "coplanar": str, "materials": str, "repeated_names": str}


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


# ------------------------------------------------------------------------------------------
_TOML_KEY = r"""(?:[A-Za-z0-9_-]+|"(?:[^"\\]|\\.)*"|'[^']*')(?:\s*\.\s*(?:[A-Za-z0-9_-]+|"(?:[^"\\]|\\.)*"|'[^']*'))*"""
_TOML_ASSIGN = re.compile(r"\s*(%s)\s*=" % _TOML_KEY)
_TOML_TABLE = re.compile(r"\s*\[\[?\s*(%s)\s*\]" % _TOML_KEY)


def _key_path(key: str) -> tuple:
    """A TOML key as written (``physics.lamps``, ``"g\\u00e9ometry"``) -> its parts, as TOML reads them."""
    try:
        parsed = tomllib.loads(key + " = 0")
    except tomllib.TOMLDecodeError:
        return ()
    parts = []
    while isinstance(parsed, dict) and len(parsed) == 1:
        (k, parsed), = parsed.items()
        parts.append(k)
    return tuple(parts)


def _line_of(text: str, key) -> int | None:
    """Line of the TOML text where ``key`` (dotted for a table's key: ``physics.lamps``) is given, or None.

    Tables (``[physics]`` then ``lamps = ...``), dotted keys (``physics.lamps = ...``), quoted keys and
    inline tables (``physics = {lamps = ...}``: the line of ``physics =``) are followed; the line that
    gives the key itself is preferred, else the one giving the nearest table that holds it."""
    target = key if isinstance(key, tuple) else tuple(key.split("."))
    best, best_len = None, 0
    table = ()
    for number, line in enumerate(text.split("\n"), start=1):
        header = _TOML_TABLE.match(line)
        if header:
            table = _key_path(header.group(1))
            path = table
        else:
            assign = _TOML_ASSIGN.match(line)
            if not assign:
                continue
            path = table + _key_path(assign.group(1))
        if path and path[:len(target)] == target:      # the key itself (or a key inside it)
            return number
        n = len(path)
        if n and path == target[:n] and n > best_len:  # a table holding it
            best, best_len = number, n
    return best


def _is_number(x) -> bool:
    """A finite int or float, not a bool (TOML's true/false are Python bools, which are ints)."""
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


#: coordinates beyond this (in scene units) are refused: Embree traces in single precision
MAX_COORDINATE = geo.MAX_COORDINATE


DATA = Path(__file__).parent / "data"


def builtin_scenes() -> dict:
    """The scenes shipped with lpy-light: ``{name: path of its TOML}`` (``lpy-light scenes`` lists them)."""
    return {p.stem: p for p in sorted(DATA.glob("*/*.toml"))}


def resolve_scene(name) -> Path:
    """A scene file's path from a path or a built-in scene's name (``angers``, ``angers-12bands``, ...).

    A folder stands for the ``scene.toml`` in it, or its only ``.toml`` file; a folder with neither that has a
    built-in scene's name (e.g. the results of ``run angers --out angers``) is not taken for a scene."""
    path = Path(name)
    scenes = builtin_scenes()
    if path.is_dir():
        found = [path / "scene.toml"] if (path / "scene.toml").is_file() else sorted(path.glob("*.toml"))
        if len(found) == 1:
            return found[0]
        if str(name) not in scenes:
            raise InputError("a folder, not a scene file: give its scene's .toml (%s)"
                             % ("it has %d: %s" % (len(found), ", ".join(f.name for f in found)) if found
                                else "it has none"), name)
    elif path.exists():
        return path
    if str(name) in scenes:
        return scenes[str(name)]
    raise InputError("scene file not found (built-in scenes: %s)" % ", ".join(scenes), name)


def load_scene(path, **overrides) -> Chamber:
    """Read a scene TOML file and everything it names; return a :class:`Chamber`.

    ``overrides`` replace the file's keys (``None`` leaves a key alone), except ``physics``: a table
    merged key by key into the file's ``[physics]`` (``physics={"one_sided": False}`` changes that
    one choice and keeps the scene's others)."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig")     # a byte-order mark, as some editors write, is dropped
    except OSError as exc:
        raise InputError("cannot read scene file: %s" % exc.strerror, path) from None
    except UnicodeDecodeError as exc:
        raise InputError("scene file is not UTF-8 text (byte 0x%02x)" % exc.object[exc.start], path,
                         exc.object.count(b"\n", 0, exc.start) + 1) from None
    try:
        spec = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        msg = str(exc)
        line = None
        if "line " in msg:
            try:
                line = int(msg.split("line ")[1].split(",")[0].split(")")[0])
            except ValueError:
                line = None
        elif "end of document" in msg:      # e.g. an unclosed array: the problem shows at the last line
            line = len(text.rstrip("\n").split("\n"))
        raise InputError("not valid TOML: %s" % msg.split(" (at")[0], path, line) from None
    overrides = {k: v for k, v in overrides.items() if v is not None}
    if isinstance(overrides.get("physics"), dict) and isinstance(spec.get("physics"), dict):
        overrides["physics"] = {**spec["physics"], **overrides["physics"]}
    spec.update(overrides)
    return chamber_from_spec(spec, path.parent, str(path), text)


def chamber_from_spec(spec: dict, base: Path, name: str = "<scene>", text: str = "") -> Chamber:
    def err(msg, key=None):
        return InputError(msg, name, _line_of(text, key) if key else None)

    unknown = set(spec) - _SCENE_KEYS
    if unknown:
        k = sorted(unknown)[0]
        raise err("unknown key %r (known: %s)" % (k, ", ".join(sorted(_SCENE_KEYS))), (k,))
    if "geometry" not in spec:
        raise err("missing 'geometry' (a .rad file or a list of them)")
    if spec["geometry"] in ([], ""):
        raise err("'geometry' is empty: expected a .rad file or a list of them", "geometry")
    if "name" in spec and not isinstance(spec["name"], str):
        raise err("'name' must be a string", "name")

    inputs = [Path(name)]          # every file read, so that results never overwrite one (cli.check_outputs)

    def paths(key, many=True, folder=False):
        value = spec.get(key)
        if value is None:
            return []
        items = value if isinstance(value, list) and many else [value]
        if not all(isinstance(v, str) and v for v in items):
            raise err("%r must be a path%s" % (key, " or a list of paths" if many else ""), key)
        out = []
        for v in items:
            p = (base / v) if not Path(v).is_absolute() else Path(v)
            if not p.exists():
                raise err("%s file not found: %s" % (key, p), key)
            if not folder and not p.is_file():     # a folder, a pipe, a device: would fail, hang or never end
                raise err("%s must be a regular file: %s" % (key, p), key)
            out.append(p)
        inputs.extend(out)
        return out

    unit = spec.get("unit")
    if unit is not None and (not isinstance(unit, str) or unit not in UNITS):
        raise err("unknown unit %r (use one of %s)" % (unit, ", ".join(UNITS)), "unit")
    flip = spec.get("flip_normals", False)
    if not isinstance(flip, bool):
        raise err("'flip_normals' must be true or false", "flip_normals")
    bands = spec.get("bands")
    if bands is not None:
        if not isinstance(bands, list) or not bands:
            raise err("'bands' must be a list of [start, end] pairs in nm, e.g. [[655, 665]], got %r" % (bands,),
                      "bands")
        for b in bands:
            if not (isinstance(b, list) and len(b) == 2 and all(_is_number(x) for x in b)):
                raise err("'bands': expected [start, end] in nm (two finite numbers), got %r" % (b,), "bands")
            if not 0 < b[0] < b[1]:
                raise err("'bands': expected 0 < start < end, got %r" % (b,), "bands")
        bands = [(float(a), float(b)) for a, b in bands]
        # overlapping bands are fine (e.g. 400-700 beside 655-665): each band travels on its own weights
        if len(set(bands)) < len(bands):
            raise err("'bands': a band is given twice (%s)" % ", ".join(
                "[%g, %g]" % b for b in sorted(set(b for b in bands if bands.count(b) > 1))), "bands")
        labels = ["%g-%g" % b for b in bands]       # Chamber.band_labels: how results name a band
        for i, label in enumerate(labels):
            if label in labels[:i]:
                raise err("'bands': %r and %r would both be named %s in the results (6 significant digits)"
                          % (list(bands[labels.index(label)]), list(bands[i]), label), "bands")
    physics = Physics()
    table = spec.get("physics")
    if table is not None and not isinstance(table, dict):
        raise err("'physics' must be a table ([physics] with one_sided, lamps, specular, max_depth, offset)",
                  "physics")
    for key, value in (table or {}).items():
        if key not in _PHYSICS_KEYS:
            raise err("unknown physics option %r (known: %s)" % (key, ", ".join(_PHYSICS_KEYS)), ("physics", key))
        kind = _PHYSICS_KEYS[key]
        if kind is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if not isinstance(value, kind) or (kind is int and isinstance(value, bool)):
            raise err("physics option %r must be a %s" % (key, kind.__name__), ("physics", key))
        setattr(physics, key, value)
    if physics.lamps not in ("line", "lambertian"):
        raise err("physics.lamps must be 'line' or 'lambertian'", "physics.lamps")
    if physics.specular not in ("mirror", "phong"):
        raise err("physics.specular must be 'mirror' or 'phong'", "physics.specular")
    if physics.coplanar not in ("random", "arbitrary"):
        raise err("physics.coplanar must be 'random' or 'arbitrary'", "physics.coplanar")
    if physics.materials not in ("sec2", "radiance"):
        raise err("physics.materials must be 'sec2' or 'radiance'", "physics.materials")
    if physics.repeated_names not in ("all", "last"):
        raise err("physics.repeated_names must be 'all' or 'last'", "physics.repeated_names")
    if not 0 <= physics.max_depth <= 10000:
        raise err("physics.max_depth must be in 0..10000", "physics.max_depth")
    if not 0 < physics.offset < 1e-2:   # NaN fails too
        raise err("physics.offset must be in (0, 0.01)", "physics.offset")

    def on_scene_line(exc, key):
        """An error about a file as a whole (no line in it) moved to the scene file's line naming it."""
        if exc.line is None:
            where = " ".join(x for x in (key, exc.path) if x)
            return err("%s: %s" % (where, exc.reason) if exc.path else exc.reason, key)
        return exc

    def read(key, reader, p):
        try:
            return reader(p)
        except InputError as exc:
            raise on_scene_line(exc, key) from None

    optical_dirs = paths("optical", many=False, folder=True)     # read_optical_folder says if it is not one
    optical = read("optical", read_optical_folder, optical_dirs[0]) if optical_dirs else None
    spec_files = paths("specularities", many=False)
    specularities = read("specularities", read_specularities, spec_files[0]) if spec_files else None
    if optical is not None and bands is None:
        raise err("'optical' tables need 'bands' (e.g. bands = [[655, 665]])", "optical")

    remove = spec.get("remove") or []
    if not isinstance(remove, list) or not all(isinstance(r, str) for r in remove):
        raise err("'remove' must be a list of identifiers", "remove")
    pos = spec.get("plant_position")
    if pos is not None and not (isinstance(pos, list) and len(pos) == 3 and all(_is_number(x) for x in pos)):
        raise err("'plant_position' must be [x, y, z] in scene units (finite numbers), got %r" % (pos,),
                  "plant_position")
    geometry_files = [read("geometry", read_geometry, p) for p in paths("geometry")]
    solid_files = [read("solid_sensors", read_rad, p) for p in paths("solid_sensors")]
    if unit is None:
        unit = _unit_of(geometry_files + solid_files)
    prims = []
    for part in geometry_files:
        part = in_unit(part, unit)
        if str(part.path).lower().endswith(".obj"):
            part = _table_materials(prims, part, optical) + list(part)
        prims.extend(part)
    solid = []
    for part in solid_files:
        solid.extend(in_unit(part, unit))
    sensors = Sensors.concat(read("sensors", read_sensors, p) for p in paths("sensors"))
    spectrum = None
    for p in paths("spectrum", many=False):
        from .units import read_lamp_spectrum
        spectrum = read("spectrum", read_lamp_spectrum, p)
    try:
        chamber = build_chamber(prims, sensors, bands=bands, optical=optical, specularities=specularities,
                                physics=physics, unit=unit, solid=solid, remove=remove, flip=flip)
    except InputError as exc:    # the scene as a whole (no light), or a table that misses a band
        raise on_scene_line(exc, getattr(exc, "key", None)) from None
    has_obj = any(str(part.path).lower().endswith(".obj") for part in geometry_files)
    _warn_unused_tables(chamber, optical, specularities, spec_files[0] if spec_files else None, has_obj)
    if spectrum is not None:
        if bands is None:
            raise err("'spectrum' (photons -> µmol m-2 s-1 per band) needs 'bands' (e.g. bands = [[655, 665]])",
                      "spectrum")
        from .units import band_photon_flux
        read("spectrum", lambda s: band_photon_flux(s, bands), spectrum)    # every band covered, before tracing
    chamber.spectrum = spectrum
    chamber.optical = optical
    if pos is not None:
        chamber.plant_position = [float(x) for x in pos]
    cal = spec.get("calibration")
    if cal is not None:
        if isinstance(cal, str):
            cal = {"file": cal}
        tol = cal.get("tolerance") if isinstance(cal, dict) else None
        if (not isinstance(cal, dict) or set(cal) - {"file", "tolerance"} or not isinstance(cal.get("file"), str)
                or not (tol is None or (isinstance(tol, (int, float)) and not isinstance(tol, bool) and tol > 0))):
            raise err("'calibration' must be a csv path or {file = \"measured.csv\", tolerance = D} "
                      "(D > 0, scene units)", "calibration")
        p = base / cal["file"] if not Path(cal["file"]).is_absolute() else Path(cal["file"])
        if not p.is_file():
            raise err("calibration file not found: %s" % p, "calibration")
        inputs.append(p)
        chamber.calibration = (p, None if tol is None else float(tol))
    chamber.source = name
    chamber.inputs = inputs
    return chamber


def read_geometry(path) -> RadFile:
    """One geometry file: Wavefront ``.obj`` by its suffix, else Radiance (SEC2's dialect included)."""
    if Path(path).suffix.lower() == ".obj":
        from .obj import read_obj
        return read_obj(path)
    return read_rad(path)


def _unit_of(files) -> str:
    """The scene's unit when the scene file names none: that of the first SEC2 ``scale_factor`` among
    ``files``, else millimetres."""
    for part in files:
        if part.scale_factor is not None:
            name = SCALE_FACTOR_UNITS.get(part.scale_factor)
            if name is None:
                raise InputError("scale_factor %g (lengths in 1/%g m) is none of lpy-light's units (%s): give the "
                                 "scene's 'unit' and this file is converted to it"
                                 % (part.scale_factor, part.scale_factor, ", ".join(UNITS)),
                                 part.path, part.scale_line)
            return name
    return "mm"


def in_unit(part: RadFile, unit: str) -> RadFile:
    """The primitives of one file with their lengths in the scene's ``unit``: unchanged unless the file gives
    SEC2's ``scale_factor N`` (lengths in 1/N m) for another unit.  Lengths: every real of a surface or
    point light but a ring's normal and a spot light's angle and direction."""
    if part.scale_factor is None:
        return part
    k = 1.0 / (part.scale_factor * UNITS[unit])
    if math.isclose(k, 1.0, rel_tol=1e-12):
        return part
    log.info("%s:%d: scale_factor %g: lengths multiplied by %g into the scene's %s", part.path, part.scale_line,
             part.scale_factor, k, unit)
    out = RadFile(path=part.path, sec2=part.sec2, scale_factor=part.scale_factor, scale_line=part.scale_line)
    for prim in part:
        t, r = prim.type, list(prim.reals)
        if t in SURFACE_TYPES or t in SEC2_TYPES:
            lengths = {"ring": (0, 1, 2, 6, 7), "spot_light": (0, 1, 2)}.get(t, range(len(r)))
            for j in lengths:
                if j < len(r):
                    r[j] *= k
            prim = Primitive(prim.modifier, t, prim.identifier, prim.strings, prim.ints, r, prim.path, prim.line)
        out.append(prim)
    return out


def _table_materials(before, part, optical) -> list:
    """Material primitives for the ``usemtl`` names of an OBJ file (``part``) that no ``.rad`` file listed
    before it defines (``before``: the primitives read so far) but that the optical tables have: ``trans``
    with a transmittance table, else ``plastic``; all their values come from the tables (and the
    specularities).  Names with neither are left to :func:`build_chamber`'s error, at the face's line."""
    defined = {p.identifier for p in before if p.type in MATERIAL_TYPES}
    tables = {} if optical is None else {**optical.reflectance, **optical.transmittance}
    made, out = set(), []
    for face in part:
        name = face.modifier
        if name in defined or name in made or name not in tables:
            continue
        made.add(name)
        trans = name in optical.transmittance
        out.append(Primitive("void", "trans" if trans else "plastic", name, [], [], [0.0] * (7 if trans else 5),
                             face.path, face.line))
        log.info("%s: material %r (usemtl) from the optical tables: %s", face.where, name,
                 "trans" if trans else "plastic")
    return out


def _warn_unused_tables(chamber, optical, specularities, spec_path, has_obj=False):
    """Warn about measured values that no material of the scene uses: a table or specularity whose name
    differs from a material's only in case (names are case-sensitive, as in Radiance), or a table outside
    a ``Plant`` folder (those are for organs) named after no material — the material then silently keeps
    its ``.rad`` values.  With OBJ geometry (materials made from the tables by name) a table no face uses
    is only a table of the library, and only the first warning is given."""
    names = {m.name for m in chamber.materials}
    lower = {n.lower(): n for n in names}

    def hint(name):
        near = lower.get(name.lower())
        return "; the scene has %r (names are case-sensitive)" % near if near else ""

    for kind, tables in ((("reflectance", optical.reflectance), ("transmittance", optical.transmittance))
                         if optical is not None else ()):
        for name, table in tables.items():
            if name not in names and (name.lower() in lower or ("Plant" not in Path(table.path).parts
                                                                and not has_obj)):
                log.warning("%s: no material %r in the scene uses this %s table%s", table.path, name, kind, hint(name))
    for name in specularities or {}:
        if name not in names and name.lower() in lower:
            log.warning("%s: no material %r in the scene uses its specular fraction%s", spec_path, name, hint(name))


# ------------------------------------------------------------------------------------------
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
