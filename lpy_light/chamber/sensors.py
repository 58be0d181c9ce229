"""Transparent sensors: discs (SEC2's csv) and planar quads.

A transparent sensor counts the photons that cross it from its front side (the
side its normal points to) and leaves them unchanged: it blocks nothing.  The
kernel tests a crossing *exactly* (|p − c| ≤ r for a disc, inside all four edges
for a quad), so no tessellation biases the count; Embree only sees a slightly
larger bounding quad that proposes candidates.

File formats
------------
SEC2 discs: header ``X,Y,Z,rayon_capteur,Xnorm,Ynorm,Znorm`` (extra columns such
as ``Orientation`` are ignored); the normal need not be unit.
Quads: header ``x0,y0,z0,x1,y1,z1,x2,y2,z2,x3,y3,z3``, corners counter-clockwise
seen from the front, planar and convex.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..kernel.records import SENSOR_DISC as DISC, SENSOR_QUAD as QUAD  # the kinds, once
from ..kernel.vectors import norm as vnorm

_DISC_COLUMNS = ["X", "Y", "Z", "rayon_capteur", "Xnorm", "Ynorm", "Znorm"]
_QUAD_COLUMNS = ["%s%d" % (a, i) for i in range(4) for a in "xyz"]
BOUND_MARGIN = 1.02   # bounding quads are 2 % larger than the sensor they stand for


@dataclass
class Sensors:
    """S transparent sensors.  Arrays: ``kind`` (S,) int32, ``center`` (S, 3), unit ``normal`` (S, 3),
    ``radius`` (S,) (discs; 0 for quads), ``corners`` (S, 4, 3) (quads; zeros for discs), in scene units."""

    kind: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    center: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    normal: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    radius: np.ndarray = field(default_factory=lambda: np.zeros(0))
    corners: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 3)))
    source: list = field(default_factory=list)   # (file, row) of each sensor

    def __len__(self):
        return len(self.kind)

    @property
    def area(self) -> np.ndarray:
        """Exact area of each sensor, (S,), in scene units²."""
        a = np.pi * self.radius ** 2
        q = self.kind == QUAD
        if q.any():
            c = self.corners[q]
            a[q] = 0.5 * np.linalg.norm(np.cross(c[:, 2] - c[:, 0], c[:, 3] - c[:, 1]), axis=1)
        return a

    @staticmethod
    def concat(parts):
        parts = list(parts)
        if not parts:
            return Sensors()
        return Sensors(np.concatenate([p.kind for p in parts]), np.concatenate([p.center for p in parts]),
                       np.concatenate([p.normal for p in parts]), np.concatenate([p.radius for p in parts]),
                       np.concatenate([p.corners for p in parts]), sum((p.source for p in parts), []))

    def flush_with(self, tri_verts, tri_normal, rel: float = 2.0 ** -16):
        """Sensors lying in the plane of a triangle, within float32's reach: per triangle, those whose centre is
        within ``rel`` · (largest coordinate) of its plane and whose bounding box meets the triangle's.

        A sensor resting on a table is crossed at the same distance as the table is hit; Embree, in
        float32, then reports the sensor as a candidate or not as its rounding falls.  The kernel tests the
        sensors listed for the triangle it hit as if Embree had reported them, in float64 against the
        triangle's own plane, so that such a sensor counts what lands on the table under it.
        ``tri_verts`` (T, 3, 3), unit ``tri_normal`` (T, 3).  Returns ``start`` (T + 1,) int64 and ``sensor``
        int64: triangle j's sensors are ``sensor[start[j]:start[j + 1]]``."""
        T = len(tri_verts)
        pairs_tri, pairs_s = [], []
        if len(self) and T:
            lo, hi = tri_verts.min(axis=1), tri_verts.max(axis=1)
            for s in range(len(self)):
                c = self.center[s]
                reach = self.radius[s] if self.kind[s] == DISC else \
                    float(np.linalg.norm(self.corners[s] - c, axis=1).max())
                tol = rel * max(float(np.abs(c).max()), float(np.abs(tri_verts).max()), 1e-30)
                height = np.abs(np.einsum("ij,ij->i", c - tri_verts[:, 0], tri_normal))
                near = (height <= tol) & np.all(lo <= c + reach + tol, axis=1) & np.all(hi >= c - reach - tol, axis=1)
                j = np.flatnonzero(near)
                pairs_tri.append(j)
                pairs_s.append(np.full(len(j), s))
        tris = np.concatenate(pairs_tri) if pairs_tri else np.zeros(0, np.int64)
        sens = np.concatenate(pairs_s) if pairs_s else np.zeros(0, np.int64)
        order = np.argsort(tris, kind="stable")
        start = np.zeros(T + 1, np.int64)
        np.cumsum(np.bincount(tris, minlength=T), out=start[1:])
        return start, np.ascontiguousarray(sens[order], dtype=np.int64)

    def bounding_triangles(self) -> np.ndarray:
        """Two triangles per sensor (sensor s owns rows 2s and 2s+1), (2S, 3, 3)."""
        S = len(self)
        quads = np.empty((S, 4, 3))
        for s in range(S):
            if self.kind[s] == DISC:
                n = self.normal[s]
                helper = np.array([1.0, 0, 0]) if abs(n[0]) < 0.9 else np.array([0, 1.0, 0])
                t = np.cross(n, helper)
                t /= vnorm(t)
                b = np.cross(n, t)
                h = self.radius[s] * BOUND_MARGIN
                quads[s] = self.center[s] + h * np.array([-t - b, t - b, t + b, -t + b])
            else:
                c = self.corners[s]
                quads[s] = c.mean(0) + BOUND_MARGIN * (c - c.mean(0))
        tris = np.empty((2 * S, 3, 3))
        tris[0::2] = quads[:, [0, 1, 2]]
        tris[1::2] = quads[:, [0, 2, 3]]
        return tris


def _error(msg, path, line=None):
    from ..errors import InputError
    return InputError(msg, path, line)


def read_sensors(path) -> Sensors:
    """Read a sensor csv (disc or quad format, told apart by its header; separated by commas, or by
    semicolons or tabs with decimal commas allowed)."""
    from .optical import _text_lines, not_utf8

    path = Path(path)
    lines = _text_lines(path, "sensor file")
    # the separator is told by the header: commas (SEC2), or semicolons / tabs (spreadsheet exports,
    # where a decimal comma is then allowed)
    head = next((ln for ln in lines if ln.strip()), "")
    delimiter = ";" if ";" in head and "," not in head else "\t" if "\t" in head and "," not in head else ","
    reader = csv.reader(lines, delimiter=delimiter, skipinitialspace=True)     # `X, "Y", Z` as `X,Y,Z`
    try:
        numbered = [(reader.line_num, row) for row in reader]
    except csv.Error as exc:
        raise _error("not a readable csv file (%s)" % exc, path, reader.line_num) from None
    numbered = [(n, row) for n, row in numbered if row and any(c.strip() for c in row)]
    if not numbered:
        raise _error("sensor file is empty: expected a header %s (discs) or %s (quads), then one sensor a line"
                     % (",".join(_DISC_COLUMNS), ",".join(_QUAD_COLUMNS)), path, 1)
    header_line, first = numbered[0]
    header = [h.strip() for h in first]
    while header and not header[-1]:
        header.pop()
    # columns are found by name, in any order, other columns ignored (a label, a height...)
    if all(c in header for c in _DISC_COLUMNS):
        columns, kind = _DISC_COLUMNS, DISC
    elif all(c in header for c in _QUAD_COLUMNS):
        columns, kind = _QUAD_COLUMNS, QUAD
    else:
        raise _error("unknown sensor header %r: expected %s (discs) or %s (quads), comma-separated%s"
                     % (",".join(header), ",".join(_DISC_COLUMNS), ",".join(_QUAD_COLUMNS), not_utf8(",".join(header))),
                     path, header_line)
    twice = sorted(c for c in columns if header.count(c) > 1)
    if twice:
        raise _error("column %s appears %d times in the header: which one is meant?"
                     % (twice[0], header.count(twice[0])), path, header_line)
    index = [header.index(c) for c in columns]
    needed = max(index) + 1          # cells a row must have: up to the last column we read
    values, source = [], []
    for number, row in numbered[1:]:
        cells = list(row)
        while len(cells) > len(header) and not cells[-1].strip():
            cells.pop()     # trailing separators
        if not needed <= len(cells) <= len(header):
            raise _error("expected %d values (%s), got %d" % (len(header), ",".join(header), len(cells)),
                         path, number)
        try:
            v = [float(cells[i].replace(",", ".") if delimiter != "," else cells[i]) for i in index]
        except ValueError:
            raise _error("expected numbers in columns %s, got %r%s" % (",".join(columns), ",".join(row),
                                                                       not_utf8(",".join(row))), path, number) from None
        if not np.all(np.isfinite(v)):
            raise _error("non-finite sensor value in %r" % ",".join(row), path, number)
        if np.abs(v).max() > 1e12:
            raise _error("sensor value beyond ±1e12 scene units in %r" % ",".join(row), path, number)
        values.append(v)
        source.append((str(path), number))
    if not values:
        raise _error("sensor file has no sensors (a header and no rows)", path, 1)
    v = np.asarray(values)
    S = len(v)
    if kind == DISC:
        center, radius, normal = v[:, 0:3], v[:, 3], v[:, 4:7]
        corners = np.zeros((S, 4, 3))
        for s in range(S):
            if not radius[s] > 0:
                raise _error("sensor radius must be > 0, got %g" % radius[s], path, source[s][1])
            if not np.pi * radius[s] ** 2 > 0:
                raise _error("sensor radius %g is too small: its area is 0 in double precision" % radius[s],
                             path, source[s][1])
    else:
        corners = v.reshape(S, 4, 3)
        center = corners.mean(1)
        normal = np.cross(corners[:, 2] - corners[:, 0], corners[:, 3] - corners[:, 1])
        radius = np.zeros(S)
        for s in range(S):
            c = corners[s]
            nrm = normal[s] / (vnorm(normal[s]) or 1)
            if np.abs((c - center[s]) @ nrm).max() > 1e-6 * (np.ptp(c, 0).max() + np.abs(c).max()):
                raise _error("quad sensor is not planar", path, source[s][1])
            for i in range(4):
                e1, e2 = c[(i + 1) % 4] - c[i], c[(i + 2) % 4] - c[(i + 1) % 4]
                if np.cross(e1, e2) @ nrm <= 0:
                    raise _error("quad sensor is not convex or its corners are not in order", path, source[s][1])
    length = np.linalg.norm(normal, axis=1)
    for s in np.flatnonzero(~(length > 0)):
        raise _error("sensor normal is zero", path, source[s][1])
    return Sensors(np.full(S, kind, np.int32), center, normal / length[:, None], radius, corners, source)
