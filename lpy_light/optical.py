"""Measured optical properties: reflectance and transmittance per wavelength, specular fractions.

Layout (SEC2's)::

    optical/<group>/ReflectancesMean/<material>.csv
    optical/<group>/TransmittancesMean/<material>.csv

Each table has a header line (``"lambda";"moy"``) then ``nm;value`` rows with a
decimal comma, every 1 nm.  Values are fractions 0-1; slightly negative values
are measurement noise and are clamped at 0.  A band's value is the mean of the
table's 1-nm samples λ with ``start <= λ < end``.

Specular fractions ``s`` (wavelength-independent) come from SEC2's
``Specularities.xlsx`` (sheet ``Feuil1``: material, value) or a csv
``material,specularity``.  SEC2 splits a reflectance R into diffuse R(1-s) and
specular R·s.
"""
from __future__ import annotations

import csv
import re
import zipfile
from dataclasses import dataclass
from pathlib import Path
from xml.etree import ElementTree

import numpy as np

from .errors import InputError


@dataclass
class Spectrum:
    """A tabulated spectral quantity: ``wavelength`` (nm) and ``value``, both (n,) float64."""

    wavelength: np.ndarray
    value: np.ndarray
    path: str = ""

    def band_mean(self, start: float, end: float) -> float:
        """Mean of the samples with ``start <= wavelength < end``."""
        sel = (self.wavelength >= start) & (self.wavelength < end)
        if not sel.any():
            raise InputError("no samples in band %g-%g nm (table covers %g-%g nm)"
                             % (start, end, self.wavelength.min(), self.wavelength.max()), self.path)
        return float(self.value[sel].mean())


def read_table(path, clamp: bool = True) -> Spectrum:
    """Read one SEC2 optical table (decimal comma, ``;`` separated, one header line)."""
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError as exc:
        raise InputError("cannot read optical table: %s" % exc.strerror, path) from None
    wl, val = [], []
    for number, line in enumerate(lines, start=1):
        text = line.strip()
        if not text:
            continue
        parts = [p.strip().strip('"') for p in text.split(";")]
        if number == 1 and not _is_number(parts[0]):
            continue  # header
        if len(parts) != 2:
            raise InputError("expected 'wavelength;value' (2 fields separated by ';'), got %d field(s)"
                             % len(parts), path, number)
        try:
            w, v = float(parts[0].replace(",", ".")), float(parts[1].replace(",", "."))
        except ValueError:
            raise InputError("expected numbers 'nm;value' (decimal comma), got %r" % text, path, number) from None
        if not (np.isfinite(w) and np.isfinite(v)):
            raise InputError("non-finite number in %r" % text, path, number)
        if v > 1.5 or v < -0.5:
            raise InputError("value %g is not a fraction 0-1" % v, path, number)
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
    return bool(re.fullmatch(r"[-+]?\d+([.,]\d*)?([eE][-+]?\d+)?", text))


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
        raise InputError("optical folder not found", folder)
    tables = {"ReflectancesMean": {}, "TransmittancesMean": {}}
    for kind, found in tables.items():
        for path in sorted(folder.glob("*/%s/*.csv" % kind)) + sorted(folder.glob("%s/*.csv" % kind)):
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
    out = {}
    for number, row in rows:
        if len(row) < 2 or row[0] in (None, ""):
            continue
        name, value = str(row[0]).strip(), row[1]
        try:
            s = float(str(value).replace(",", "."))
        except ValueError:
            if number == 1:
                continue   # header
            raise InputError("expected a specular fraction for %r, got %r" % (name, value), path, number) from None
        if not 0.0 <= s <= 1.0:
            raise InputError("specular fraction %g of %r is not in [0, 1]" % (s, name), path, number)
        out[name] = s
    return out


def _csv_rows(path):
    with open(path, newline="", encoding="utf-8", errors="replace") as fh:
        sample = fh.read(2048)
        fh.seek(0)
        delimiter = ";" if sample.count(";") > sample.count(",") else ","
        return [(i, row) for i, row in enumerate(csv.reader(fh, delimiter=delimiter), start=1)]


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
    except (zipfile.BadZipFile, KeyError, ElementTree.ParseError) as exc:
        raise InputError("not a readable .xlsx workbook (%s)" % exc, path) from None
    rows = []
    for row in data.iter("{%s}row" % _NS["m"]):
        number = int(row.get("r", len(rows) + 1))
        cells = {}
        for c in row.findall("m:c", _NS):
            col = re.match(r"[A-Z]+", c.get("r", "A")).group(0)
            v = c.find("m:v", _NS)
            text = v.text if v is not None else None
            if c.get("t") == "s" and text is not None:
                text = shared[int(text)]
            elif c.get("t") == "inlineStr":
                text = "".join(t.text or "" for t in c.iter("{%s}t" % _NS["m"]))
            cells[col] = text
        rows.append((number, [cells.get("A"), cells.get("B")]))
    return rows
