"""A corpus of malformed inputs: every one is refused with one line naming file and line.

Each case starts from a small valid scene that uses every reader (geometry, sensors, optical
tables, specularities, bands, lamp spectrum), breaks one thing, and runs
``lpy-light run SCENE --photons 1000 --out DIR``: exit status 2, exactly one line on stderr
``lpy-light: error: FILE:LINE: ...`` naming what was expected, and no results in DIR.
Most cases call :func:`lpy_light.cli.main` in-process; a few run the real command to show
that no traceback reaches stderr.  API cases (organ meshes, materials) raise our own
:class:`~lpy_light.errors.InputError`, never a bare ValueError, IndexError or KeyError.
"""
from __future__ import annotations

import io
import subprocess
import sys
import zipfile

import numpy as np
import pytest

from lpy_light import cli
from lpy_light.errors import InputError, LpyLightError
from scenes import box, lamp_rectangle, sensors_csv

# ------------------------------------------------------------------------------------------
# the valid base scene
RAD = ("void plastic wall\n0\n0\n5 0.5 0.5 0.5 0 0\n\nvoid light lamp\n0\n0\n3 10 10 10\n\n"
       + box("wall", (0, 0, 0), (1000, 1000, 1100)) + lamp_rectangle("lamp", (500, 500), 100, 1000))
N_RAD = RAD.count("\n")          # a primitive appended to RAD starts on line N_RAD + 1
SENSORS = sensors_csv([(300, 300, 400, 60, 0, 0, 1), (700, 650, 200, 60, 0, 0, -1)])
TOML = ('geometry = "scene.rad"\n'            # 1
        'sensors = "sensors.csv"\n'           # 2
        'unit = "mm"\n'                       # 3
        'optical = "optical"\n'               # 4
        'specularities = "spec.csv"\n'        # 5
        'bands = [[655, 665]]\n'              # 6
        'spectrum = "spectrum.txt"\n')        # 7
TABLE_PATH = "optical/Env/ReflectancesMean/wall.csv"


def table(rows=None, header='"lambda";"moy"') -> str:
    rows = rows if rows is not None else ["%d;0,%d" % (w, 40 + w % 7) for w in range(600, 701)]
    return (header + "\n" if header else "") + "\n".join(rows) + "\n"


BASE = {
    "scene.toml": TOML,
    "scene.rad": RAD,
    "sensors.csv": SENSORS,
    TABLE_PATH: table(),
    "spec.csv": "material,specularity\nwall,0.1\n",
    "spectrum.txt": "wavelength value\n" + "".join("%d %.3f\n" % (w, 0.5 + w / 1000) for w in range(600, 701, 2)),
}


def write(folder, changes=None):
    files = dict(BASE)
    files.update(changes or {})
    for name, content in files.items():
        if content is None:
            continue
        path = folder / name
        path.parent.mkdir(parents=True, exist_ok=True)
        if isinstance(content, bytes):
            path.write_bytes(content)
        else:
            path.write_text(content)
    return folder / "scene.toml"


def rad_plus(text):
    return {"scene.rad": RAD + text}


def toml_with(line, replace=None):
    """The base TOML with one line replaced (``replace``: its key) or one line appended."""
    if replace is None:
        return {"scene.toml": TOML + line + "\n"}
    lines = TOML.splitlines()
    lines = [line if ln.startswith(replace + " ") else ln for ln in lines]
    return {"scene.toml": "\n".join(lines) + "\n"}


def xlsx(sheet_xml, shared=None) -> bytes:
    ns = "http://schemas.openxmlformats.org/spreadsheetml/2006/main"
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        z.writestr("xl/workbook.xml", '<workbook xmlns="%s"><sheets><sheet name="Feuil1"/></sheets></workbook>' % ns)
        z.writestr("xl/worksheets/sheet1.xml", '<worksheet xmlns="%s"><sheetData>%s</sheetData></worksheet>'
                   % (ns, sheet_xml))
        if shared is not None:
            z.writestr("xl/sharedStrings.xml", '<sst xmlns="%s">%s</sst>' % (ns, "".join(
                "<si><t>%s</t></si>" % s for s in shared)))
    return buf.getvalue()


SPEC_XLSX = toml_with('specularities = "spec.xlsx"', replace="specularities")
POLY = "0 0 0 1 0 0 1 1 0"                  # a valid triangle's 9 reals
QUAD_HEADER = "x0,y0,z0,x1,y1,z1,x2,y2,z2,x3,y3,z3\n"
D = "X,Y,Z,rayon_capteur,Xnorm,Ynorm,Znorm\n"

# (id, changes, file named, line (None: the file as a whole), words expected in the message)
CASES = [
    # --- Radiance geometry ----------------------------------------------------------------
    ("rad-plastic-4-reals", rad_plus("void plastic p2\n0\n0\n4 0.5 0.5 0.5 0\n"), "scene.rad", N_RAD + 1,
     "plastic p2 needs 5 real arguments, got 4"),
    ("rad-polygon-8-reals", rad_plus("wall polygon bad\n0\n0\n8 0 0 0 1 0 0 1 1\n"), "scene.rad", N_RAD + 1,
     "needs 3·n reals"),
    ("rad-polygon-6-reals", rad_plus("wall polygon bad 0 0 6 0 0 0 1 0 0\n"), "scene.rad", N_RAD + 1,
     "n >= 3 vertices"),
    ("rad-real-not-a-number", rad_plus("wall polygon bad\n0\n0\n9 0 0 0\n1 zero 0\n1 1 0\n"), "scene.rad", N_RAD + 5,
     "expected a real number, got 'zero'"),
    ("rad-real-decimal-comma", rad_plus("wall polygon bad 0 0 9 0 0 0 1,5 0 0 1 1 0\n"), "scene.rad", N_RAD + 1,
     "expected a real number, got '1,5'"),
    ("rad-int-count-not-integer", rad_plus("void plastic p2\n0\nx\n5 .5 .5 .5 0 0\n"), "scene.rad", N_RAD + 3,
     "number of integer arguments"),
    ("rad-negative-count", rad_plus("void plastic p2\n-1\n0\n5 .5 .5 .5 0 0\n"), "scene.rad", N_RAD + 2,
     "number of string arguments (a non-negative integer)"),
    ("rad-count-unicode-digit", rad_plus("void plastic p2 ² 0 5 .5 .5 .5 0 0\n"), "scene.rad", N_RAD + 1,
     "number of string arguments"),
    ("rad-int-arg-not-integer", rad_plus("void plastic p2 0 1 1.5 5 .5 .5 .5 0 0\n"), "scene.rad", N_RAD + 1,
     "expected an integer argument, got '1.5'"),
    ("rad-surface-type-typo", rad_plus("wall polgon bad 0 0 9 %s\n" % POLY), "scene.rad", N_RAD + 1,
     "unknown primitive type 'polgon'"),
    ("rad-unsupported-type", rad_plus("void glass g 0 0 3 1 1 1\n"), "scene.rad", N_RAD + 1,
     "'glass' is not supported"),
    ("rad-undefined-modifier", rad_plus("nowhere polygon bad 0 0 9 %s\n" % POLY), "scene.rad", N_RAD + 1,
     "undefined modifier 'nowhere'"),
    ("rad-skipped-modifier", rad_plus("void x odd 0 0 0\nodd polygon bad 0 0 9 %s\n" % POLY), "scene.rad",
     N_RAD + 2, "which was skipped"),
    ("rad-nan-coordinate", rad_plus("wall polygon bad 0 0 9 0 0 NaN 1 0 0 1 1 0\n"), "scene.rad", N_RAD + 1,
     "'NaN' is not finite"),
    ("rad-inf-coordinate", rad_plus("wall polygon bad 0 0 9 0 0 0 1e999 0 0 1 1 0\n"), "scene.rad", N_RAD + 1,
     "'1e999' is not finite"),
    ("rad-huge-coordinate", rad_plus("wall polygon bad 0 0 9 0 0 0 1e13 0 0 1 1 0\n"), "scene.rad", N_RAD + 1,
     "beyond"),
    ("rad-collinear-polygon", rad_plus("wall polygon bad 0 0 9 0 0 0 1 0 0 2 0 0\n"), "scene.rad", N_RAD + 1,
     "zero area"),
    ("rad-repeated-vertex-polygon", rad_plus("wall polygon bad 0 0 9 0 0 0 0 0 0 1 0 0\n"), "scene.rad", N_RAD + 1,
     "fewer than 3 distinct vertices"),
    ("rad-negative-sphere-radius", rad_plus("wall sphere ball 0 0 4 500 500 500 -5\n"), "scene.rad", N_RAD + 1,
     "radius > 0"),
    ("rad-zero-length-cylinder", rad_plus("wall cylinder pipe 0 0 7 1 1 1 1 1 1 5\n"), "scene.rad", N_RAD + 1,
     "two distinct end points"),
    ("rad-ring-inner-above-outer", rad_plus("wall ring r 0 0 8 5 5 5 0 0 1 10 2\n"), "scene.rad", N_RAD + 1,
     "inner radius < outer radius"),
    ("rad-truncated", rad_plus("wall polygon cut\n0\n0\n9 0 0 0\n1 0"), "scene.rad", N_RAD + 5,
     "unexpected end of file"),
    ("rad-count-too-small", rad_plus("void plastic p2 0 0 3 .5 .5 .5 0 0\n"), "scene.rad", N_RAD + 1,
     "expected a primitive type"),
    ("rad-binary-garbage", {"scene.rad": RAD.encode() + bytes(range(256)) * 4}, "scene.rad", N_RAD + 1,
     "NUL byte"),
    ("rad-not-utf8", {"scene.rad": RAD.encode() + b"void plastic mur\xe9 0 0 5 .5 .5 .5 0 0\n"}, "scene.rad",
     N_RAD + 1, "byte 0xe9 is not UTF-8"),
    ("rad-inline-command", rad_plus("!xform -t 1 0 0 other.rad\n"), "scene.rad", N_RAD + 1, "inline commands"),
    ("rad-material-not-void", rad_plus("wall plastic p2 0 0 5 .5 .5 .5 0 0\n"), "scene.rad", N_RAD + 1,
     "modifier 'wall' not supported"),
    ("rad-not-energy-conserving", rad_plus("void trans t2 0 0 7 .6 .6 .6 0 0 .6 0\n"), "scene.rad", N_RAD + 1,
     "not energy-conserving"),
    ("rad-negative-reflectance", rad_plus("void plastic p2 0 0 5 -.5 .5 .5 0 0\n"), "scene.rad", N_RAD + 1,
     "negative argument"),
    ("rad-specular-above-1", rad_plus("void metal m2 0 0 5 .5 .5 .5 1.5 0\n"), "scene.rad", N_RAD + 1,
     "specular fractions must be <= 1"),
    ("rad-lamp-power-overflow", rad_plus("void light hot 0 0 3 1e300 1e300 1e300\n"
                                         "hot polygon hp 0 0 9 0 0 0 1e11 0 0 1e11 1e11 0\n"), "scene.rad",
     N_RAD + 2, "not a finite positive number"),
    ("rad-no-light", {"scene.rad": RAD.replace("3 10 10 10", "3 0 0 0")}, "scene.rad", 6, "no light source"),
    ("rad-empty", {"scene.rad": "# nothing here\n"}, "scene.toml", 1, "no light source"),
    ("rad-alias", rad_plus("void alias wall2 wall\n"), "scene.rad", N_RAD + 1, "'alias'"),
    ("rad-material-with-strings", rad_plus("void plastic p2 1 foo 0 5 .5 .5 .5 0 0\n"), "scene.rad", N_RAD + 1,
     "takes no string arguments"),
    ("rad-polygon-with-ints", rad_plus("wall polygon bad 0 2 1 2 9 0 0 0 1 0 0 1 1 0\n"), "scene.rad", N_RAD + 1,
     "takes no integer arguments"),
    ("optical-band-partly-covered", {TABLE_PATH: table(["%d;0,5" % w for w in range(600, 660)])}, "wall.csv",
     None, "band 655-665 nm is not covered"),
    ("geometry-is-a-folder", {"scene.toml": TOML.replace('"scene.rad"', '"optical"')}, "scene.toml", 1,
     "geometry must be a regular file"),
    # --- optical tables -------------------------------------------------------------------
    ("optical-comma-separator", {TABLE_PATH: table(["600,0,5"] + ["%d;0,5" % w for w in range(601, 701)])},
     "wall.csv", 2, "2 fields separated by ';'"),
    ("optical-three-fields", {TABLE_PATH: table(["600;0,5;0,4"])}, "wall.csv", 2, "got 3 field(s)"),
    ("optical-two-decimal-commas", {TABLE_PATH: table(["600;0,5,1"])}, "wall.csv", 2, "expected numbers"),
    ("optical-not-monotone", {TABLE_PATH: table(["%d;0,5" % w for w in [600, 602, 601] + list(range(603, 700))])},
     "wall.csv", 4, "wavelengths must increase (601 after 602)"),
    ("optical-repeated-wavelength", {TABLE_PATH: table(["600;0,5", "600;0,5"])}, "wall.csv", 3,
     "wavelengths must increase"),
    ("optical-percent", {TABLE_PATH: table(["%d;45,3" % w for w in range(600, 701)])}, "wall.csv", 2,
     "not a fraction 0-1"),
    ("optical-value-above-1", {TABLE_PATH: table(["%d;1,3" % w for w in range(600, 701)])}, "wall.csv", 2,
     "not a fraction 0-1"),
    ("optical-nan", {TABLE_PATH: table(["600;nan"])}, "wall.csv", 2, "expected numbers"),
    ("optical-header-only", {TABLE_PATH: table([])}, "wall.csv", None, "no data rows"),
    ("optical-empty-file", {TABLE_PATH: ""}, "wall.csv", None, "no data rows"),
    ("optical-negative-wavelength", {TABLE_PATH: table(["-600;0,5"])}, "wall.csv", 2, "not a wavelength"),
    ("optical-band-not-covered", {TABLE_PATH: table(["%d;0,5" % w for w in range(400, 500)])}, "wall.csv",
     None, "band 655-665 nm is not covered"),
    ("optical-binary", {TABLE_PATH: b"\x89PNG\r\n\x1a\n\x00\x00"}, "wall.csv", 3, "NUL byte"),
    ("optical-not-utf8", {TABLE_PATH: b'"lambda";"moy"\n600;0,5\xff\n'}, "wall.csv", 2, "byte 0xff is not UTF-8"),
    ("optical-folder-is-a-file", toml_with('optical = "spec.csv"', replace="optical"), "spec.csv", None,
     "expected a folder"),
    ("optical-without-bands", {"scene.toml": TOML.replace("bands = [[655, 665]]\n", "")}, "scene.toml", 4,
     "need 'bands'"),
    # --- specularities --------------------------------------------------------------------
    ("spec-above-1", {"spec.csv": "material,specularity\nwall,1.5\n"}, "spec.csv", 2, "not in [0, 1]"),
    ("spec-not-a-number", {"spec.csv": "material,specularity\nwall,shiny\n"}, "spec.csv", 2,
     "expected a specular fraction for 'wall'"),
    ("spec-nan", {"spec.csv": "material,specularity\nwall,nan\n"}, "spec.csv", 2, "not in [0, 1]"),
    ("spec-duplicate", {"spec.csv": "material,specularity\nwall,0.1\nwall,0.2\n"}, "spec.csv", 3,
     "appears twice (also line 2)"),
    ("spec-empty", {"spec.csv": ""}, "spec.csv", None, "no 'material, specular fraction' rows"),
    ("spec-huge-field", {"spec.csv": "material,specularity\nwall," + "9" * 200_000 + "\n"}, "spec.csv", 2,
     "not a readable csv"),
    ("spec-xlsx-not-a-zip", dict(SPEC_XLSX, **{"spec.xlsx": b"PK\x03\x04 not really a zip"}), "spec.xlsx", None,
     "not a readable .xlsx"),
    ("spec-xlsx-bad-shared-string", dict(SPEC_XLSX, **{"spec.xlsx": xlsx('<row r="1"><c r="A1" t="s"><v>7</v></c>'
                                                                       '</row>', shared=["wall"])}),
     "spec.xlsx", 1, "shared string"),
    ("spec-xlsx-bad-row-number", dict(SPEC_XLSX, **{"spec.xlsx": xlsx('<row r="x"><c r="A1"><v>1</v></c></row>')}),
     "spec.xlsx", None, "row number"),
    ("spec-xlsx-value-above-1", dict(SPEC_XLSX, **{"spec.xlsx": xlsx(
        '<row r="1"><c r="A1" t="s"><v>0</v></c><c r="B1"><v>3</v></c></row>', shared=["wall"])}),
     "spec.xlsx", 1, "not in [0, 1]"),
    # --- sensors --------------------------------------------------------------------------
    ("sensors-missing-column", {"sensors.csv": "X,Y,Z,rayon_capteur,Xnorm,Ynorm\n1,2,3,4,0,0\n"}, "sensors.csv", 1,
     "unknown sensor header"),
    ("sensors-mixed-separators", {"sensors.csv": D.replace(",", ";") + "1,2;3;4;0;0;1\n"}, "sensors.csv", 2,
     "expected 7 values"),
    ("sensors-zero-normal", {"sensors.csv": D + "300,300,400,60,0,0,1\n300,300,400,60,0,0,0\n"}, "sensors.csv", 3,
     "sensor normal is zero"),
    ("sensors-negative-radius", {"sensors.csv": D + "300,300,400,-6,0,0,1\n"}, "sensors.csv", 2,
     "radius must be > 0, got -6"),
    ("sensors-zero-radius", {"sensors.csv": D + "300,300,400,0,0,0,1\n"}, "sensors.csv", 2, "radius must be > 0"),
    ("sensors-nan", {"sensors.csv": D + "300,nan,400,6,0,0,1\n"}, "sensors.csv", 2, "non-finite"),
    ("sensors-short-line", {"sensors.csv": D + "300,300,400,6,0,0,1\n300,300,400,6,0,0\n"}, "sensors.csv", 3,
     "expected 7 values"),
    ("sensors-long-line", {"sensors.csv": D + "300,300,400,6,0,0,1,5\n"}, "sensors.csv", 2,
     "expected 7 values (X,Y,Z,rayon_capteur,Xnorm,Ynorm,Znorm), got 8"),
    ("sensors-not-a-number", {"sensors.csv": D + "300,300,400,six,0,0,1\n"}, "sensors.csv", 2, "expected numbers"),
    ("sensors-empty", {"sensors.csv": ""}, "sensors.csv", 1, "sensor file is empty"),
    ("sensors-header-only", {"sensors.csv": D}, "sensors.csv", 1, "no sensors"),
    ("sensors-quad-not-planar", {"sensors.csv": QUAD_HEADER + "0,0,0,1,0,0,1,1,0.5,0,1,0\n"}, "sensors.csv", 2,
     "not planar"),
    ("sensors-quad-out-of-order", {"sensors.csv": QUAD_HEADER + "0,0,0,1,1,0,1,0,0,0,1,0\n"}, "sensors.csv", 2,
     "not convex"),
    ("sensors-not-utf8", {"sensors.csv": D.encode() + b"300,300,400,6\xb0,0,0,1\n"}, "sensors.csv", 2,
     "byte 0xb0 is not UTF-8"),
    ("spec-not-utf8", {"spec.csv": b"material,specularity\nwall,0\xb71\n"}, "spec.csv", 2,
     "byte 0xb7 is not UTF-8"),
    ("sensors-binary", {"sensors.csv": D.encode() + b"\x00\x01\x02"}, "sensors.csv", 2, "NUL byte"),
    ("sensors-huge-field", {"sensors.csv": D + "1" * 200_000 + ",2,3,4,0,0,1\n"}, "sensors.csv", 2,
     "not a readable csv"),
    # --- scene TOML -----------------------------------------------------------------------
    ("toml-syntax", {"scene.toml": TOML + "bands = [[655, 665]\n"}, "scene.toml", 8, "not valid TOML"),
    ("toml-unknown-key", toml_with('geometri = "scene.rad"'), "scene.toml", 8, "unknown key 'geometri'"),
    ("toml-missing-geometry", {"scene.toml": TOML.replace('geometry = "scene.rad"\n', "")}, "scene.toml", None,
     "missing 'geometry'"),
    ("toml-geometry-number", toml_with("geometry = 5", replace="geometry"), "scene.toml", 1,
     "'geometry' must be a path"),
    ("toml-geometry-empty-list", toml_with("geometry = []", replace="geometry"), "scene.toml", 1,
     "'geometry' is empty"),
    ("toml-geometry-not-found", toml_with('geometry = "nowhere.rad"', replace="geometry"), "scene.toml", 1,
     "geometry file not found"),
    ("toml-sensors-not-found", toml_with('sensors = "nowhere.csv"', replace="sensors"), "scene.toml", 2,
     "sensors file not found"),
    ("toml-spectrum-not-found", toml_with('spectrum = "nowhere.txt"', replace="spectrum"), "scene.toml", 7,
     "spectrum file not found"),
    ("toml-unit-number", toml_with("unit = 5", replace="unit"), "scene.toml", 3, "unknown unit 5"),
    ("toml-unit-list", toml_with('unit = ["mm"]', replace="unit"), "scene.toml", 3, "unknown unit"),
    ("toml-unit-inch", toml_with('unit = "inch"', replace="unit"), "scene.toml", 3, "unknown unit 'inch'"),
    ("toml-bands-reversed", toml_with("bands = [[700, 600]]", replace="bands"), "scene.toml", 6,
     "0 < start < end"),
    ("toml-bands-twice", toml_with("bands = [[655, 665], [600, 680], [655, 665]]", replace="bands"), "scene.toml", 6,
     "given twice"),
    ("toml-bands-text", toml_with('bands = [["red", 665]]', replace="bands"), "scene.toml", 6,
     "two finite numbers"),
    ("toml-bands-flat", toml_with("bands = [655, 665]", replace="bands"), "scene.toml", 6, "[start, end]"),
    ("toml-bands-inf", toml_with("bands = [[655, inf]]", replace="bands"), "scene.toml", 6, "two finite numbers"),
    ("toml-bands-bool", toml_with("bands = [[true, 665]]", replace="bands"), "scene.toml", 6,
     "two finite numbers"),
    ("toml-bands-empty", toml_with("bands = []", replace="bands"), "scene.toml", 6, "must be a list"),
    ("toml-physics-unknown", toml_with("[physics]\nbounces = 3"), "scene.toml", 9,
     "unknown physics option 'bounces'"),
    ("toml-physics-type", toml_with('[physics]\nmax_depth = "many"'), "scene.toml", 9, "must be a int"),
    ("toml-physics-bool-depth", toml_with("[physics]\nmax_depth = true"), "scene.toml", 9, "must be a int"),
    ("toml-physics-lamps", toml_with('[physics]\nlamps = "laser"'), "scene.toml", 9, "'line' or 'lambertian'"),
    ("toml-physics-offset-nan", toml_with("[physics]\noffset = nan"), "scene.toml", 9, "offset must be in"),
    ("toml-physics-repeated-names", toml_with('[physics]\nrepeated_names = "first"'), "scene.toml", 9,
     "'all' or 'last'"),
    ("toml-physics-not-a-table", toml_with("physics = 5"), "scene.toml", 8, "'physics' must be a table"),
    ("toml-plant-position", toml_with("plant_position = [1, 2]"), "scene.toml", 8, "[x, y, z]"),
    ("toml-remove-missing", toml_with('remove = ["nothing"]'), "scene.toml", 8, "not in the geometry: nothing"),
    ("toml-not-utf8", {"scene.toml": TOML.encode() + b"# caf\xe9\n"}, "scene.toml", 8, "not UTF-8 text (byte 0xe9)"),
    # --- lamp spectrum --------------------------------------------------------------------
    ("spectrum-three-columns", {"spectrum.txt": "wavelength value\n600 1 2\n"}, "spectrum.txt", 2,
     "2 numbers"),
    ("spectrum-decreasing", {"spectrum.txt": "wavelength value\n600 1\n599 1\n"}, "spectrum.txt", 3,
     "wavelengths must increase"),
    # --- eighth session: a second round of unseen inputs ---------------------------------------
    ("toml-physics-dotted-key", toml_with('physics.lamps = "laser"'), "scene.toml", 8, "'line' or 'lambertian'"),
    ("toml-physics-inline-table", toml_with('physics = {lamps = "laser"}'), "scene.toml", 8,
     "'line' or 'lambertian'"),
    ("toml-physics-key-shadows-top-level", toml_with('[physics]\nunit = "m"'), "scene.toml", 9,
     "unknown physics option 'unit'"),
    ("toml-geometry-subtable", toml_with('geometry.file = "scene.rad"', replace="geometry"), "scene.toml", 1,
     "'geometry' must be a path"),
    ("toml-quoted-unknown-key", toml_with('"g\\u00e9ometry" = "scene.rad"'), "scene.toml", 8,
     "unknown key 'g\u00e9ometry'"),
    ("toml-optical-list", toml_with('optical = ["optical", "optical"]', replace="optical"), "scene.toml", 4,
     "'optical' must be a path"),
    ("toml-spectrum-list", toml_with('spectrum = ["spectrum.txt", "spectrum.txt"]', replace="spectrum"),
     "scene.toml", 7, "'spectrum' must be a path"),
    ("toml-bands-same-label", toml_with("bands = [[655, 665], [655.0000001, 665]]", replace="bands"), "scene.toml",
     6, "would both be named 655-665"),
    ("spectrum-not-covering-band", {"spectrum.txt": "wavelength value\n400 1\n402 1\n404 1\n"}, "scene.toml", 7,
     "band 655-665 nm is not covered"),
    ("spectrum-form-feed-in-a-line", {"spectrum.txt": "wavelength value\n600 1\x0c\n602 1\n604 x\n"},
     "spectrum.txt", 4, "got '604 x'"),
    ("rad-light-negative", rad_plus("void light neg 0 0 3 -10 -10 -10\n"), "scene.rad", N_RAD + 1,
     "cannot emit negative light"),
    ("rad-light-mixed-signs", rad_plus("void light neg 0 0 3 30 -10 10\n"), "scene.rad", N_RAD + 1,
     "cannot emit negative light"),
    ("sensors-column-twice", {"sensors.csv": "X,Y,Z,rayon_capteur,Xnorm,Ynorm,Znorm,X\n1,2,3,4,0,0,1,5\n"},
     "sensors.csv", 1, "column X appears 2 times"),
    ("rad-material-named-void", rad_plus("void plastic void 0 0 5 .5 .5 .5 0 0\n"), "scene.rad", N_RAD + 1,
     "'void' is Radiance's name for no modifier"),
    ("rad-inward-lambertian-lamp", {"scene.rad": RAD + "lamp tube t 0 0 7 100 100 500 100 900 500 5\n",
                                    "scene.toml": TOML + '[physics]\nlamps = "lambertian"\n'}, "scene.rad", N_RAD + 1,
     "a tube faces inward"),
    ("sensors-radius-underflows", {"sensors.csv": D + "300,300,400,1e-300,0,0,1\n"}, "sensors.csv", 2,
     "its area is 0"),
]


@pytest.mark.filterwarnings("error")       # a numpy warning would be a second line on stderr
@pytest.mark.parametrize("changes, name, line, words", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_corpus_case(tmp_path, capsys, changes, name, line, words):
    scene = write(tmp_path / "s", changes)
    out = tmp_path / "out"
    code = cli.main(["run", str(scene), "--photons", "1000", "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    lines = err.splitlines()
    assert code == 2, err
    assert len(lines) == 1, err
    msg = lines[0]
    assert msg.startswith("lpy-light: error: "), msg
    where = "%s:%d: " % (name, line) if line else "%s: " % name
    assert where in msg, msg
    assert words in msg, msg
    assert not out.exists(), "no results for bad input"


def test_corpus_is_large_and_base_is_valid(tmp_path, capsys):
    assert len(CASES) >= 30 and len({c[0] for c in CASES}) == len(CASES)
    scene = write(tmp_path / "s")
    assert cli.main(["run", str(scene), "--photons", "1000", "--out", str(tmp_path / "out"), "--quiet"]) == 0
    assert capsys.readouterr().err == ""
    assert (tmp_path / "out" / "sensors.csv").exists()


@pytest.mark.parametrize("changes", [
    {TABLE_PATH: table(header=None)},                                   # no header line
    {TABLE_PATH: "\ufeff" + table().replace("\n", "\r\n")},             # byte-order mark, CRLF
    {"sensors.csv": "\ufeff" + SENSORS.replace("\n", ",\n")},           # BOM, trailing separators
    {"sensors.csv": SENSORS.replace("\n", "\r\n") + "\n\n"},             # CRLF, blank lines
    {"sensors.csv": SENSORS.replace(",", ";").replace(".", ",")},          # spreadsheet export: ; and decimal comma
    {"scene.rad": RAD + "# un mur \xe9 commentaire\n"},                  # non-ASCII in a comment (UTF-8)
    {"scene.rad": RAD.encode() + b"# latin-1 comment: caf\xe9\n"},      # and non-UTF-8 in a comment
    {"scene.rad": RAD.replace("\n", "\r\n")},
    {"spec.csv": "material;specularity\nwall;0,1\n"},                   # French csv
    {"sensors.csv": 'X, "Y", Z, rayon_capteur, Xnorm, Ynorm, Znorm\n300, 300, 400, 60, 0, 0, 1\n'},   # spaces, quotes
    {"scene.toml": TOML.replace("bands = [[655, 665]]", "bands = [[600, 700], [655, 665]]")},   # overlapping bands
    {"spectrum.txt": "wavelength;value\n" + "".join("%d;0,5\n" % w for w in range(600, 701, 2))},
    {"scene.rad": "\ufeff" + RAD, "scene.toml": "\ufeff" + TOML},      # byte-order marks (Windows editors)
    {"scene.rad": "\ufeff# a comment first\n" + RAD},
    {"sensors.csv": "label," + SENSORS.replace("\n", "\nx,").rstrip("x,")},        # an extra column first
    {"sensors.csv": "Y,X,Z,rayon_capteur,Xnorm,Ynorm,Znorm\n300,300,400,60,0,0,1\n"},   # columns by name
    {TABLE_PATH: None, TABLE_PATH.replace(".csv", ".CSV"): table()},    # upper-case extension
])
def test_variants_that_are_fine(tmp_path, capsys, changes):
    scene = write(tmp_path / "s", changes)
    code = cli.main(["run", str(scene), "--photons", "1000", "--out", str(tmp_path / "out"), "--quiet"])
    assert code == 0, capsys.readouterr().err


def test_decimal_comma_spectrum_is_read_as_such(tmp_path):
    from lpy_light.chamber.units import read_lamp_spectrum
    path = tmp_path / "s.txt"
    path.write_text("wl value\n401,5 0,25\n403,5 0,5\n")
    s = read_lamp_spectrum(path)
    np.testing.assert_array_equal(s.wavelength, [401.5, 403.5])
    np.testing.assert_array_equal(s.value, [0.25, 0.5])


@pytest.mark.parametrize("args, words", [
    (["--seed", "-1"], "--seed must be a whole number"),
    (["--seed", str(2 ** 64)], "--seed must be a whole number"),
    (["--threads", "0"], "--threads must be in 1..1024"),
    (["--threads", "100000"], "--threads must be in 1..1024"),
    (["--precision", "2"], "--precision must be"),
    (["--nee-picks", "-1"], "--nee-picks must be a whole number in 0..4096"),
    (["--nee-picks", str(2 ** 31 + 5), "--estimator", "nee"], "--nee-picks must be a whole number in 0..4096"),
    (["--reference-band", "700-800"], "--reference-band needs --reference"),
])
def test_bad_options(tmp_path, capsys, args, words):
    scene = write(tmp_path / "s")
    out = tmp_path / "out"
    code = cli.main(["run", str(scene), "--photons", "1000", "--out", str(out), "--quiet"] + args)
    lines = capsys.readouterr().err.splitlines()
    assert code == 2 and len(lines) == 1 and words in lines[0], lines
    assert not out.exists()


def test_unknown_scene_name(tmp_path, capsys):
    assert cli.main(["run", "no-such-scene", "--out", str(tmp_path / "o"), "--quiet"]) == 2
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and "no-such-scene: scene file not found (built-in scenes: angers" in lines[0]


# --- the real command: no traceback reaches the user ------------------------------------------
SUBPROCESS = ["rad-binary-garbage", "rad-lamp-power-overflow", "optical-not-monotone", "toml-syntax",
              "spec-xlsx-bad-shared-string"]


@pytest.mark.parametrize("case", SUBPROCESS)
def test_command_line_prints_one_line(tmp_path, case):
    _, changes, name, line, words = next(c for c in CASES if c[0] == case)
    scene = write(tmp_path / "s", changes)
    out = tmp_path / "out"
    p = subprocess.run([sys.executable, "-m", "lpy_light", "run", str(scene), "--photons", "1000", "--out", str(out)],
                       capture_output=True, text=True)
    assert p.returncode == 2 and p.stdout == ""
    assert "Traceback" not in p.stderr
    lines = p.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("lpy-light: error: ") and words in lines[0], p.stderr
    assert not out.exists()


# --- organs and materials through the API ----------------------------------------------------
TRI_V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
TRI_F = np.array([[0, 1, 2]])


class _NoTables:
    bands, n_bands, optical, band_labels = None, 1, None, ["rad"]


ORGAN_CASES = [
    ("nan-vertices", lambda o: o.organ_from_mesh(1, (np.full((3, 3), np.nan), TRI_F), "Leaf"), "degenerate"),
    ("inf-vertices", lambda o: o.organ_from_mesh(1, (np.full((3, 3), np.inf), TRI_F), "Leaf"), "degenerate"),
    ("face-out-of-range", lambda o: o.organ_from_mesh(2, (TRI_V, [[0, 1, 3]]), "Leaf"), "face index 3 outside"),
    ("face-negative", lambda o: o.organ_from_mesh(2, (TRI_V, [[0, -1, 2]]), "Leaf"), "face index -1 outside"),
    ("empty-mesh", lambda o: o.organ_from_mesh(3, (np.zeros((0, 3)), np.zeros((0, 3), int)), "Leaf"),
     "no triangles"),
    ("vertices-2d", lambda o: o.organ_from_mesh(4, (TRI_V[:, :2], TRI_F), "Leaf"), "expected vertices (v, 3)"),
    ("faces-4-columns", lambda o: o.organ_from_mesh(4, (TRI_V, [[0, 1, 2, 0]]), "Leaf"), "faces (f, 3)"),
    ("faces-float", lambda o: o.organ_from_mesh(5, (TRI_V, TRI_F.astype(float)), "Leaf"), "must be integers"),
    ("faces-ragged", lambda o: o.organ_from_mesh(5, (TRI_V, [[0, 1, 2], [0, 1]]), "Leaf"), "expected a mesh"),
    ("not-a-mesh", lambda o: o.organ_from_mesh(6, 42, "Leaf"), "expected a mesh"),
    ("text-vertices", lambda o: o.organ_from_mesh(6, ([["a", "b", "c"]] * 3, TRI_F), "Leaf"), "expected a mesh"),
    ("collinear", lambda o: o.organ_from_mesh(7, ([[0, 0, 0], [1, 0, 0], [2, 0, 0]], TRI_F), "Leaf"), "degenerate"),
    ("material-not-a-name", lambda o: o.organ_from_mesh(8, (TRI_V, TRI_F), 42), "material must be a name"),
    ("offset-2d", lambda o: o.organ_from_mesh(9, (TRI_V, TRI_F), "Leaf", offset=(1, 2)), "offset (x, y, z)"),
    ("scale-nan", lambda o: o.organ_from_mesh(9, (TRI_V, TRI_F), "Leaf", scale=float("nan")), "scale > 0"),
    ("unknown-material", lambda o: o.plant_material("Feuille", "Feuille", _NoTables()), "no optical table"),
    ("material-reflectance-2", lambda o: o.plant_material({"reflectance": 2}, "m", _NoTables()),
     "in [0, 1]"),
    ("material-nan", lambda o: o.plant_material({"reflectance": float("nan")}, "m", _NoTables()), "in [0, 1]"),
    ("material-r-plus-t", lambda o: o.plant_material({"reflectance": .6, "transmittance": .6}, "m", _NoTables()),
     "R + T <= 1"),
    ("material-typo", lambda o: o.plant_material({"reflectanse": .5}, "m", _NoTables()), "unknown key"),
    ("material-text", lambda o: o.plant_material({"reflectance": "half"}, "m", _NoTables()),
     "no reflectance table 'half'"),
    ("material-number", lambda o: o.plant_material(5, "m", _NoTables()), "expected a table name"),
]


@pytest.mark.parametrize("make, words", [c[1:] for c in ORGAN_CASES], ids=[c[0] for c in ORGAN_CASES])
@pytest.mark.filterwarnings("error")
def test_organ_api_case(make, words):
    from lpy_light.plant import organs
    with pytest.raises(LpyLightError) as info:
        make(organs)
    assert isinstance(info.value, InputError) and words in str(info.value), str(info.value)


def test_some_nan_triangles_are_dropped_with_a_warning(caplog):
    from lpy_light.plant.organs import organ_from_mesh
    v = np.vstack([TRI_V, [[np.nan, 0, 0]]])
    organ = organ_from_mesh(1, (v, [[0, 1, 2], [0, 1, 3]]), "Leaf", module="Leaf")
    assert len(organ.triangles) == 1 and organ.dropped == 1
    assert "dropped 1 degenerate triangle" in caplog.text


@pytest.fixture(scope="module")
def light_chamber(tmp_path_factory):
    from lpy_light.chamber.scene import load_scene
    return load_scene(write(tmp_path_factory.mktemp("lm")))


@pytest.mark.parametrize("organs_spec, words", [
    ({"Leaf": 5}, "expected a table name"),
    ({"Leaf": {"reflectance": "x"}}, "no reflectance table 'x'"),
    ({"Leaf": ("wall",)}, "(front, back) pair"),
    ({"Leaf": "Feuille"}, "no optical table"),
])
def test_light_model_materials(light_chamber, organs_spec, words):
    from lpy_light import LightModel
    with pytest.raises(InputError, match=None) as info:
        LightModel(light_chamber, organs=organs_spec, lamp_flux=[1.0], threads=1)
    assert words in str(info.value)


def test_light_model_meshes(light_chamber):
    from lpy_light import LightModel
    model = LightModel(light_chamber, organs={"Leaf": {"reflectance": 0.4, "transmittance": 0.4}}, lamp_flux=[1.0],
                       threads=1, photons=2000, plant_unit="mm", position=[500, 500, 100])
    for bad, words in [({1: (TRI_V, [[0, 1, 9]])}, "outside"), ({1: "mesh"}, "expected a mesh"),
                       ({1: ((TRI_V, TRI_F), "NoSuchTable")}, "no optical table")]:
        with pytest.raises(InputError) as info:
            model.intercept(bad)
        assert words in str(info.value)
    lights = model.intercept({1: (TRI_V * 100, TRI_F)})     # and a good one still works after the errors
    assert set(lights) == {1}


def test_out_is_a_file(tmp_path, capsys):
    scene = write(tmp_path / "s")
    (tmp_path / "out").write_text("x")
    assert cli.main(["run", str(scene), "--photons", "1000", "--out", str(tmp_path / "out"), "--quiet"]) == 2
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and "out: --out must be a folder" in lines[0]


def test_results_that_cannot_be_written_give_one_line(tmp_path, capsys, monkeypatch):
    from lpy_light.run import results
    scene = write(tmp_path / "s")

    def full(path, text):
        raise OSError(28, "No space left on device", str(path))

    monkeypatch.setattr(results, "atomic_write", full)
    assert cli.main(["run", str(scene), "--photons", "1000", "--out", str(tmp_path / "out"), "--quiet"]) == 1
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 1 and lines[0].endswith("sensors.csv: No space left on device")


def test_latin1_text_columns_are_fine(tmp_path, capsys):
    """Only where a number is expected does a byte that is not UTF-8 matter."""
    scene = write(tmp_path / "s", {
        "sensors.csv": (D.rstrip("\n") + ",Orientation\n300,300,400,60,0,0,1,Vers le haut \xe9\n").encode("latin-1"),
        TABLE_PATH: table(header='"longueur";"r\xe9flectance"').encode("latin-1")})
    assert cli.main(["run", str(scene), "--photons", "1000", "--out", str(tmp_path / "out"), "--quiet"]) == 0


def test_bad_input_leaves_no_earlier_results(tmp_path, capsys):
    """A run refused on bad input into a folder holding an earlier run's results removes them: they would
    pass for this run's."""
    out = tmp_path / "out"
    scene = write(tmp_path / "s")
    assert cli.main(["run", str(scene), "--photons", "1000", "--out", str(out), "--quiet"]) == 0
    assert (out / "sensors.csv").exists() and (out / "summary.json").exists()
    bad = write(tmp_path / "b", {"sensors.csv": "X,Y,Z\n"})
    assert cli.main(["run", str(bad), "--photons", "1000", "--out", str(out), "--quiet"]) == 2
    assert len(capsys.readouterr().err.splitlines()) == 1
    assert not (out / "sensors.csv").exists() and not (out / "summary.json").exists()


@pytest.mark.parametrize("argv", [["run"], ["run", "x.toml"], ["run", "angers", "--out", "o", "--photons", "0"],
                                  ["run", "angers", "--out", "o", "--photons", "abc"], ["bogus"]])
def test_command_line_errors_are_one_line(capsys, argv):
    with pytest.raises(SystemExit) as exc:
        cli.main(argv)
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "error: " in err, err


def test_a_scene_without_sensors_writes_the_header(tmp_path, capsys):
    scene = write(tmp_path / "s", {"scene.toml": TOML.replace('sensors = "sensors.csv"\n', "")})
    assert cli.main(["run", str(scene), "--photons", "1000", "--out", str(tmp_path / "out"), "--quiet"]) == 0
    assert (tmp_path / "out" / "sensors.csv").read_text().startswith("sensor,band,photons,photons_std")


def test_special_files_are_refused_not_read(tmp_path, capsys):
    """A named pipe (or a device) given as an input file would hang the run or read forever: refused at once,
    on the scene file's line."""
    import os
    scene = write(tmp_path / "s", toml_with('geometry = "pipe.rad"', replace="geometry"))
    os.mkfifo(tmp_path / "s" / "pipe.rad")
    code = cli.main(["run", str(scene), "--photons", "1000", "--out", str(tmp_path / "out"), "--quiet"])
    lines = capsys.readouterr().err.splitlines()
    assert code == 2 and len(lines) == 1 and "scene.toml:1: geometry must be a regular file" in lines[0], lines


@pytest.mark.parametrize("argv", [["--photons", "0"], ["--estimator", "mc"], ["--photons", "abc"]])
def test_refused_options_leave_no_earlier_results(tmp_path, capsys, argv):
    """argparse refuses the command line before any scene is read: an earlier run's results in --out go too."""
    scene = write(tmp_path / "s")
    out = tmp_path / "out"
    assert cli.main(["run", str(scene), "--photons", "1000", "--out", str(out), "--quiet"]) == 0
    assert (out / "summary.json").exists()
    with pytest.raises(SystemExit) as exc:
        cli.main(["run", str(scene), "--out=%s" % out, "--quiet"] + argv)
    assert exc.value.code == 2
    assert not (out / "summary.json").exists() and not (out / "sensors.csv").exists()


def test_results_never_overwrite_or_remove_an_input(tmp_path, capsys):
    """--out in the scene's own folder, whose sensor list is called sensors.csv: the run is refused (it would
    overwrite its input), and a refused run there removes no input named like a result."""
    folder = tmp_path / "s"
    scene = write(folder)
    before = (folder / "sensors.csv").read_text()
    for out in (str(folder), ""):
        code = cli.main(["run", str(scene), "--photons", "1000", "--out", out, "--quiet"])
        lines = capsys.readouterr().err.splitlines()
        assert code == 2 and len(lines) == 1, lines
    assert "would overwrite the input file" in cli_message(tmp_path, scene, str(folder), capsys)
    bad = write(tmp_path / "bad", rad_plus("wall polygon bad 0 0 6 0 0 0 1 0 0\n"))
    code = cli.main(["run", str(bad), "--photons", "1000", "--out", str(tmp_path / "bad"), "--quiet"])
    assert code == 2
    assert (folder / "sensors.csv").read_text() == before
    assert (tmp_path / "bad" / "sensors.csv").read_text() == before     # an input, not an earlier result


def cli_message(tmp_path, scene, out, capsys):
    cli.main(["run", str(scene), "--photons", "1000", "--out", out, "--quiet"])
    return capsys.readouterr().err


def test_undefined_numbers_are_written_as_null_and_empty_cells(tmp_path, caplog):
    """A scene whose lamp lights no sensor (all below the floor, facing down): the lamp spectrum cannot scale
    the bands, so ppfd is undefined: empty cells in sensors.csv, null in summary.json (strict JSON), a warning."""
    import csv
    import json
    scene = write(tmp_path / "s", {"sensors.csv": D + "300,300,-400,60,0,0,-1\n"})
    out = tmp_path / "out"
    assert cli.main(["run", str(scene), "--photons", "2000", "--out", str(out), "--quiet"]) == 0
    assert "ppfd is left empty" in caplog.text
    summary = json.loads((out / "summary.json").read_text(), parse_constant=lambda c: pytest.fail(c))
    assert summary["normalisation"]["scale"] == [None]
    rows = list(csv.DictReader(open(out / "sensors.csv")))
    assert rows[0]["photons"] == "0.0" and rows[0]["ppfd"] == "" and rows[0]["ppfd_std"] == ""


@pytest.mark.parametrize("name, text, line, words", [
    ("mesures.txt", "# actualNbPhotons many\nnb particules = 5\n", 1, "'# actualNbPhotons N'"),
    ("mesures.txt", "nb particules = 5\nnb particules = -5\n", 2, "N >= 0"),
    ("mesures.txt", "nb particules = nan\n", 1, "'nb particules = N' (a finite number)"),
    ("sensors.csv", "sensor,photons,photons_std\n0,1,1\n", 1, "column band"),
    ("sensors.csv", "sensor,band,photons,photons_std\n0,655-665,many,1\n", 2, "photons (a finite number)"),
])
def test_bad_reference_files(tmp_path, capsys, name, text, line, words):
    """--reference files are input too: refused with their file and line, never a traceback."""
    scene = write(tmp_path / "s")
    ref = tmp_path / "ref" / name
    ref.parent.mkdir()
    ref.write_text(text)
    (ref.parent / "summary.json").write_text('{"photons": 1000}')
    code = cli.main(["run", str(scene), "--photons", "1000", "--out", str(tmp_path / "out"), "--quiet",
                     "--reference", str(ref)])
    lines = capsys.readouterr().err.splitlines()
    assert code == 2 and len(lines) == 1, lines
    assert "%s:%d: " % (name, line) in lines[0] and words in lines[0], lines


def test_tables_no_material_uses_are_warned_about(tmp_path, caplog):
    """A table or a specular fraction whose name differs from a material's only in case is not used (the
    material keeps its .rad values): warned about, naming the file and the material meant."""
    scene = write(tmp_path / "s", {TABLE_PATH: None, TABLE_PATH.replace("wall", "Wall"): table(),
                                   "spec.csv": "material,specularity\nWall,0.1\n",
                                   "optical/Env/ReflectancesMean/notes.txt": "a note\n"})
    assert cli.main(["run", str(scene), "--photons", "1000", "--out", str(tmp_path / "out"), "--quiet"]) == 0
    assert "Wall.csv: no material 'Wall' in the scene uses this reflectance table; the scene has 'wall'" in caplog.text
    assert "spec.csv: no material 'Wall' in the scene uses its specular fraction" in caplog.text
    assert "notes.txt: not read (optical tables are .csv files)" in caplog.text
