"""From photon counts to µmol m⁻² s⁻¹.

The kernel counts photon packets: ``photons[s, b]`` is the expected number of
the N emitted packets of band b that reach sensor s.  Its flux density in
simulation terms is ``photons / (N · area)``.  To give it units we need how many
µmol s⁻¹ the lamps emit per band, which the measured lamp spectrum provides:

* ``spectrum/chambre1_spectrum.txt`` gives the spectral photon flux density
  q(λ) (µmol m⁻² s⁻¹ nm⁻¹) measured at a reference point in the chamber.  Its
  band value is M_b = mean of the samples in [start, end) × (end − start).
* **Assumption (stated, configurable):** the reference is the set of the
  scene's transparent sensors — the spectrum was measured at the sensor sites,
  so the simulated flux density averaged over them is M_b.  Then

      ppfd[s, b] = M_b · (photons[s, b] / area_s) / mean_r (photons[r, b] / area_r).

  ``reference`` can name other sensors (row indices).
* Calibration against measured sensors (:func:`read_measured`, :func:`calibrate`):
  a csv of measured values (µmol m⁻² s⁻¹) per band at sensor sites; one scale
  per band, least squares through the origin (measured = k_b · photons/area),
  residuals reported per measured point and as rms / R² per band.

Derived quantities (per sensor or organ): PAR = sum of the bands inside
400-700 nm when they tile it; R:FR = ppfd(655-665) / ppfd(725-735) (the
red:far-red ratio of Smith, 1982 / Sager et al., 1988, on SEC2's bands), without
the first-order bias of a ratio of two estimates (:mod:`lpy_light.chamber.ratios`).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError
from .optical import Spectrum, _text_lines
from . import ratios
from .ratios import MAX_DENOMINATOR_CV

log = logging.getLogger("lpy_light")

RED, FAR_RED = (655.0, 665.0), (725.0, 735.0)


def read_lamp_spectrum(path) -> Spectrum:
    """Read a lamp spectrum: two columns, wavelength (nm) and µmol m⁻² s⁻¹ nm⁻¹; one header line."""
    path = Path(path)
    lines = _text_lines(path, "spectrum")      # lines counted on \n only, as an editor counts them
    wl, val = [], []
    for number, line in enumerate(lines, start=1):
        # fields are separated by blanks, ';' or ','; with blanks or ';', a ',' is a decimal comma
        text = line.strip()
        if any(c in text for c in " \t;"):
            parts = text.replace(";", " ").replace(",", ".").split()
        else:
            parts = text.split(",")
        if not text:
            continue
        try:
            if len(parts) != 2:
                raise ValueError
            w, v = float(parts[0]), float(parts[1])
        except ValueError:
            if number == 1:
                continue
            raise InputError("expected 'wavelength value' (2 numbers), got %r" % line.strip(), path, number) from None
        if not (np.isfinite(w) and np.isfinite(v)) or v < 0:
            raise InputError("expected a finite, non-negative spectral value, got %r" % line.strip(), path, number)
        if wl and w <= wl[-1]:
            raise InputError("wavelengths must increase", path, number)
        wl.append(w)
        val.append(v)
    if len(wl) < 2:
        raise InputError("spectrum has fewer than 2 samples", path)
    return Spectrum(np.array(wl), np.array(val), str(path))


def band_photon_flux(spectrum: Spectrum, bands) -> np.ndarray:
    """M_b = ∫_band q(λ) dλ ≈ mean of samples in [start, end) × width, (B,) µmol m⁻² s⁻¹."""
    return np.array([spectrum.band_mean(a, b) * (b - a) for a, b in bands])


#: what :func:`from_spectrum` assumes (written to summary.json)
SPECTRUM_ASSUMPTION = ("the lamp spectrum was measured at the sensor sites: the mean photon flux density over the "
                       "reference sensors equals the measured band flux (ppfd[s, b] = M_b * density[s, b] / "
                       "mean_r density[r, b], M_b = integral of the measured spectrum over band b)")
CALIBRATION_ASSUMPTION = ("measured = k_b * photons / area_m2 per band b, k_b fitted by least squares through "
                          "the origin over the measured sensors")


@dataclass
class Normalisation:
    """µmol m⁻² s⁻¹ per (photons / m²) for the run's N photons, per band: ``scale`` (B,) and its σ.

    ppfd[s, b] = scale[b] · photons[s, b] / area_m2[s].
    """

    scale: np.ndarray
    scale_std: np.ndarray
    how: str
    assumption: str = SPECTRUM_ASSUMPTION


def from_spectrum(photons, photons_std, area_m2, spectrum, bands, reference=None) -> Normalisation:
    """Scale so the mean flux density over the reference sensors equals the measured spectrum.

    ``photons``, ``photons_std``: (S, B); ``area_m2``: (S,).
    """
    ref = np.arange(len(photons)) if reference is None else np.asarray(reference)
    if len(ref) == 0:
        raise InputError("normalising by the lamp spectrum needs reference sensors (the scene has none)")
    M = band_photon_flux(spectrum, bands)
    density = photons[ref] / area_m2[ref, None]
    mean = density.mean(axis=0)
    mean_std = np.sqrt(((photons_std[ref] / area_m2[ref, None]) ** 2).sum(axis=0)) / len(ref)
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = M / mean
        scale_std = scale * mean_std / mean
    for b in np.flatnonzero(~(mean > 0)):
        log.warning("band %g-%g nm: no photon reached the reference sensors, so the lamp spectrum cannot scale "
                    "this band: its ppfd is left empty (trace more photons, or check that light reaches the "
                    "sensors)" % tuple(bands[b]))
        scale[b] = scale_std[b] = np.nan
    return Normalisation(scale, scale_std, "lamp spectrum %s averaged over %d reference sensors"
                         % (spectrum.path, len(ref)))


LAMP_FLUX_ASSUMPTION = ("the scene's lamp_flux is the photon flux the lamps emit per band (µmol s-1; e.g. fitted "
                        "to a survey by lpy-light calibrate): ppfd[s, b] = lamp_flux_b * tally[s, b] / (N * area_s)")


def from_lamp_flux(chamber, photons: int) -> Normalisation:
    """Scale from the scene's ``lamp_flux`` (µmol s⁻¹ per band): exact, no σ.

    A photon of band b starts with the weight ``output / mean output`` of its lamp
    (:meth:`lpy_light.chamber.emitters.Emitters.start_weight`), whose mean over the lamps is
    ``band_share[b]``; the N photons then carry ``lamp_flux_b`` in total when each unit of weight is
    ``lamp_flux_b / (N · band_share_b)``."""
    share = chamber.emitters.band_share()
    scale = np.asarray(chamber.lamp_flux, float) / photons / (1.0 if share is None else share)
    return Normalisation(scale, np.zeros_like(scale), "lamp flux of the scene %s (µmol s-1 per band)"
                         % chamber.source, LAMP_FLUX_ASSUMPTION)


def scene_normalisation(chamber, result) -> Normalisation | None:
    """The scene's own way to µmol m⁻² s⁻¹: its ``lamp_flux``, else its lamp spectrum over its sensors, else
    None (photon counts only)."""
    if chamber.lamp_flux is not None:
        return from_lamp_flux(chamber, result.photons)
    if chamber.spectrum is not None and chamber.bands is not None and len(chamber.sensors):
        photons, std = result.sensors()
        return from_spectrum(photons, std, chamber.sensors.area * chamber.metres_per_unit ** 2, chamber.spectrum,
                             chamber.bands)
    return None


def ppfd(photons, photons_std, area_m2, norm: Normalisation):
    """Photon flux density (µmol m⁻² s⁻¹) and its σ, (S, B), from photon counts on areas (S,) m²."""
    density = photons / area_m2[:, None]
    value = density * norm.scale
    with np.errstate(divide="ignore", invalid="ignore"):
        scale_rel = np.where(norm.scale != 0, norm.scale_std / norm.scale, 0.0)   # a dark band: ppfd exactly 0
        rel = np.sqrt((photons_std / np.where(photons > 0, photons, np.nan)) ** 2 + scale_rel ** 2)
    std = np.where(photons > 0, value * rel, photons_std / area_m2[:, None] * norm.scale)
    return value, std


def band_index(bands, band) -> int | None:
    for i, (a, b) in enumerate(bands or []):
        if abs(a - band[0]) < 1e-9 and abs(b - band[1]) < 1e-9:
            return i
    return None


def par_columns(bands):
    """Indices of the bands that tile 400-700 nm exactly, or None."""
    inside = sorted((a, b, i) for i, (a, b) in enumerate(bands or []) if a >= 400 and b <= 700)
    if not inside or inside[0][0] != 400 or inside[-1][1] != 700:
        return None
    for (a0, b0, _), (a1, b1, _) in zip(inside, inside[1:]):
        if b0 != a1:
            return None
    return [i for _, _, i in inside]


#: how R:FR is computed (summary.json): :func:`lpy_light.chamber.ratios.corrected_ratio`
RFR_HOW = ("ppfd(red) / ppfd(far red) without its first-order bias (delta method on the bands' covariance, "
           "docs/physics.md); empty where the far red's relative sigma exceeds %g" % MAX_DENOMINATOR_CV)


def derived_description(bands) -> dict:
    """What ``sensors_derived.csv`` holds for these bands (for summary.json): PAR's bands, R:FR's two bands."""
    out = {}
    cols = par_columns(bands)
    if cols is not None:
        out["par"] = {"bands": ["%g-%g" % tuple(bands[i]) for i in cols],
                      "how": "sum of the bands' ppfd that tile 400-700 nm, µmol m-2 s-1"}
    if band_index(bands, RED) is not None and band_index(bands, FAR_RED) is not None:
        out["r_fr"] = {"red": "%g-%g" % RED, "far_red": "%g-%g" % FAR_RED, "how": RFR_HOW}
    return out


def par_and_rfr(x, cov, scale, scale_std, bands):
    """PAR and R:FR with σ that include the bands' covariance (all bands ride on the same photons).

    ``x`` (S, B) tallies, ``cov`` (S, B, B) their covariance between bands,
    ``scale`` (S, B) the factor turning a tally into µmol m⁻² s⁻¹ (e.g.
    flux / (N · area)) and ``scale_std`` its σ (independent of the tallies).
    Returns ``par, par_std, rfr, rfr_std``, each (S,) or None when the bands
    do not allow it.  R:FR is the ratio without its first-order bias, NaN where
    the far red's relative σ exceeds :data:`lpy_light.chamber.ratios.MAX_DENOMINATOR_CV`
    or it has no far red (:func:`lpy_light.chamber.ratios.corrected_ratio`).
    """
    par = par_std = rfr = rfr_std = None
    cols = par_columns(bands)
    if cols is not None:
        w = np.zeros_like(scale)
        w[:, cols] = scale[:, cols]
        par = (x * w).sum(axis=1)
        var = np.einsum("sb,sbc,sc->s", w, cov, w) + ((x[:, cols] * scale_std[:, cols]) ** 2).sum(axis=1)
        par_std = np.sqrt(np.maximum(var, 0.0))
    r, f = band_index(bands, RED), band_index(bands, FAR_RED)
    if r is not None and f is not None:
        tallies = x[:, r], x[:, f], cov[:, r, r], cov[:, f, f], cov[:, r, f], scale[:, r], scale[:, f]
        if not ratios.correcting():             # benchmarks measuring the bias only (ratios.uncorrected)
            rfr, rfr_std = ratios.plain_ratio(*tallies, scale_std[:, r], scale_std[:, f])
            return par, par_std, rfr, rfr_std
        with np.errstate(divide="ignore", invalid="ignore"):
            cv2 = (scale_std / scale) ** 2
        rfr, rfr_std, _ = ratios.corrected_ratio(*tallies, cv2[:, r], cv2[:, f])
    return par, par_std, rfr, rfr_std


# --- calibration against measured sensors ---------------------------------------------------
@dataclass
class Measured:
    """Measured values at scene sensors, read from a csv (:func:`read_measured`).

    ``sensor`` (P,) the matched scene sensor of each measured row, ``line`` (P,)
    its line in the file, ``distance`` (P,) from the measured point to that
    sensor's centre (scene units; 0 when given by ``sensor`` index alone),
    ``values`` (P, B) µmol m⁻² s⁻¹ (nan where the row has no value for a band),
    ``columns`` (B,) whether the file has a column for each scene band.
    """

    path: str
    sensor: np.ndarray
    line: np.ndarray
    distance: np.ndarray
    values: np.ndarray
    columns: np.ndarray


@dataclass
class Calibration:
    """The result of :func:`calibrate`: a :class:`Normalisation`, residual rows and per-band figures."""

    norm: Normalisation
    rows: list
    summary: dict


def _band_of(header: str, labels, bands):
    """Index of the scene band a csv column names (``655-665`` or the label itself), None if not a band
    column, -1 if it looks like a band the scene does not have."""
    h = header.strip()
    if h in labels:
        return labels.index(h)
    parts = h.replace("nm", "").split("-")
    if len(parts) == 2:
        try:
            a, b = float(parts[0]), float(parts[1])
        except ValueError:
            return None
        i = band_index(bands, (a, b)) if bands else None
        return -1 if i is None else i
    return None


def sensor_size(sensors) -> np.ndarray:
    """Default matching tolerance per sensor (scene units): a disc's radius, a quad's centre-to-corner distance."""
    size = np.array(sensors.radius, float)
    quad = size == 0
    if quad.any():
        size[quad] = np.linalg.norm(sensors.corners[quad] - sensors.center[quad, None, :], axis=2).max(axis=1)
    return size


def read_measured(path, chamber, tolerance: float | None = None) -> Measured:
    """Read a csv of measured sensors and match each row to a scene sensor.

    Columns: ``x,y,z`` (scene units; the nearest scene sensor is taken, an error
    if it is farther than ``tolerance``, by default the sensor's own radius) or
    ``sensor`` (0-based row of the scene's sensors, as in ``sensors.csv``), and
    one column per band named by its label (``655-665``; ``rad`` for a scene
    without bands) holding µmol m⁻² s⁻¹.  Empty cells are missing values; other
    columns are ignored; one row per reading (repeat readings of a site are
    separate points).
    """
    import csv

    path = Path(path)
    try:
        with open(path, newline="", encoding="utf-8-sig", errors="replace") as fh:
            text = fh.read()
    except OSError as exc:
        raise InputError("cannot read calibration file: %s" % exc.strerror, path) from None
    lines = [line[:-1] if line.endswith("\r") else line for line in text.split("\n")]   # as an editor counts
    while lines and not lines[-1].strip():
        lines.pop()
    if not lines or not lines[0].strip():
        raise InputError("calibration file is empty (expected a header x,y,z or sensor, then band columns)", path, 1)
    delimiter = ";" if lines[0].count(";") > lines[0].count(",") else ","
    rows = list(csv.reader(lines, delimiter=delimiter))
    header = [h.strip() for h in rows[0]]
    low = [h.lower() for h in header]
    labels, bands = chamber.band_labels, chamber.bands
    B = len(labels)
    band_col = {}
    for c, h in enumerate(header):
        b = _band_of(h, labels, bands)
        if b == -1:
            raise InputError("column %r is not a band of the scene (bands: %s)" % (h, ", ".join(labels)), path, 1)
        if b is not None:
            if b in band_col.values():
                raise InputError("band %s has two columns" % labels[b], path, 1)
            band_col[c] = b
    if not band_col:
        raise InputError("no band column (expected one or more of %s)" % ", ".join(labels), path, 1)
    has_xyz = all(k in low for k in "xyz")
    has_index = "sensor" in low
    if not (has_xyz or has_index):
        raise InputError("expected columns x,y,z (a measured point) or sensor (a row of the scene's sensors)", path, 1)
    S = len(chamber.sensors)
    if S == 0:
        raise InputError("calibration needs scene sensors (the scene has none)", path)
    center = chamber.sensors.center
    size = sensor_size(chamber.sensors)
    sensor, line_no, dist, values = [], [], [], []
    for number, row in enumerate(rows[1:], start=2):
        if not row or all(not c.strip() for c in row):
            continue
        if len(row) < len(header):
            raise InputError("expected %d values (%s), got %d" % (len(header), ",".join(header), len(row)), path, number)
        cells = dict(zip(low, (c.strip().replace(",", ".") if delimiter == ";" else c.strip() for c in row)))
        try:
            if has_index:
                s = int(cells["sensor"])
                if not 0 <= s < S:
                    raise InputError("sensor %d is not a row of the scene's %d sensors (0-based)" % (s, S), path, number)
            if has_xyz:
                p = np.array([float(cells[k]) for k in "xyz"])
                if not np.isfinite(p).all():
                    raise ValueError
        except ValueError:
            raise InputError("expected %s as numbers, got %r" % ("sensor" if has_index else "x,y,z", ",".join(row)),
                             path, number) from None
        d = 0.0
        if has_xyz:
            dd = np.linalg.norm(center - p, axis=1)
            if not has_index:
                s = int(np.argmin(dd))
            d = float(dd[s])
            tol = size[s] if tolerance is None else tolerance
            if d > tol:
                raise InputError("measured point (%g, %g, %g) is %.4g %s from the nearest scene sensor (row %d at "
                                 "%g, %g, %g), more than the tolerance %.4g"
                                 % (*p, d, chamber.unit, s, *center[s], tol), path, number)
        v = np.full(B, np.nan)
        for c, b in band_col.items():
            cell = row[c].strip()
            if not cell:
                continue
            try:
                v[b] = float(cell.replace(",", ".") if delimiter == ";" else cell)
            except ValueError:
                raise InputError("expected a number for band %s, got %r" % (labels[b], cell), path, number) from None
            if not np.isfinite(v[b]) or v[b] < 0:
                raise InputError("expected a finite, non-negative value for band %s, got %r" % (labels[b], cell),
                                 path, number)
        sensor.append(s)
        line_no.append(number)
        dist.append(d)
        values.append(v)
    if not sensor:
        raise InputError("calibration file has no measured rows", path)
    columns = np.zeros(B, bool)
    columns[list(band_col.values())] = True
    return Measured(str(path), np.array(sensor), np.array(line_no), np.array(dist), np.array(values), columns)


def calibrate(measured: Measured, photons, photons_std, area_m2, labels, fallback: Normalisation | None = None
              ) -> Calibration:
    """One scale per band, least squares through the origin: measured = k_b · photons / area_m2.

    ``photons``, ``photons_std`` (S, B) for the run's N photons, ``area_m2`` (S,).
    k_b = Σ x y / Σ x², x = simulated density at the matched sensors, y = measured;
    σ(k_b) = √(Σ r² / (n − 1) / Σ x²) from the residuals r = y − k_b x (they hold
    both the measurement's and the simulation's noise), or from the simulation's
    σ alone for one point.  Bands without a column take ``fallback``'s scale
    (the lamp spectrum) or raise.  R² = 1 − Σ r² / Σ (y − ȳ)².
    """
    B = len(labels)
    scale, scale_std = np.full(B, np.nan), np.full(B, np.nan)
    per_band, rows = {}, []
    s_idx = measured.sensor
    density = photons[s_idx] / area_m2[s_idx, None]
    density_std = photons_std[s_idx] / area_m2[s_idx, None]
    for b, label in enumerate(labels):
        if not measured.columns[b]:
            if fallback is None:
                raise InputError("no column for band %s, and the scene has no lamp spectrum to normalise it"
                                 % label, measured.path, 1)
            scale[b], scale_std[b] = fallback.scale[b], fallback.scale_std[b]
            per_band[label] = {"from": "lamp spectrum", "scale": float(scale[b]), "scale_std": float(scale_std[b])}
            continue
        keep = np.isfinite(measured.values[:, b])
        x, xs, y = density[keep, b], density_std[keep, b], measured.values[keep, b]
        n = int(keep.sum())
        sxx = float(x @ x)
        if n == 0 or not sxx > 0:
            raise InputError("band %s: %s" % (label, "no measured value" if n == 0 else
                                               "no simulated photons on the measured sensors (trace more photons)"),
                             measured.path)
        k = float(x @ y) / sxx
        r = y - k * x
        if n > 1:
            k_std = float(np.sqrt((r @ r) / (n - 1) / sxx))
        else:
            k_std = abs(k) * float(xs[0] / x[0])
        ss_tot = float(((y - y.mean()) ** 2).sum())
        with np.errstate(divide="ignore", invalid="ignore"):
            rel = np.where(y > 0, r / y, np.nan)
        scale[b], scale_std[b] = k, k_std
        per_band[label] = {
            "from": "measured", "points": n, "scale": k, "scale_std": k_std,
            "rms": float(np.sqrt(np.mean(r ** 2))), "rms_relative": float(np.sqrt(np.nanmean(rel ** 2))),
            "r2": 1.0 - float(r @ r) / ss_tot if n > 1 and ss_tot > 0 else float("nan"),
        }
        if fallback is not None and fallback.scale[b] > 0:
            per_band[label]["scale_over_spectrum"] = k / float(fallback.scale[b])
        for j, i in enumerate(np.flatnonzero(keep)):
            s = int(s_idx[i])
            rows.append({"line": int(measured.line[i]), "sensor": s, "band": label,
                         "distance": float(measured.distance[i]), "measured": float(y[j]),
                         "simulated": k * float(x[j]), "simulated_std": abs(k) * float(xs[j]),
                         "residual": float(r[j]), "relative_residual": float(rel[j])})
    how = "calibrated against %s (%d measured rows)" % (measured.path, len(measured.sensor))
    summary = {"file": measured.path, "rows": int(len(measured.sensor)), "assumption": CALIBRATION_ASSUMPTION,
               "bands": per_band}
    return Calibration(Normalisation(scale, scale_std, how, CALIBRATION_ASSUMPTION), rows, summary)
