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
* Calibration against measured sensors (``calibrate``): one scale per band,
  least squares through the origin, residuals reported.

Derived quantities (per sensor or organ): PAR = sum of the bands inside
400-700 nm when they tile it; R:FR = ppfd(655-665) / ppfd(725-735) (the
red:far-red ratio of Smith, 1982 / Sager et al., 1988, on SEC2's bands).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .errors import InputError
from .optical import Spectrum

RED, FAR_RED = (655.0, 665.0), (725.0, 735.0)


def read_lamp_spectrum(path) -> Spectrum:
    """Read a lamp spectrum: two columns, wavelength (nm) and µmol m⁻² s⁻¹ nm⁻¹; one header line."""
    path = Path(path)
    try:
        lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError as exc:
        raise InputError("cannot read spectrum: %s" % exc.strerror, path) from None
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


@dataclass
class Normalisation:
    """µmol m⁻² s⁻¹ per (photon packet / scene-unit² / N), per band: ``scale`` (B,) and its σ."""

    scale: np.ndarray
    scale_std: np.ndarray
    how: str


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
    return Normalisation(scale, scale_std, "lamp spectrum %s averaged over %d reference sensors"
                         % (spectrum.path, len(ref)))


def ppfd(photons, photons_std, area_m2, norm: Normalisation):
    """Photon flux density (µmol m⁻² s⁻¹) and its σ, (S, B), from photon counts on areas (S,) m²."""
    density = photons / area_m2[:, None]
    value = density * norm.scale
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.sqrt((photons_std / np.where(photons > 0, photons, np.nan)) ** 2
                      + (norm.scale_std / norm.scale) ** 2)
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


def red_far_red(value, std, bands):
    """R:FR = value[:, red] / value[:, far-red] and its σ, or (None, None) without both bands."""
    r, f = band_index(bands, RED), band_index(bands, FAR_RED)
    if r is None or f is None:
        return None, None
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = value[:, r] / value[:, f]
        rel = np.sqrt((std[:, r] / value[:, r]) ** 2 + (std[:, f] / value[:, f]) ** 2)
    return ratio, ratio * rel


def par_and_rfr(x, cov, scale, scale_std, bands):
    """PAR and R:FR with σ that include the bands' covariance (all bands ride on the same photons).

    ``x`` (S, B) tallies, ``cov`` (S, B, B) their covariance between bands,
    ``scale`` (S, B) the factor turning a tally into µmol m⁻² s⁻¹ (e.g.
    flux / (N · area)) and ``scale_std`` its σ (independent of the tallies).
    Returns ``par, par_std, rfr, rfr_std``, each (S,) or None when the bands
    do not allow it.
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
        with np.errstate(divide="ignore", invalid="ignore"):
            rfr = (x[:, r] * scale[:, r]) / (x[:, f] * scale[:, f])
            rel2 = (cov[:, r, r] / x[:, r] ** 2 + cov[:, f, f] / x[:, f] ** 2 - 2 * cov[:, r, f] / (x[:, r] * x[:, f])
                    + (scale_std[:, r] / scale[:, r]) ** 2 + (scale_std[:, f] / scale[:, f]) ** 2)
            rfr_std = np.abs(rfr) * np.sqrt(np.maximum(rel2, 0.0))
    return par, par_std, rfr, rfr_std
