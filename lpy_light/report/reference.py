"""Reference results to compare a run with: SEC2's ``mesures*.txt``, the photon-mapping
engine's csv, or a previous run's ``sensors.csv``.

A reference gives, per sensor, a photon count for a known number of emitted
photons (Poisson noise: σ = √count) or an expected count with its own σ.  A run
is compared after scaling it to the reference's photon number:

    z_s = (ours_s · N_ref / N_ours − ref_s) / √(σ_ours,s² (N_ref/N_ours)² + σ_ref,s²)

and summarised by the share of sensors with |z| < 4, the mean relative bias
(with its σ) and the rms relative difference.

A per-sensor test cannot see a structure shared by whole rows of sensors (a 1 % tilt
hides under a 0.8 % noise per sensor); :func:`row_profiles` averages the ratio to the
reference (both normalised to mean 1) over each row of each sensor plane, with its σ,
and fits its least-squares change across the rows.  :func:`average` makes one
reference of several (e.g. SEC2 and the photon-mapping engine).
"""
from __future__ import annotations

import csv
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import InputError

#: SEC2's nominal photon count when a file does not state ``# actualNbPhotons``
SEC2_DEFAULT_PHOTONS = 999_999_936


@dataclass
class Reference:
    """Per-sensor reference counts ``photons`` (S,) and their σ (S,), for ``n_photons`` emitted."""

    photons: np.ndarray
    photons_std: np.ndarray
    n_photons: float
    source: str
    centers: np.ndarray | None = None     # (S, 3) when the file gives positions


@dataclass
class Comparison:
    """A run against a reference, both per sensor (S,) and summarised."""

    z: np.ndarray            # (S,) signed z-scores
    relative: np.ndarray     # (S,) ours/ref − 1
    within_4sigma: float     # share of sensors with |z| < 4
    bias: float              # mean of ``relative``
    bias_std: float          # its σ (from both σ's)
    rms: float               # rms of ``relative``
    rms_noise: float         # rms of ``relative`` that noise alone explains
    profiles: list = field(default_factory=list)   # :class:`Profile` per sensor plane (filled by the CLI)

    def line(self) -> str:
        return ("within 4σ %.1f%%, bias %+.2f%% ± %.2f%%, rms %.2f%% (noise alone %.2f%%), max |z| %.1f"
                % (100 * self.within_4sigma, 100 * self.bias, 100 * self.bias_std, 100 * self.rms,
                   100 * self.rms_noise, np.abs(self.z).max()))


_CENTER = re.compile(r"centre\s*\(([^)]*)\)")


def read_sec2(path) -> Reference:
    """SEC2's ``mesures.txt``: blocks ``disque de centre (x,y,z) ...`` then ``nb particules = N``."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise InputError("cannot read reference: %s" % exc.strerror, path) from None
    n_photons = SEC2_DEFAULT_PHOTONS
    counts, centers = [], []
    for number, line in enumerate(text.split("\n"), start=1):      # lines as an editor counts them
        if line.startswith("# actualNbPhotons"):
            n_photons = _positive(line.split()[-1] if len(line.split()) > 2 else "", "'# actualNbPhotons N'",
                                  path, number)
        elif "centre" in line:
            m = _CENTER.search(line)
            try:
                centers.append([float(v) for v in m.group(1).split(",")])
            except (AttributeError, ValueError):
                raise InputError("expected 'disque de centre (x,y,z)'", path, number) from None
        elif line.startswith("nb particules"):
            count = _number(line.split("=")[1] if "=" in line else "", "'nb particules = N'", path, number)
            if count < 0:
                raise InputError("expected 'nb particules = N' with N >= 0, got %g" % count, path, number)
            counts.append(count)
    if not counts:
        raise InputError("no 'nb particules = N' lines: not a SEC2 result file", path)
    counts = np.array(counts)
    return Reference(counts, np.sqrt(counts), n_photons, str(path),
                     np.array(centers) if len(centers) == len(counts) else None)


def _number(text, what, path, line=None) -> float:
    """A finite number, or an InputError naming ``what`` was expected."""
    try:
        value = float(str(text).strip())
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise InputError("expected %s (a finite number), got %r" % (what, str(text).strip()), path, line)
    return value


def _positive(text, what, path, line=None) -> float:
    value = _number(text, what, path, line)
    if not value > 0:
        raise InputError("expected %s with N > 0, got %g" % (what, value), path, line)
    return value


def read_photon_mapping(path, n_photons: float = 1e9) -> Reference:
    """The photon-mapping engine's ``captor_result-N-...csv`` (``id,n_photons,elevation``)."""
    path = Path(path)
    m = re.search(r"captor_result-(\d+)-", path.name)
    if m:
        n_photons = float(m.group(1))
    rows = _read_csv(path, ("n_photons",))
    counts = np.array([_number(r["n_photons"], "n_photons", path, i) for i, r in enumerate(rows, start=2)])
    if (counts < 0).any():
        raise InputError("expected n_photons >= 0", path, 2 + int(np.argmax(counts < 0)))
    return Reference(counts, np.sqrt(counts), n_photons, str(path))


def read_run(path, band: str | None = None) -> Reference:
    """A previous run's ``sensors.csv`` (one band: the first, or ``band``); ``summary.json`` beside it gives N."""
    import json

    path = Path(path)
    rows = [(i, r) for i, r in enumerate(_read_csv(path, ("band", "photons", "photons_std")), start=2)]
    if not rows:
        raise InputError("no sensor rows: not a run's sensors.csv", path)
    band = band or rows[0][1]["band"]
    rows = [(i, r) for i, r in rows if r["band"] == band]
    if not rows:
        raise InputError("no rows for band %r" % band, path)
    summary = path.with_name("summary.json")
    try:
        n_photons = json.loads(summary.read_text(encoding="utf-8"))["photons"]
    except (OSError, ValueError, KeyError, TypeError):
        raise InputError("a run's sensors.csv needs its summary.json beside it (for the photon count)", summary) from None
    n_photons = _positive(n_photons, "'photons': N", summary)
    counts = np.array([_number(r["photons"], "photons", path, i) for i, r in rows])
    std = np.array([_number(r["photons_std"], "photons_std", path, i) for i, r in rows])
    centers = (np.array([[_number(r[k], k, path, i) for k in "xyz"] for i, r in rows])
               if all(k in rows[0][1] for k in "xyz") else None)
    return Reference(counts, std, n_photons, str(path), centers)


def read(path) -> Reference:
    """Any reference: a SEC2 ``.txt``, a photon-mapping ``captor_result-*.csv`` or a run's ``sensors.csv``."""
    path = Path(path)
    if path.suffix == ".txt":
        return read_sec2(path)
    if path.name.startswith("captor_result"):
        return read_photon_mapping(path)
    return read_run(path)


def _read_csv(path: Path, columns=()) -> list:
    """Rows of a csv (dicts by header); the header must hold ``columns``."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh)
            missing = [c for c in columns if c not in (reader.fieldnames or [])]
            if missing:
                raise InputError("expected the column%s %s in the header" % ("s" * (len(missing) > 1),
                                                                               ",".join(missing)), path, 1)
            return list(reader)
    except OSError as exc:
        raise InputError("cannot read reference: %s" % exc.strerror, path) from None
    except UnicodeDecodeError as exc:
        raise InputError("not UTF-8 text (byte 0x%02x)" % exc.object[exc.start], path) from None
    except csv.Error as exc:
        raise InputError("not a readable csv file (%s)" % exc, path) from None


def average(refs) -> Reference:
    """One reference from several of the same S sensors: the mean of their counts per emitted photon
    (each scaled to the first one's photon number), σ from theirs (independent runs)."""
    refs = list(refs)
    if len(refs) == 1:
        return refs[0]
    first = refs[0]
    for r in refs[1:]:
        if r.photons.shape != first.photons.shape:
            raise InputError("references to average have %d and %d sensors" % (len(first.photons), len(r.photons)),
                             r.source)
    k = [first.n_photons / r.n_photons for r in refs]
    photons = sum(ki * r.photons for ki, r in zip(k, refs)) / len(refs)
    std = np.sqrt(sum((ki * r.photons_std) ** 2 for ki, r in zip(k, refs))) / len(refs)
    return Reference(photons, std, first.n_photons, " + ".join(r.source for r in refs),
                     next((r.centers for r in refs if r.centers is not None), None))


@dataclass
class Profile:
    """The ratio to a reference along one axis of one sensor plane, averaged over the sensors that share a
    coordinate (a row: the sensors of one ``y`` when ``axis`` is y), both sides normalised to mean 1 over all
    sensors.  Arrays are (k,), one entry per row, in increasing ``position``."""

    plane: str               # file-name tag of the plane, e.g. "z1000"
    title: str               # e.g. "z = 1000 mm, facing +z"
    axis: str                # the coordinate that names a row ("y": rows of constant y)
    position: np.ndarray     # (k,) that coordinate, scene units
    ratio: np.ndarray        # (k,) mean over the row of (ours / reference), mean 1 over all sensors
    ratio_std: np.ndarray    # (k,) its σ, from both σ's
    count: np.ndarray        # (k,) sensors in the row
    slope: float             # least-squares change of ``ratio`` from the first row to the last (σ-weighted)
    slope_std: float         # its σ

    def lines(self) -> list:
        """Printable lines: the plane and its slope, then one line per row."""
        out = ["%s: ratio to the reference along %s (mean 1), change across the rows %+.2f%% ± %.2f%%"
               % (self.title, self.axis, 100 * self.slope, 100 * self.slope_std)]
        for x, r, s, n in zip(self.position, self.ratio, self.ratio_std, self.count):
            out.append("  %s = %-8g %.4f ± %.4f  (%+.2f%%, %d sensor%s)" % (self.axis, x, r, s, 100 * (r - 1), n,
                                                                         "s" * int(n > 1)))
        return out


def row_profiles(photons, photons_std, ref: Reference, centers, normals, unit: str = "", across: int = 1) -> list:
    """:class:`Profile` of every sensor plane (largest first) of our counts (S,) against ``ref``.

    ``centers``, ``normals``: (S, 3) the sensors'.  Rows are the sensors sharing the plane's in-plane
    coordinate number ``across`` (1: the second, ``y`` on a horizontal plane, as in rows of constant y;
    0: the first, columns of constant x).  Per sensor r_s = (ours_s / Σ ours) / (ref_s / Σ ref), then
    divided by its mean over all sensors; its σ combines both relative σ's.  A row's ratio is the mean
    of its r_s.  The slope is the σ-weighted least-squares line through the rows against their position,
    reported as its change from the first row to the last (0 for a plane with one row).
    """
    from .plots import plane_groups

    photons, photons_std = np.asarray(photons, float), np.asarray(photons_std, float)
    if photons.shape != ref.photons.shape:
        raise InputError("reference has %d sensors, the run %d" % (len(ref.photons), len(photons)), ref.source)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = (photons / photons.sum()) / (ref.photons / ref.photons.sum())
        rel = np.hypot(photons_std / photons, ref.photons_std / ref.photons)
    ok = np.isfinite(ratio) & np.isfinite(rel)
    scale = ratio[ok].mean() if ok.any() else 1.0
    ratio, sigma = ratio / scale, ratio / scale * rel
    out = []
    for g in plane_groups(centers, normals, unit=unit):
        idx = g["index"][ok[g["index"]]]
        if not len(idx):
            continue
        coord = g["uv"][ok[g["index"]], across]
        span = max(float(np.ptp(g["uv"])), 1e-300)
        key = np.round(coord / span, 6)
        rows = np.unique(key)
        pos = np.array([coord[key == k].mean() for k in rows])
        n = np.array([np.sum(key == k) for k in rows])
        r = np.array([ratio[idx[key == k]].mean() for k in rows])
        rs = np.array([np.sqrt(np.sum(sigma[idx[key == k]] ** 2)) for k in rows]) / n
        slope = slope_std = 0.0
        if len(rows) > 1 and np.all(rs > 0):
            t = (pos - pos.mean()) / np.ptp(pos)           # first row to last: t spans 1
            w = 1 / rs ** 2
            a = np.stack([np.ones_like(t), t], axis=1)
            cov = np.linalg.inv(a.T @ (a * w[:, None]))
            slope, slope_std = float((cov @ (a.T @ (w * r)))[1]), float(np.sqrt(cov[1, 1]))
        out.append(Profile(g["name"], g["title"], g["axes"][across], pos, r, rs, n, slope, slope_std))
    return out


def compare(photons, photons_std, n_photons: float, ref: Reference) -> Comparison:
    """Compare our counts (S,) for ``n_photons`` emitted with a reference of the same S sensors."""
    photons, photons_std = np.asarray(photons, float), np.asarray(photons_std, float)
    if photons.shape != ref.photons.shape:
        raise InputError("reference has %d sensors, the run %d" % (len(ref.photons), len(photons)), ref.source)
    k = ref.n_photons / n_photons
    ours, ours_std = photons * k, photons_std * k
    sigma = np.hypot(ours_std, ref.photons_std)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(sigma > 0, (ours - ref.photons) / sigma, 0.0)
        relative = ours / ref.photons - 1
        rel_sigma = sigma / ref.photons
    S = len(relative)
    return Comparison(z=z, relative=relative, within_4sigma=float(np.mean(np.abs(z) < 4)),
                      bias=float(relative.mean()), bias_std=float(np.sqrt((rel_sigma ** 2).sum()) / S),
                      rms=float(np.sqrt(np.mean(relative ** 2))), rms_noise=float(np.sqrt(np.mean(rel_sigma ** 2))))
