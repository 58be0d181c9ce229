"""Measured optical properties: reflectance and transmittance per wavelength, specular fractions.

Layout (SEC2's)::

    optical/<group>/ReflectancesMean/<material>.csv
    optical/<group>/TransmittancesMean/<material>.csv

Each table has a header line (``"lambda";"moy"``) then ``nm;value`` rows with a
decimal comma, every 1 nm.  Values are fractions 0-1; values slightly outside
(down to -0.2, up to 1.2) are measurement noise and are clamped to [0, 1];
anything further out (a table in percent, say) is an error.  A band's value is the mean of the
table's 1-nm samples λ with ``start <= λ < end``.

Specular fractions ``s`` (wavelength-independent) come from SEC2's
``Specularities.xlsx`` (sheet ``Feuil1``: material, value) or a csv
``material,specularity``.  SEC2 splits a reflectance R into diffuse R(1-s) and
specular R·s.
"""
from __future__ import annotations

import csv
import logging
import re
import zipfile
from dataclasses import dataclass
from pathlib import Path
from xml.etree import ElementTree

import numpy as np

from ..errors import InputError

log = logging.getLogger("lpy_light")


@dataclass
class Spectrum:
    """A tabulated spectral quantity: ``wavelength`` (nm) and ``value``, both (n,) float64."""

    wavelength: np.ndarray
    value: np.ndarray
    path: str = ""

    def band_mean(self, start: float, end: float) -> float:
        """Mean of the samples with ``start <= wavelength < end``; the table must cover the band, to one sample
        spacing at either end (a spectrum from 401 nm serves a band from 400 nm), else :class:`InputError` (key
        ``bands``): a mean over the part it covers would silently stand for the whole band."""
        wl = self.wavelength
        sel = (wl >= start) & (wl < end)
        step = float(np.median(np.diff(np.sort(wl)))) if len(wl) > 1 else 0.0
        if not sel.any() or wl.min() > start + step + 1e-9 or wl.max() < end - 2 * step - 1e-9:
            error = InputError("band %g-%g nm is not covered by this table (it covers %g-%g nm)"
                               % (start, end, wl.min(), wl.max()), self.path)
            error.key = "bands"
            raise error
        return float(self.value[sel].mean())


def read_table(path, clamp: bool = True) -> Spectrum:
    """Read one SEC2 optical table (decimal comma, ``;`` separated, one header line)."""
    path = Path(path)
    lines = _text_lines(path, "optical table")
    wl, val = [], []
    for number, line in enumerate(lines, start=1):
        text = line.strip()
        if not text:
            continue
        parts = [p.strip().strip('"') for p in text.split(";")]
        if number == 1 and not _is_number(parts[0]) and parts[0].lower() not in ("nan", "inf", "-inf"):
            continue  # header
        if len(parts) != 2:
            raise InputError("expected 'wavelength;value' (2 fields separated by ';'), got %d field(s) in %r%s"
                             % (len(parts), text, not_utf8(text)), path, number)
        if not (_is_number(parts[0]) and _is_number(parts[1])):
            raise InputError("expected numbers 'nm;value' (decimal comma or point), got %r%s"
                             % (text, not_utf8(text)), path, number)
        w, v = float(parts[0].replace(",", ".")), float(parts[1].replace(",", "."))
        if not (np.isfinite(w) and np.isfinite(v)):
            raise InputError("non-finite number in %r" % text, path, number)
        if not 0 < w < 1e5:
            raise InputError("wavelength %g nm is not a wavelength (expected nm, > 0)" % w, path, number)
        if v > 1.2 or v < -0.2:
            raise InputError("value %g is not a fraction 0-1 (a table in percent? divide by 100)" % v, path, number)
        if wl and w <= wl[-1]:
            raise InputError("wavelengths must increase (%g after %g)" % (w, wl[-1]), path, number)
        wl.append(w)
        val.append(v)
    if not wl:
        raise InputError("optical table has no data rows", path)
    value = np.asarray(val)
    if clamp:
        value = np.clip(value, 0.0, 1.0)
    return Spectrum(np.asarray(wl), value, str(path))


def _is_number(text: str) -> bool:
    return bool(re.fullmatch(r"[-+]?([0-9]+([.,][0-9]*)?|[.,][0-9]+)([eE][-+]?[0-9]+)?", text))


def _text_lines(path, what) -> list:
    """Lines of a text file (UTF-8, a byte-order mark allowed); a NUL byte (a binary file) is an error.

    Bytes that are not UTF-8 are kept as surrogates (a Latin-1 accent in a header or a text
    column does no harm); where a number was expected, :func:`not_utf8` says why it is not one.
    """
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise InputError("cannot read %s: %s" % (what, exc.strerror), path) from None
    if b"\x00" in data:
        raise InputError("NUL byte: this is not a text file", path, data.count(b"\n", 0, data.index(b"\x00")) + 1)
    if data.startswith(b"\xef\xbb\xbf"):
        data = data[3:]
    return data.decode("utf-8", errors="surrogateescape").split("\n")


def not_utf8(text: str) -> str:
    """`` (byte 0x.. is not UTF-8 text)`` when ``text`` holds an undecodable byte, else ``""``."""
    for ch in text:
        if "\udc80" <= ch <= "\udcff":
            return " (byte 0x%02x is not UTF-8 text)" % (ord(ch) - 0xdc00)
    return ""


@dataclass
class OpticalLibrary:
    """Per-material spectra found under an ``optical/`` folder."""

    reflectance: dict
    transmittance: dict

    def materials(self):
        return sorted(set(self.reflectance) | set(self.transmittance))


def read_optical_folder(folder) -> OpticalLibrary:
    """Collect ``*/ReflectancesMean/*.csv`` and ``*/TransmittancesMean/*.csv`` under ``folder``."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("optical: expected a folder (with */ReflectancesMean/*.csv tables), got %s"
                         % ("a file" if folder.exists() else "nothing: not found"), folder)
    tables = {"ReflectancesMean": {}, "TransmittancesMean": {}}
    for kind, found in tables.items():
        found_paths = sorted(folder.glob("*/%s/*" % kind)) + sorted(folder.glob("%s/*" % kind))
        for path in found_paths:
            if path.suffix.lower() != ".csv" or not path.is_file():       # .csv or .CSV tables only
                if not path.name.startswith("."):
                    log.warning("%s: not read (optical tables are .csv files)", path)
                continue
            name = path.stem
            if name in found:
                raise InputError("material %r has two %s tables (also %s)" % (name, kind, found[name].path), path)
            found[name] = read_table(path)
    if not tables["ReflectancesMean"] and not tables["TransmittancesMean"]:
        raise InputError("no ReflectancesMean/ or TransmittancesMean/ tables found", folder)
    return OpticalLibrary(tables["ReflectancesMean"], tables["TransmittancesMean"])


def read_specularities(path) -> dict:
    """Specular fraction per material from SEC2's ``.xlsx`` (sheet Feuil1) or a csv."""
    path = Path(path)
    if not path.exists():
        raise InputError("specularities file not found", path)
    rows = _xlsx_rows(path) if path.suffix.lower() == ".xlsx" else _csv_rows(path)
    out, where = {}, {}
    for number, row in rows:
        if len(row) < 2 or row[0] in (None, ""):
            continue
        name, value = str(row[0]).strip(), row[1]
        try:
            s = float(str(value).strip().replace(",", "."))
        except ValueError:
            if number == 1:
                continue   # header
            raise InputError("expected a specular fraction for %r, got %r%s" % (name, value, not_utf8(str(value))),
                             path, number) from None
        if not 0.0 <= s <= 1.0:
            raise InputError("specular fraction %g of %r is not in [0, 1]" % (s, name), path, number)
        if name in out:
            raise InputError("material %r appears twice (also line %d)" % (name, where[name]), path, number)
        out[name] = s
        where[name] = number
    if not out:
        raise InputError("no 'material, specular fraction' rows found", path)
    return out


def _csv_rows(path):
    lines = _text_lines(path, "specularities file")
    sample = "\n".join(lines)[:2048]
    delimiter = ";" if sample.count(";") > sample.count(",") else ","
    reader = csv.reader(lines, delimiter=delimiter)
    try:
        return [(reader.line_num, row) for row in reader]
    except csv.Error as exc:
        raise InputError("not a readable csv file (%s)" % exc, path, reader.line_num) from None


_NS = {"m": "http://schemas.openxmlformats.org/spreadsheetml/2006/main"}


def _xlsx_rows(path, sheet: str = "Feuil1"):
    """Rows of one sheet of an .xlsx file, read with the standard library only."""
    try:
        with zipfile.ZipFile(path) as z:
            shared = []
            if "xl/sharedStrings.xml" in z.namelist():
                root = ElementTree.fromstring(z.read("xl/sharedStrings.xml"))
                for si in root.findall("m:si", _NS):
                    shared.append("".join(t.text or "" for t in si.iter("{%s}t" % _NS["m"])))
            book = ElementTree.fromstring(z.read("xl/workbook.xml"))
            names = [s.get("name") for s in book.findall("m:sheets/m:sheet", _NS)]
            index = names.index(sheet) + 1 if sheet in names else 1
            data = ElementTree.fromstring(z.read("xl/worksheets/sheet%d.xml" % index))
    except (zipfile.BadZipFile, KeyError, ElementTree.ParseError, OSError, EOFError, RuntimeError,
            NotImplementedError, zipfile.LargeZipFile) as exc:
        raise InputError("not a readable .xlsx workbook (%s)" % exc, path) from None
    rows = []
    for row in data.iter("{%s}row" % _NS["m"]):
        r = row.get("r", str(len(rows) + 1))
        if not r.isascii() or not r.isdigit():
            raise InputError("not a readable .xlsx workbook (row number %r)" % r, path)
        number = int(r)
        cells = {}
        for c in row.findall("m:c", _NS):
            ref = re.match(r"[A-Z]+", c.get("r", "A"))
            if ref is None:
                raise InputError("not a readable .xlsx workbook (cell reference %r)" % c.get("r"), path, number)
            v = c.find("m:v", _NS)
            text = v.text if v is not None else None
            if c.get("t") == "s" and text is not None:
                if not (text.isascii() and text.isdigit() and int(text) < len(shared)):
                    raise InputError("not a readable .xlsx workbook (shared string %r of %d)" % (text, len(shared)),
                                     path, number)
                text = shared[int(text)]
            elif c.get("t") == "inlineStr":
                text = "".join(t.text or "" for t in c.iter("{%s}t" % _NS["m"]))
            cells[ref.group(0)] = text
        rows.append((number, [cells.get("A"), cells.get("B")]))
    return rows
