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
    base = "angers-12bands"                        # this scene is that one (path or built-in name) with
                                                   # the keys given here; optional
    lamp_flux = [812.0, ...]                       # µmol s-1 the lamps emit per band; optional
    [lamps.lamp20Str]                              # a light source's output and position; optional
    [materials.MurBlanc]                           # a material's reflectance, transmission split; optional
                                                   # (the last three: lpy_light.chamber.overrides; a fitted
                                                   # chamber from lpy-light calibrate has them)

    [physics]                                      # optional, SEC2's semantics by default
    one_sided = true          # a surface is seen only from its front (SEC2)
    lamps = "line"            # light cylinders: isotropic line sources (SEC2) | "lambertian"
    specular = "mirror"       # specular reflection: "mirror" (SEC2) | "phong" (lobe from roughness)
    coplanar = "random"       # a hit where surfaces coincide picks one at random (SEC2) | "arbitrary"
    materials = "sec2"        # .rad parameters of untabled materials: SEC2's reading | "radiance"
    repeated_names = "all"    # surfaces sharing an identifier: all kept (Radiance) | "last" (SEC2's reader)
    max_depth = 50            # scattering events before a photon is cut

Without ``bands`` the scene has one band, ``rad``, with the ``.rad`` values.

Geometry files are Radiance ``.rad`` files (SEC2's dialect included: :mod:`lpy_light.chamber.radiance`) and
Wavefront ``.obj`` files (:mod:`lpy_light.chamber.obj`), read in the order listed.  A ``.rad`` file that gives
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
from pathlib import Path

from .chamber import UNITS, Chamber, Physics, build_chamber
from ..errors import InputError
from .optical import read_optical_folder, read_specularities
from .radiance import MATERIAL_TYPES, SEC2_TYPES, SURFACE_TYPES, Primitive, RadFile, read_rad
from .sensors import Sensors, read_sensors

#: the chamber and how it is built are :mod:`lpy_light.chamber.chamber`'s; a scene reads into one
__all__ = ["UNITS", "SCALE_FACTOR_UNITS", "Chamber", "Physics", "build_chamber", "builtin_scenes", "resolve_scene",
           "load_scene", "chamber_from_spec", "read_geometry", "in_unit", "DATA"]

log = logging.getLogger("lpy_light")

#: SEC2's scale_factor (file units per metre) of each unit
SCALE_FACTOR_UNITS = {1000.0: "mm", 100.0: "cm", 10.0: "dm", 1.0: "m", 0.001: "km"}
_SCENE_KEYS = {"geometry", "sensors", "unit", "optical", "specularities", "bands", "solid_sensors", "remove",
               "physics", "spectrum", "calibration", "name", "plant_position", "flip_normals",
               "lamps", "materials", "lamp_flux", "surveyed"}
#: keys holding paths (relative to the scene file that gives them)
_PATH_KEYS = ("geometry", "sensors", "optical", "specularities", "spectrum", "solid_sensors")
_PHYSICS_KEYS = {"one_sided": bool, "lamps": str, "specular": str, "max_depth": int, "offset": float,
                 "coplanar": str, "materials": str, "repeated_names": str}


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


DATA = Path(__file__).parents[1] / "data"


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
    one choice and keeps the scene's others).  A file with ``base`` is that scene with the file's keys
    (:func:`read_spec`)."""
    path = Path(path)
    spec, folder, text = read_spec(path)
    overrides = {k: v for k, v in overrides.items() if v is not None}
    if isinstance(overrides.get("physics"), dict) and isinstance(spec.get("physics"), dict):
        overrides["physics"] = {**spec["physics"], **overrides["physics"]}
    spec.update(overrides)
    return chamber_from_spec(spec, folder, str(path), text)


def _merged(base: dict, child: dict) -> dict:
    """``base``'s keys with ``child``'s: tables of tables (``physics``, ``lamps.*``, ``materials.*``) key by key."""
    out = dict(base)
    for k, v in child.items():
        if k == "physics" and isinstance(v, dict) and isinstance(base.get(k), dict):
            out[k] = {**base[k], **v}
        elif k in ("lamps", "materials") and isinstance(v, dict) and isinstance(base.get(k), dict):
            out[k] = {n: ({**base[k][n], **t} if isinstance(t, dict) and isinstance(base[k].get(n), dict) else t)
                      for n, t in {**base[k], **v}.items()}
        else:
            out[k] = v
    return out


def read_spec(path, _seen=()) -> tuple:
    """A scene file's keys, the folder its paths are relative to, and its text: ``(spec, folder, text)``.

    With ``base = "other.toml"`` (relative to this file, or a built-in scene's name) the keys are the
    base's with this file's on top; this file's own paths are made absolute, so that every path
    still means the file it named."""
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
    if "base" not in spec:
        return spec, path.parent, text
    base = spec.pop("base")
    if not isinstance(base, str) or not base:
        raise InputError("'base' must be a scene file or a built-in scene's name", path, _line_of(text, "base"))
    base_path = path.parent / base
    if not base_path.is_file():
        if base in builtin_scenes():
            base_path = builtin_scenes()[base]
        else:
            raise InputError("base scene not found: %s (a scene file, relative to this one, or a built-in scene: "
                             "%s)" % (base, ", ".join(builtin_scenes())), path, _line_of(text, "base"))
    if base_path.resolve() in _seen or len(_seen) > 8:
        raise InputError("'base' leads back to %s: scenes based on each other" % base_path, path, _line_of(text, "base"))
    base_spec, folder, _ = read_spec(base_path, _seen + (path.resolve(),))
    for k in _PATH_KEYS:
        v = spec.get(k)
        if isinstance(v, str) and v:
            spec[k] = str(path.parent / v)
        elif isinstance(v, list):
            spec[k] = [str(path.parent / x) if isinstance(x, str) and x else x for x in v]
    if isinstance(spec.get("calibration"), str):
        spec["calibration"] = str(path.parent / spec["calibration"])
    elif isinstance(spec.get("calibration"), dict) and isinstance(spec["calibration"].get("file"), str):
        spec["calibration"] = {**spec["calibration"], "file": str(path.parent / spec["calibration"]["file"])}
    return _merged(base_spec, spec), folder, text


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
    from . import overrides
    for key, apply in (("lamps", overrides.apply_lamps), ("materials", overrides.apply_materials)):
        table = spec.get(key)
        if table is not None:
            if not isinstance(table, dict):
                raise err("'%s' must be tables [%s.NAME]" % (key, key), key)
            chamber.overrides[key] = apply(chamber, table, err)
    if spec.get("lamp_flux") is not None:
        chamber.lamp_flux = overrides.lamp_flux(spec["lamp_flux"], chamber.n_bands, err)
    if spec.get("surveyed") is not None:
        chamber.surveyed = overrides.read_surveyed(spec["surveyed"], err)
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
