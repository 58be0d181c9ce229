"""Wavefront OBJ chambers: faces as Radiance polygons whose modifier is their ``usemtl`` name.

CAD tools (and SEC2's successor, which wrote ``testChamber.obj`` from the Angers ``.rad``)
export chambers as OBJ.  A face ``f 1 2 3 4`` after ``usemtl MurBlanc`` and ``o paroiy0``
becomes the Radiance primitive ``MurBlanc polygon paroiy0`` with the face's vertices, in
their order (so its front is the side they wind counter-clockwise around, as in Radiance and
in the OBJ convention), exactly as Radiance's ``obj2rad`` converts a face.  What a material
name means is decided by the scene (:mod:`lpy_light.chamber.scene`): a material of that name defined
in a ``.rad`` listed before the OBJ, else the scene's measured optical tables of that name.
The ``.mtl`` file is not read: its colours are a viewer's (the Angers ``.mtl`` gives every
wall ``Kd 1.0``), not measured reflectances.

Faces of zero area (the Angers OBJ's lamps, written as flat strips of width 0) are left out
with a warning: an OBJ cannot carry a line lamp; the lamps come from a ``.rad`` file.

Read: ``v`` (a fourth weight is ignored), ``f`` (``i``, ``i/t``, ``i//n``, ``i/t/n``; negative
indices count back from the latest vertex), ``usemtl``, ``o``, ``g``; ignored: ``vn``, ``vt``,
``vp``, ``s``, ``mtllib``, ``l``, ``p`` and display attributes.  Free-form geometry (``curv``,
``surf``, ...) is refused, as is anything else, with the file and line.
"""
from __future__ import annotations

import logging
import math
from pathlib import Path

from ..errors import InputError
from .geometry import MAX_COORDINATE, triangulate_polygon
from .radiance import Primitive, RadFile

log = logging.getLogger("lpy_light")

#: statements that carry nothing lpy-light uses (normals, texture, smoothing, display attributes)
_IGNORED = {"vn", "vt", "vp", "s", "mtllib", "l", "p", "bevel", "c_interp", "d_interp", "lod", "maplib",
            "usemap", "shadow_obj", "trace_obj", "ctech", "stech", "mg"}
#: free-form geometry: surfaces lpy-light cannot triangulate, refused rather than left out
_FREEFORM = {"cstype", "deg", "bmat", "step", "curv", "curv2", "surf", "parm", "trim", "hole", "scrv", "sp",
             "end", "con"}


def read_obj(path) -> RadFile:
    """The faces of an OBJ file as ``polygon`` primitives (modifier: the face's ``usemtl`` name,
    identifier: its ``o``/``g`` name, line: the face's line), in file order."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError("cannot read OBJ file: %s" % exc.strerror, path) from None
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    return parse_obj(data.decode("utf-8", errors="surrogateescape"), str(path))


def _logical_lines(text: str):
    """(line number, statement) pairs: comments dropped, a trailing backslash joins the next line."""
    pending, first = "", 0
    for number, raw in enumerate(text.split("\n"), start=1):
        code = raw.split("#", 1)[0].rstrip("\r")
        if not pending:
            first = number
        if code.rstrip().endswith("\\"):
            pending += code.rstrip()[:-1] + " "
            continue
        yield first, pending + code
        pending = ""
    if pending:
        yield first, pending


def parse_obj(text: str, name: str = "<string>") -> RadFile:
    """Parse OBJ text (see :func:`read_obj`); ``name`` is used in error messages."""
    nul = text.find("\x00")
    if nul >= 0:
        raise InputError("NUL byte: this is not a text file (an OBJ file is plain text)", name,
                         text.count("\n", 0, nul) + 1)
    vertices = []
    material, obj_name = None, None
    faces = RadFile(path=name)
    flat = []
    for number, line in _logical_lines(text):
        if any("\udc80" <= ch <= "\udcff" for ch in line):
            raise InputError("bytes that are not UTF-8 text", name, number)
        words = line.split()
        if not words:
            continue
        key, args = words[0], words[1:]
        if key == "v":
            if len(args) not in (3, 4):
                raise InputError("a vertex needs x y z (and optionally a weight), got %d numbers" % len(args),
                                 name, number)
            try:
                xyz = [float(a) for a in args[:3]]
            except ValueError:
                raise InputError("vertex coordinates must be numbers, got %s" % " ".join(args[:3]),
                                 name, number) from None
            if not all(math.isfinite(c) for c in xyz):
                raise InputError("vertex coordinate is not finite: %s" % " ".join(args[:3]), name, number)
            if max(abs(c) for c in xyz) > MAX_COORDINATE:
                raise InputError("vertex coordinate %g is beyond ±%g scene units (the tracer works in single "
                                 "precision); is the unit right?" % (max(xyz, key=abs), MAX_COORDINATE), name, number)
            vertices.append(xyz)
        elif key == "f":
            if len(args) < 3:
                raise InputError("a face needs at least 3 vertices, got %d" % len(args), name, number)
            if material is None:
                raise InputError("face before any 'usemtl': every face needs a material name", name, number)
            points = []
            for ref in args:
                head = ref.split("/", 1)[0]
                try:
                    k = int(head)
                except ValueError:
                    raise InputError("face vertex %r is not a vertex index" % ref, name, number) from None
                index = k - 1 if k > 0 else len(vertices) + k
                if k == 0 or not 0 <= index < len(vertices):
                    raise InputError("face vertex %d does not exist (%d vertices so far)" % (k, len(vertices)),
                                     name, number)
                points.append(vertices[index])
            try:
                triangulate_polygon(points)
            except ValueError:
                flat.append(obj_name or "face at line %d" % number)
                continue
            reals = [c for p in points for c in p]
            faces.append(Primitive(material, "polygon", obj_name or "face", [], [], reals, name, number))
        elif key == "usemtl":
            if len(args) != 1:
                raise InputError("'usemtl' needs one material name (a single word, as Radiance names and the "
                                 "optical tables' file names are), got %d words" % len(args), name, number)
            material = args[0]
        elif key in ("o", "g"):
            obj_name = args[0] if args else None
        elif key in _FREEFORM:
            raise InputError("free-form geometry (%r) is not supported: export the chamber as polygons" % key,
                             name, number)
        elif key not in _IGNORED:
            raise InputError("unknown OBJ statement %r (expected v, f, usemtl, o, g, ...)" % key, name, number)
    if flat:
        names = sorted(set(flat))
        log.warning("%s: %d face(s) of zero area left out (%s%s): an OBJ cannot carry a line lamp; give lamps "
                    "in a .rad file listed in 'geometry'", name, len(flat), ", ".join(names[:6]),
                    ", ..." if len(names) > 6 else "")
    return faces
