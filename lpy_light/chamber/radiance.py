"""Reading Radiance scene descriptions (``.rad``) as Radiance reads them.

A ``.rad`` file is a stream of whitespace-separated tokens; ``#`` starts a comment
that runs to the end of the line.  Each primitive is::

    modifier type identifier
    n_strings  s1 ... sn
    n_ints     i1 ... in
    n_reals    r1 ... rn

Items need not be one per line.  :func:`read_rad` returns every primitive in file
order (repeated identifiers are all kept) with the line where it starts; what a
type *means* is decided in :mod:`lpy_light.chamber.scene`.  Inline commands (``!cmd``)
are refused with an error naming the line.

SEC2's dialect
--------------
SEC2, the engine before lpy-light, reads a variant of the format that its users' files
are written in (docs/physics.md, "SEC2's scene files", gives the evidence for each form):

* ``scale_factor N`` before the first primitive: the file's lengths are in units of
  1/N metre (``1000``: mm, ``100``: cm);
* ``MOD point NAME x y z [radius]`` (SEC2 takes the sphere as a point: the radius is
  ignored), ``MOD point_light NAME x y z`` and ``MOD spot_light NAME x y z angle dx dy dz``:
  light sources whose numbers follow the identifier without argument counts (the
  Radiance form ``0 0 N ...`` is read too) and end at the first token that is not a number;
* in a file that uses the two forms above, a count of real arguments smaller than the
  numbers on the line of its last real (``1`` then ``0.32 0.32 0.32``): the whole line is
  read, as SEC2-era readers read a line (with a warning).

A file with none of these forms is read exactly as Radiance reads it.
"""
from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import InputError

log = logging.getLogger("lpy_light")

#: Primitive types lpy-light understands, with the number of reals each takes
#: (``None``: a multiple of 3, at least 9, for polygons).
SURFACE_TYPES = {"polygon": None, "cylinder": 7, "tube": 7, "sphere": 4, "bubble": 4, "ring": 8}
MATERIAL_TYPES = {"plastic": 5, "metal": 5, "trans": 7, "light": 3, "glow": 4, "mirror": 3}
#: Radiance types we know but do not model: an error, not a silent skip.
UNSUPPORTED_TYPES = {"cone", "cup", "source", "instance", "mesh", "dielectric", "interface", "glass",
                     "plasfunc", "metfunc", "transfunc", "BRTDfunc", "plasdata", "metdata", "transdata",
                     "texfunc", "texdata", "patfunc", "brightfunc", "colorfunc", "brightdata", "colordata",
                     "colorpict", "mixfunc", "mixdata", "mixtext", "mixpict", "antimatter", "prism1",
                     "prism2", "spotlight", "illum", "mist", "BSDF", "aBSDF", "ashik2", "WGMDfunc",
                     "brighttext", "colortext", "alias", "trans2", "plastic2", "metal2"}

#: SEC2's light sources at a point (its dialect; no argument counts): how many numbers each takes.
SEC2_TYPES = {"point": (3, 4), "point_light": (3,), "spot_light": (7,)}
_SEC2_ARGUMENTS = {"point": "its centre x y z and optionally a radius (which SEC2 ignores)",
                   "point_light": "its centre x y z (SEC2's files keep a tube's length, diameter, angle and "
                                  "direction on commented-out lines: SEC2 does not read them)",
                   "spot_light": "its centre x y z, an angle (degrees) and a direction dx dy dz"}
_SEC2_LINE = re.compile(r"\s*(scale_factor\s+\S|\S+\s+(%s)(\s|$))" % "|".join(SEC2_TYPES), re.ASCII)

# Radiance splits on C isspace (space, \t, \n, \v, \f, \r): ASCII whitespace only.
_TOKEN = re.compile(r"\S+", re.ASCII)
_COUNT = re.compile(r"[0-9]+")
_INT = re.compile(r"[-+]?[0-9]+")
_REAL = re.compile(r"[-+]?([0-9]+\.?[0-9]*|\.[0-9]+)([eE][-+]?[0-9]+)?")


@dataclass
class Primitive:
    """One Radiance primitive: ``modifier type identifier`` and its arguments."""

    modifier: str
    type: str
    identifier: str
    strings: list = field(default_factory=list)
    ints: list = field(default_factory=list)
    reals: list = field(default_factory=list)
    path: str = ""
    line: int = 0

    @property
    def where(self) -> str:
        return "%s:%d" % (self.path, self.line)


class RadFile(list):
    """The primitives of one ``.rad`` file, in order (a list), and what SEC2's dialect adds to it:
    ``sec2`` (the file uses the dialect), ``scale_factor`` (file units per metre, or None) and the
    line that gives it, ``scale_line``."""

    def __init__(self, prims=(), path: str = "", sec2: bool = False, scale_factor=None, scale_line: int = 0):
        super().__init__(prims)
        self.path, self.sec2 = path, sec2
        self.scale_factor, self.scale_line = scale_factor, scale_line


def uses_sec2_dialect(text: str) -> bool:
    """Whether a line (comments aside) starts with ``scale_factor N`` or with ``MOD TYPE`` of SEC2's
    light types: the file is written in SEC2's dialect."""
    return any(_SEC2_LINE.match(raw.split("#", 1)[0]) for raw in text.split("\n"))


def _looks_numeric(tok: str) -> bool:
    """A token that is meant as a number (Radiance's form, or nan/inf spelled out)."""
    return bool(_REAL.fullmatch(tok)) or tok.lower().lstrip("+-") in ("nan", "inf", "infinity")


def tokenize(text: str):
    """Yield ``(token, line_number)`` pairs; ``#`` comments are dropped.

    Lines are counted on ``\n`` only (as an editor and Radiance count them), not on
    the other characters :meth:`str.splitlines` breaks at.
    """
    for number, raw in enumerate(text.split("\n"), start=1):
        line = raw.split("#", 1)[0]
        for match in _TOKEN.finditer(line):
            yield match.group(0), number


def _bad_byte(text: str, name: str):
    """Refuse what is not text: a NUL byte, or bytes that are not UTF-8 outside comments."""
    nul = text.find("\x00")
    if nul >= 0:
        raise InputError("NUL byte: this is not a text file (a Radiance scene is plain text)",
                         name, text.count("\n", 0, nul) + 1)
    for number, raw in enumerate(text.split("\n"), start=1):
        code = raw.split("#", 1)[0]
        for ch in code:
            if "\udc80" <= ch <= "\udcff":
                raise InputError("byte 0x%02x is not UTF-8 text (Radiance scenes are ASCII)"
                                 % (ord(ch) - 0xdc00), name, number)


def read_rad(path) -> list:
    """Parse a ``.rad`` file into a list of :class:`Primitive`.

    Raises :class:`InputError` naming file and line on any syntax problem: a
    truncated primitive, a count that is not a non-negative integer, a real that
    is not a finite number, an inline ``!command``, bytes that are not text.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise InputError("cannot read Radiance file: %s" % exc.strerror, path) from None
    if data.startswith(b"\xef\xbb\xbf"):      # a UTF-8 byte-order mark is not a token
        data = data[3:]
    return parse_rad(data.decode("utf-8", errors="surrogateescape"), str(path))


def parse_rad(text: str, name: str = "<string>") -> RadFile:
    """Parse Radiance text (see :func:`read_rad`); ``name`` is used in error messages."""
    _bad_byte(text, name)
    tokens = list(tokenize(text))
    sec2 = uses_sec2_dialect(text)
    prims = RadFile(path=name, sec2=sec2)
    i = 0
    n = len(tokens)

    def number(tok, line):
        """A real argument of the primitive being read, or an error naming its line."""
        try:
            value = float(tok)
        except ValueError:
            value = None
        if value is not None and not math.isfinite(value):
            raise InputError("real argument %r is not finite (primitive %s %s)" % (tok, ptype, ident), name, line)
        if value is None or not _REAL.fullmatch(tok):
            raise InputError("expected a real number, got %r (primitive %s %s)" % (tok, ptype, ident), name, line)
        return value

    def sec2_numbers(start_line):
        """The numbers after a SEC2 light's identifier, up to the first token that is not one."""
        nonlocal i
        found = []
        while i < n and _looks_numeric(tokens[i][0]):
            found.append((tokens[i][0], number(*tokens[i]), tokens[i][1]))
            i += 1
        arity = SEC2_TYPES[ptype]
        if (len(found) >= 3 and all(_COUNT.fullmatch(t) and int(t) == 0 for t, _, _ in found[:2])
                and _COUNT.fullmatch(found[2][0]) and int(found[2][0]) in arity
                and len(found) == 3 + int(found[2][0])):
            found = found[3:]           # written with Radiance's counts: 0 0 N then N reals
        if len(found) not in arity:
            where = found[max(arity)][2] if len(found) > max(arity) else start_line
            raise InputError("%s %s takes %s: %s numbers, got %d (%s)"
                             % (ptype, ident, _SEC2_ARGUMENTS[ptype], " or ".join(map(str, arity)), len(found),
                                " ".join(t for t, _, _ in found) or "none"), name, where)
        return [v for _, v, _ in found]

    def line_rest(last_line):
        """SEC2's dialect: the numbers left on ``last_line`` (the line of a primitive's last real) when
        the line ends with them; they are real arguments too."""
        nonlocal i
        j = i
        while j < n and tokens[j][1] == last_line and _REAL.fullmatch(tokens[j][0]):
            j += 1
        if j == i or (j < n and tokens[j][1] == last_line):
            return []
        extra = [number(*tokens[k]) for k in range(i, j)]
        i = j
        return extra

    def take(what, start_line):
        nonlocal i
        if i >= n:
            raise InputError("unexpected end of file: expected %s of the primitive that starts at line %d"
                             % (what, start_line), name, tokens[-1][1])
        tok, line = tokens[i]
        i += 1
        return tok, line

    def count(what, start_line):
        tok, line = take("the number of " + what, start_line)
        if not _COUNT.fullmatch(tok):
            raise InputError("expected the number of %s (a non-negative integer) of %s %s %s (line %d), got %r"
                             % (what, modifier, ptype, ident, start_line, tok), name, line)
        return int(tok)

    while i < n:
        tok, start = tokens[i]
        if tok.startswith("!"):
            raise InputError("inline commands (%r) are not supported; expand the scene first "
                             "(e.g. with Radiance's xform) and pass the result" % tok, name, start)
        if tok == "scale_factor" and i + 1 < n and _looks_numeric(tokens[i + 1][0]):     # SEC2's dialect
            value, line = tokens[i + 1]
            i += 2
            scale = float(value) if _REAL.fullmatch(value) else math.nan
            if not 1e-6 <= scale <= 1e9:      # NaN too
                raise InputError("scale_factor must be a positive number, 1e-6 to 1e9 (file units per metre: "
                                 "1000 for mm, 100 for cm), got %r" % value, name, line)
            if prims.scale_factor is not None:
                raise InputError("scale_factor given twice (first at line %d)" % prims.scale_line, name, line)
            if prims:
                raise InputError("scale_factor after the first primitive (line %d): SEC2's files give it once, "
                                 "before any primitive" % prims[0].line, name, line)
            prims.scale_factor, prims.scale_line = scale, line
            continue
        modifier, _ = take("a modifier", start)
        ptype, line = take("a primitive type", start)
        if _REAL.fullmatch(ptype) or ptype.lower() in ("nan", "inf", "infinity"):
            after = (" (does the count of real arguments of the primitive at line %d match its reals?)"
                     % prims[-1].line) if prims else ""
            raise InputError("expected a primitive type (polygon, plastic, ...), got the number %r%s"
                             % (ptype, after), name, line)
        ident, _ = take("an identifier", start)
        if ptype.startswith("!") or ident.startswith("!"):
            raise InputError("inline commands are not supported", name, line)
        if ptype == "alias":     # "mod alias new old": no argument counts; not read by lpy-light
            raise InputError("Radiance 'alias' (%s alias %s ...) is not supported: define the material again"
                             % (modifier, ident), name, line)
        if ptype in SEC2_TYPES:  # SEC2's point lights: their numbers, no counts
            prims.append(Primitive(modifier, ptype, ident, [], [], sec2_numbers(start), name, start))
            continue
        strings = [take("a string argument", start)[0] for _ in range(count("string arguments", start))]
        ints = []
        for _ in range(count("integer arguments", start)):
            tok, line = take("an integer argument", start)
            if not _INT.fullmatch(tok):
                raise InputError("expected an integer argument, got %r" % tok, name, line)
            ints.append(int(tok))
        reals = []
        n_reals = count("real arguments", start)
        last = tokens[i - 1][1]
        for _ in range(n_reals):
            tok, last = take("a real argument", start)
            reals.append(number(tok, last))
        if sec2:
            extra = line_rest(last)
            if extra:
                log.warning("%s:%d: %s %s: its count says %d real arguments, its line holds %d more; all %d are "
                            "read (SEC2's dialect, read line by line)", name, last, ptype, ident, n_reals,
                            len(extra), n_reals + len(extra))
                reals.extend(extra)
        prims.append(Primitive(modifier, ptype, ident, strings, ints, reals, name, start))
    return prims
