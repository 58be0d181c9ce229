"""Reading Radiance scene descriptions (``.rad``) as Radiance reads them.

A ``.rad`` file is a stream of whitespace-separated tokens; ``#`` starts a comment
that runs to the end of the line.  Each primitive is::

    modifier type identifier
    n_strings  s1 ... sn
    n_ints     i1 ... in
    n_reals    r1 ... rn

Items need not be one per line.  :func:`read_rad` returns every primitive in file
order (repeated identifiers are all kept) with the line where it starts; what a
type *means* is decided in :mod:`lpy_light.scene`.  Inline commands (``!cmd``)
are refused with an error naming the line.
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path

from .errors import InputError

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


def parse_rad(text: str, name: str = "<string>") -> list:
    """Parse Radiance text (see :func:`read_rad`); ``name`` is used in error messages."""
    _bad_byte(text, name)
    tokens = list(tokenize(text))
    prims = []
    i = 0
    n = len(tokens)

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
        strings = [take("a string argument", start)[0] for _ in range(count("string arguments", start))]
        ints = []
        for _ in range(count("integer arguments", start)):
            tok, line = take("an integer argument", start)
            if not _INT.fullmatch(tok):
                raise InputError("expected an integer argument, got %r" % tok, name, line)
            ints.append(int(tok))
        reals = []
        for _ in range(count("real arguments", start)):
            tok, line = take("a real argument", start)
            try:
                value = float(tok)
            except ValueError:
                value = None
            if value is not None and not math.isfinite(value):
                raise InputError("real argument %r is not finite (primitive %s %s)" % (tok, ptype, ident),
                                 name, line)
            if value is None or not _REAL.fullmatch(tok):
                raise InputError("expected a real number, got %r (primitive %s %s)" % (tok, ptype, ident),
                                 name, line)
            reals.append(value)
        prims.append(Primitive(modifier, ptype, ident, strings, ints, reals, name, start))
    return prims
