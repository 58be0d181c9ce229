"""Materials: what a surface does to a photon, per spectral band.

Each material becomes a (5, B) table of event probabilities (SEC2's model):

=================  =================================  ==============================
event              probability                        new direction
=================  =================================  ==============================
diffuse reflect    R·(1 − s)                          cosine lobe, front side
specular reflect   R·s                                mirror (or Phong lobe, option)
diffuse transmit   T·(1 − t_s)                        cosine lobe, back side
specular transmit  T·t_s                              unchanged (thin surface)
absorb             1 − R − T                          photon ends
=================  =================================  ==============================

R, T: band means of the measured tables when the material has one (file name =
material name), else the ``.rad`` values (mean of the R, G, B reals).  s: the
specularity table's value, else the ``.rad`` specularity.  Radiance parameters:

* ``plastic``/``metal`` R G B spec rough — SEC2 uses the same split for both.
* ``trans`` R G B spec rough trans tspec — read as SEC2 does: ``trans`` is the
  transmittance T itself and ``tspec`` the specular part of it.  (Radiance's own
  ``trans`` divides these differently; see docs/physics.md.)
* ``mirror`` R G B — R = mean, all specular.
* ``light``/``glow`` — emit; as surfaces they absorb everything.

With ``[physics] materials = "radiance"`` a material *without* measured tables
takes Radiance's own energy split instead (C = mean of R, G, B; no Fresnel or
roughness terms): ``plastic`` diffuse C(1 − s), specular s; ``metal`` diffuse
C(1 − s), specular C·s; ``trans`` diffuse reflection C(1 − s)(1 − t), specular
reflection s, transmission C(1 − s)·t, of which the part ``tspec`` is specular.
Measured tables always give R and T directly.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..errors import InputError
from ..kernel.records import ABSORB, DIFFUSE_R, DIFFUSE_T, SPECULAR_R, SPECULAR_T  # noqa: F401  (the kinds, once)
from .radiance import MATERIAL_TYPES

EMITTING = ("light", "glow")


@dataclass
class Material:
    """A material's per-band behaviour.  ``events``: (5, B) probabilities; ``roughness``: Radiance α."""

    name: str
    type: str
    events: np.ndarray
    roughness: float = 0.0
    radiance: float = 0.0     # mean RGB radiance of light/glow, W sr⁻¹ m⁻² in Radiance's units
    where: str = ""


def build_material(prim, bands, optical=None, specularities=None, reading: str = "sec2") -> Material:
    """Event table of one material primitive for ``bands`` (list of (start, end) nm, or None = rad values).

    ``reading``: how ``.rad`` parameters of a material without tables become R, s, T — "sec2"
    (default) or "radiance" (see the module docstring)."""
    n_bands = 1 if bands is None else len(bands)
    expected = MATERIAL_TYPES[prim.type]
    if len(prim.reals) != expected:
        raise InputError("%s %s needs %d real arguments, got %d" % (prim.type, prim.identifier, expected,
                                                                   len(prim.reals)), prim.path, prim.line)
    r = prim.reals
    events = np.zeros((5, n_bands))
    if prim.type in EMITTING:
        if not all(x >= 0 for x in r[:3]):
            raise InputError("%s %s: radiance %s: a lamp cannot emit negative light (each of r g b must be >= 0)"
                             % (prim.type, prim.identifier, " ".join("%g" % x for x in r[:3])), prim.path, prim.line)
        events[ABSORB] = 1.0
        return Material(prim.identifier, prim.type, events, radiance=float(np.mean(r[:3])), where=prim.where)
    if any(x < 0 for x in r):
        raise InputError("%s %s has a negative argument" % (prim.type, prim.identifier), prim.path, prim.line)

    def from_table(tables, fallback):
        if bands is not None and optical is not None and prim.identifier in tables:
            return np.array([tables[prim.identifier].band_mean(a, b) for a, b in bands])
        return np.full(n_bands, fallback)

    R = from_table(optical.reflectance if optical else {}, float(np.mean(r[:3])))
    s = r[3] if prim.type != "mirror" else 1.0
    if specularities and prim.identifier in specularities and prim.type != "mirror":
        s = specularities[prim.identifier]
    rough = r[4] if prim.type in ("plastic", "metal", "trans") else 0.0
    T = np.zeros(n_bands)
    tspec = 0.0
    if prim.type == "trans":
        T = from_table(optical.transmittance if optical else {}, r[5])
        tspec = r[6]
    elif optical is not None and bands is not None and prim.identifier in optical.transmittance:
        import logging
        logging.getLogger("lpy_light").warning(
            "%s: %s %s has a transmittance table (%s), which only a 'trans' material uses: it lets no light "
            "through", prim.where, prim.type, prim.identifier, optical.transmittance[prim.identifier].path)
    if s > 1 or tspec > 1:
        raise InputError("%s %s: specular fractions must be <= 1" % (prim.type, prim.identifier),
                         prim.path, prim.line)
    events[DIFFUSE_R] = R * (1 - s)
    events[SPECULAR_R] = R * s
    events[DIFFUSE_T] = T * (1 - tspec)
    events[SPECULAR_T] = T * tspec
    tabled = optical is not None and bands is not None and (
        prim.identifier in optical.reflectance or prim.identifier in optical.transmittance)
    if reading == "radiance" and prim.type in ("plastic", "metal", "trans") and not tabled:
        C = float(np.mean(r[:3]))
        t = r[5] if prim.type == "trans" else 0.0
        events[DIFFUSE_R] = C * (1 - s) * (1 - t)
        events[SPECULAR_R] = C * s if prim.type == "metal" else s
        events[DIFFUSE_T] = C * (1 - s) * t * (1 - tspec)
        events[SPECULAR_T] = C * (1 - s) * t * tspec
        R = events[DIFFUSE_R] + events[SPECULAR_R]
        T = events[DIFFUSE_T] + events[SPECULAR_T]
    total = R + T
    if np.any(total > 1 + 1e-9):
        b = int(np.argmax(total))
        hint = ("" if reading == "radiance" or prim.type != "trans" else
                " (read as SEC2 does: R = mean colour, T = trans; for Radiance's own split of these "
                "parameters set [physics] materials = \"radiance\")")
        raise InputError("%s %s reflects and transmits %.4g > 1 (band %d): not energy-conserving%s"
                         % (prim.type, prim.identifier, total[b], b, hint), prim.path, prim.line)
    events[ABSORB] = np.clip(1 - total, 0, 1)
    return Material(prim.identifier, prim.type, events, roughness=rough, where=prim.where)


def black(n_bands: int, name: str = "black") -> Material:
    e = np.zeros((5, n_bands))
    e[ABSORB] = 1
    return Material(name, "plastic", e)


def band_passes(prob: np.ndarray) -> np.ndarray:
    """(B,) the pass (path) that carries each band, for ``prob`` (M, 5, B): bands share a path as long as
    Σ_e max_b P_e,b over the group's bands stays <= 1 for every material (e = the four scattering events).

    Then q_e = max over the group's bands of P_e,b is a probability table and no weight factor
    P_e,b / q_e exceeds 1.  Where it would sum above 1 (a dichroic film: R = 0.95 in blue, T = 0.95 in
    red), scaling q down lets a band's weight grow bounce after bounce (×1.9 per hit there), an estimate
    whose σ cannot be trusted; those bands travel on paths of their own instead.  Greedy, in band order:
    one pass for every measured chamber and plant seen so far."""
    scatter = prob[:, :ABSORB, :]                      # (M, 4, B)
    passes, tops = np.zeros(prob.shape[2], np.int64), []
    for b in range(prob.shape[2]):
        for g, top in enumerate(tops):
            merged = np.maximum(top, scatter[:, :, b])
            if np.all(merged.sum(axis=1) <= 1.0 + 1e-12):
                tops[g] = merged
                passes[b] = g
                break
        else:
            passes[b] = len(tops)
            tops.append(scatter[:, :, b].copy())
    return passes


def sampling_tables(materials, specular: str = "mirror", weighted: bool = True):
    """Arrays the kernel needs: ``prob`` (M, 5, B) event probabilities per band,
    ``cum`` (M, 5, P) cumulative probabilities q of the event drawn on each of P
    paths per photon (the last slot, "absorb", takes the rest), ``passes`` (B,)
    the path that carries each band, ``phong`` (M,) lobe exponents (inf =
    perfect mirror).

    ``weighted`` (the estimators whose photons carry a weight, :attr:`lpy_light.estimators.registry.Estimator.weighted`:
    ``weighted``, ``nee``): bands share paths (:func:`band_passes`; P = 1 in
    every scene so far), q of a path = max over its bands of P_e,b over the four
    scattering events, so that the weight factor P_e,b / q_e never exceeds 1;
    absorption is deposited as an expected value by the kernel.  Not ``weighted`` (``analog``):
    P = B, q = P_e,b of each band: SEC2's own counting, one band per path; the
    kernel then traces every photon once per band, each path carrying weight 1
    in its band only (a shared q, e.g. the band mean, would let a band whose
    P_e,b exceeds q grow its weight bounce after bounce: with R = 0.9 / 0.1 /
    0.6 the second moment grows by 0.81 / 0.53 = 1.5 per bounce, an estimate
    whose σ cannot be trusted).
    """
    from ..kernel.sampling import phong_exponent

    prob = np.stack([m.events for m in materials])
    if not weighted:
        q = prob.copy()                              # (M, 5, B): each band its own path
        passes = np.arange(prob.shape[2])
    else:
        passes = band_passes(prob)
        q = np.stack([prob[:, :, passes == g].max(axis=2) for g in range(passes.max() + 1)], axis=2)
        q[:, ABSORB, :] = 0.0
    cum = np.cumsum(q, axis=1)
    cum[:, -1, :] = 1.0 + 1e-12   # the last event takes the rest, whatever the rounding
    cum = np.ascontiguousarray(cum)
    if specular == "phong":
        phong = np.array([phong_exponent(m.roughness) for m in materials])
    else:
        phong = np.full(len(materials), math.inf)
    return prob, cum, np.ascontiguousarray(passes), phong
