"""A survey of a chamber: measured µmol m⁻² s⁻¹ per band at sensor sites (``lpy-light calibrate``'s input).

A survey is a sensor file (:mod:`lpy_light.chamber.sensors`: ``X,Y,Z,rayon_capteur,Xnorm,Ynorm,Znorm`` for discs, or
a quad's corners) with one more column per band, named by the band as the scene names it (``655-665``) or
with a ``ppfd_`` prefix (``ppfd_655-665``)::

    X,Y,Z,rayon_capteur,Xnorm,Ynorm,Znorm,ppfd_400-445,...,ppfd_735-800
    110,930,1000,10.0,0,0,1,3.99082,...,7.31162

Optionally a ``row`` column groups the sites into the rows the cross-validation leaves out one at a time;
without it a row is the sites that share an x or a y coordinate, whichever makes more rows.

Bad input is refused with the file and line (:class:`~lpy_light.errors.InputError`): a band column the
scene lacks, a site outside the chamber, a missing, zero, negative or non-numeric reading.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..chamber.sensors import Sensors, read_sensors
from ..chamber.units import _band_of

PREFIX = "ppfd_"


@dataclass
class Survey:
    """S measured sites: ``sensors`` (their discs or quads), ``values`` (S, B) µmol m⁻² s⁻¹ (NaN in a band the
    survey has no column for), ``columns`` (B,) which bands it measured, ``line`` (S,) each site's line in
    the file, ``row`` (S,) int: the row (cross-validation fold) of each site."""

    path: str
    sensors: Sensors
    values: np.ndarray
    columns: np.ndarray
    line: np.ndarray
    row: np.ndarray
    row_source: str = ""

    def __len__(self):
        return len(self.line)


def _rows_of(center: np.ndarray) -> np.ndarray:
    """Rows of sites when the survey names none: the sites sharing an x or a y coordinate (to 1e-6 of the span),
    whichever makes more rows of at least two sites each on average (thinner folds: a left-out row then lies
    as close to the fitted ones as the survey's own spacing, as a plant between surveyed rows does), else five
    blocks in file order."""
    span = float(np.ptp(center, axis=0).max()) or 1.0
    best = None
    for axis in (1, 0):
        _, row = np.unique(np.round(center[:, axis] / (1e-6 * span)), return_inverse=True)
        if 3 <= row.max() + 1 <= len(center) // 2 and (best is None or row.max() > best[0].max()):
            best = row, "the sites sharing a %s coordinate" % "xy"[axis]
    if best is not None:
        return best
    return np.arange(len(center)) * 5 // max(len(center), 1), "five blocks of sites in file order"


def read_survey(path, chamber) -> Survey:
    """Read a survey csv for ``chamber`` (its bands, its extent); see the module docstring."""
    path = Path(path)
    sensors = read_sensors(path)          # positions, normals, radii: errors with their line
    lines = path.read_text(encoding="utf-8-sig", errors="replace").split("\n")
    lines = [ln[:-1] if ln.endswith("\r") else ln for ln in lines]
    numbered = [(n, ln) for n, ln in enumerate(lines, start=1) if ln.strip()]
    head_line, head = numbered[0]
    delimiter = ";" if ";" in head and "," not in head else "\t" if "\t" in head and "," not in head else ","
    header = [h.strip() for h in next(csv.reader([head], delimiter=delimiter))]
    labels, bands = chamber.band_labels, chamber.bands
    band_col = {}
    for c, h in enumerate(header):
        name = h[len(PREFIX):] if h.lower().startswith(PREFIX) else h
        b = _band_of(name, labels, bands)
        if b == -1 or (b is None and h.lower().startswith(PREFIX)):
            raise InputError("column %r is not a band of the scene %s (its bands: %s)"
                             % (h, chamber.source, ", ".join(labels)), path, head_line)
        if b is not None:
            if b in band_col.values():
                raise InputError("band %s has two columns" % labels[b], path, head_line)
            band_col[c] = b
    if not band_col:
        raise InputError("no measured band column (expected columns named %s, or with the prefix %s)"
                         % (", ".join(labels), PREFIX), path, head_line)
    row_col = header.index("row") if "row" in header else None
    B = len(labels)
    values = np.full((len(sensors), B), np.nan)
    line = np.array([n for _, n in sensors.source])
    text_of = dict(numbered)
    row_names = []
    lo, hi = chamber.triangles.reshape(-1, 3).min(axis=0), chamber.triangles.reshape(-1, 3).max(axis=0)
    for s, number in enumerate(line):
        cells = [c.strip() for c in next(csv.reader([text_of[number]], delimiter=delimiter))]
        for c, b in band_col.items():
            cell = cells[c].replace(",", ".") if c < len(cells) and delimiter != "," else \
                (cells[c] if c < len(cells) else "")
            if not cell:
                raise InputError("site %d has no reading for band %s (every site needs one in every band column)"
                                 % (s + 1, labels[b]), path, number)
            try:
                v = float(cell)
            except ValueError:
                raise InputError("expected a number for band %s, got %r" % (labels[b], cell), path, number) from None
            if not np.isfinite(v) or v < 0:
                raise InputError("expected a finite reading >= 0 µmol m-2 s-1 for band %s, got %r"
                                 % (labels[b], cell), path, number)
            if v == 0:
                raise InputError("a reading of 0 for band %s: the fit weighs relative residuals, so a site that "
                                 "read nothing cannot be fitted (leave it out)" % labels[b], path, number)
            values[s, b] = v
        c = sensors.center[s]
        if np.any(c < lo) or np.any(c > hi):
            raise InputError("site (%g, %g, %g) is outside the chamber %s (its surfaces span %s to %s, %s)"
                             % (*c, chamber.source, np.round(lo, 3).tolist(), np.round(hi, 3).tolist(), chamber.unit),
                             path, number)
        if row_col is not None:
            row_names.append(cells[row_col] if row_col < len(cells) else "")
    if row_col is not None:
        _, row = np.unique(np.array(row_names, dtype=object).astype(str), return_inverse=True)
        source = "the survey's 'row' column"
    else:
        row, source = _rows_of(sensors.center)
    if row.max() + 1 < 2:
        raise InputError("the survey's sites make one row: cross-validation needs at least two (add a 'row' "
                         "column)", path, head_line)
    columns = np.zeros(B, bool)
    columns[list(band_col.values())] = True
    return Survey(str(path), sensors, values, columns, line, np.asarray(row, int), source)

