"""What a scene file changes in the chamber its geometry describes: lamps, materials, the lamps' flux, and where a
calibration's survey constrains the light.

A fitted chamber (``lpy-light calibrate``, :mod:`lpy_light.calibration.calibrate`) is the original scene plus these
tables; anyone may write them by hand too::

    base = "angers-12bands"          # the scene this one changes (a path, or a built-in scene's name)

    [lamps.lamp20Str]                # a light source, by its identifier in the geometry
    output = 0.93                    # its power × this, in every band; or one factor per band
    shift = [0.0, 12.5, 0.0]         # its emission moved by this (scene units); its surfaces stay

    [materials.MurBlanc]             # a material, by its name
    reflectance = 0.95               # its reflectance (diffuse and specular) × this
    [materials.Makrolon]
    specular_transmission = 0.1      # the part of its transmittance that goes straight through (0..1)

    lamp_flux = [812.0, 150.3, ...]  # µmol s-1 the lamps emit in each band: ppfd from this, not the spectrum

    [surveyed]                       # where the fit's survey constrains the light (calibrate writes it)
    lower = [110.0, 930.0, 1000.0]   # its sites' box, scene units
    upper = [1210.0, 1830.0, 1400.0]
    margin = 100.0                   # how far beyond the box it still does (the sites' spacing)
    sigma = [[1000.0, 0.014], ...]   # the fitted light's relative σ over the chamber at each height

A plant that reaches beyond ``[surveyed]`` is warned about, once (:func:`outside_survey`).

``output`` and ``lamp_flux`` are per band (a single number: the same in every band).  With ``lamp_flux``
the photon counts become µmol m⁻² s⁻¹ directly (:func:`lpy_light.chamber.units.from_lamp_flux`), with no
assumption about where the lamp spectrum was measured.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..kernel.emission import EMIT_CYLINDER, EMIT_LINE, EMIT_POINT, EMIT_SPHERE, EMIT_TRIANGLE
from .materials import ABSORB, DIFFUSE_R, DIFFUSE_T, SPECULAR_R, SPECULAR_T

#: the keys of a ``[lamps.NAME]`` and a ``[materials.NAME]`` table
LAMP_KEYS = ("output", "shift")
MATERIAL_KEYS = ("reflectance", "specular_transmission")
#: rows of an emitter element's ``data`` that are points (the rest are radii)
_POINT_ROWS = {EMIT_LINE: 2, EMIT_CYLINDER: 2, EMIT_POINT: 1, EMIT_SPHERE: 1, EMIT_TRIANGLE: 3}


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def per_band(value, n_bands: int, what: str, positive: bool = True) -> np.ndarray:
    """A number or a list of ``n_bands`` numbers -> (B,) float64; ValueError saying what is wrong."""
    items = value if isinstance(value, list) else [value]
    if not items or not all(_is_number(x) for x in items) or len(items) not in (1, n_bands):
        raise ValueError("%s must be a number or a list of %d numbers (one per band), got %r"
                         % (what, n_bands, value))
    out = np.broadcast_to(np.array(items, float), (n_bands,)).copy()
    if positive and not (out >= 0).all():
        raise ValueError("%s must be >= 0, got %r" % (what, value))
    return out


def apply_lamps(chamber, lamps: dict, err) -> dict:
    """Change ``chamber.emitters`` by the ``[lamps.NAME]`` tables; returns what was applied, for summaries.
    ``err(message, key)`` makes the InputError naming the scene file's line."""
    em = chamber.emitters
    B = chamber.n_bands
    output = np.ones((len(em), B)) if em.output is None else em.output.copy()
    data = em.data.copy()
    names = np.array(em.name, dtype=object)
    applied = {}
    for name, table in lamps.items():
        key = ("lamps", name)
        if not isinstance(table, dict):
            raise err("[lamps.%s] must be a table (output = ..., shift = [dx, dy, dz])" % name, key)
        mine = names == name
        if not mine.any():
            raise err("[lamps.%s]: no light source of that identifier (light sources: %s)"
                      % (name, ", ".join(sorted(set(em.name))) or "none"), key)
        for k, v in table.items():
            if k not in LAMP_KEYS:
                raise err("[lamps.%s]: unknown key %r (known: %s)" % (name, k, ", ".join(LAMP_KEYS)), key + (k,))
        if "output" in table:
            try:
                output[mine] *= per_band(table["output"], B, "[lamps.%s] output" % name)
            except ValueError as exc:
                raise err(str(exc), key + ("output",)) from None
        if "shift" in table:
            s = table["shift"]
            if not (isinstance(s, list) and len(s) == 3 and all(_is_number(x) for x in s)):
                raise err("[lamps.%s] shift must be [dx, dy, dz] in scene units, got %r" % (name, s), key + ("shift",))
            for e in np.flatnonzero(mine):
                data[e, :_POINT_ROWS[int(em.kind[e])]] += np.array(s, float)
        applied[name] = dict(table)
    if applied:
        chamber.emitters = dataclasses.replace(em, data=data, output=output)
    return applied


def apply_materials(chamber, materials: dict, err) -> dict:
    """Change ``chamber.materials`` by the ``[materials.NAME]`` tables (in place); returns what was applied."""
    by_name = {m.name: i for i, m in enumerate(chamber.materials)}
    applied = {}
    for name, table in materials.items():
        key = ("materials", name)
        if not isinstance(table, dict):
            raise err("[materials.%s] must be a table (reflectance = ..., specular_transmission = ...)" % name, key)
        if name not in by_name:
            raise err("[materials.%s]: no material of that name in the scene" % name, key)
        i = by_name[name]
        e = chamber.materials[i].events.copy()
        for k, v in table.items():
            if k not in MATERIAL_KEYS:
                raise err("[materials.%s]: unknown key %r (known: %s)" % (name, k, ", ".join(MATERIAL_KEYS)),
                          key + (k,))
            if k == "reflectance":
                try:
                    f = per_band(v, e.shape[1], "[materials.%s] reflectance" % name)
                except ValueError as exc:
                    raise err(str(exc), key + (k,)) from None
                e[DIFFUSE_R] *= f
                e[SPECULAR_R] *= f
            else:
                if not (_is_number(v) and 0 <= v <= 1):
                    raise err("[materials.%s] specular_transmission must be in 0..1, got %r" % (name, v), key + (k,))
                T = e[DIFFUSE_T] + e[SPECULAR_T]
                e[DIFFUSE_T], e[SPECULAR_T] = T * (1 - v), T * v
        total = e[DIFFUSE_R] + e[SPECULAR_R] + e[DIFFUSE_T] + e[SPECULAR_T]
        if (total > 1 + 1e-9).any():
            raise err("[materials.%s]: reflects and transmits %.4g > 1 in band %d: not energy-conserving"
                      % (name, total.max(), int(np.argmax(total))), key)
        e[ABSORB] = np.clip(1 - total, 0, 1)
        chamber.materials[i] = dataclasses.replace(chamber.materials[i], events=e)
        applied[name] = dict(table)
    return applied


def lamp_flux(value, n_bands: int, err) -> np.ndarray:
    """The ``lamp_flux`` key: (B,) µmol s⁻¹, each > 0."""
    try:
        flux = per_band(value, n_bands, "'lamp_flux' (µmol s-1 per band)")
    except ValueError as exc:
        raise err(str(exc), "lamp_flux") from None
    if not (flux > 0).all():
        raise err("'lamp_flux' must be > 0 in every band, got %r" % (value,), "lamp_flux")
    return flux


def _point(v) -> bool:
    return isinstance(v, list) and len(v) == 3 and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                       for x in v)


def read_surveyed(table, err) -> dict:
    """A fitted scene's ``[surveyed]`` table (written by ``calibrate``): ``lower``, ``upper`` [x, y, z] the box of
    the survey's sites, ``margin`` how far beyond it the survey still constrains the light (scene units), and
    optionally ``sigma`` [[z, relative σ], ...] the fitted light's σ over the chamber at those heights."""
    if not isinstance(table, dict) or not _point(table.get("lower")) or not _point(table.get("upper")):
        raise err("[surveyed] needs lower = [x, y, z] and upper = [x, y, z] (scene units)", ("surveyed",))
    margin = table.get("margin", 0.0)
    if not isinstance(margin, (int, float)) or margin < 0:
        raise err("[surveyed] margin must be a number >= 0 (scene units)", ("surveyed", "margin"))
    sigma = table.get("sigma", [])
    if not (isinstance(sigma, list) and all(isinstance(p, list) and len(p) == 2 for p in sigma)):
        raise err("[surveyed] sigma must be [[z, relative sigma], ...]", ("surveyed", "sigma"))
    return {"lower": np.array(table["lower"], float), "upper": np.array(table["upper"], float),
            "margin": float(margin), "sigma": [(float(z), float(v)) for z, v in sigma]}


def outside_survey(surveyed: dict | None, lower, upper, unit: str = "") -> str | None:
    """A warning when the box ``lower``..``upper`` (a plant's, scene units) reaches beyond what the calibration's
    survey constrains (its sites' box and margin), or None."""
    if not surveyed:
        return None
    lo, hi = surveyed["lower"] - surveyed["margin"], surveyed["upper"] + surveyed["margin"]
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    if (lower >= lo).all() and (upper <= hi).all():
        return None
    top = float(upper[2])
    sigma = [v for z, v in surveyed["sigma"] if z <= top + surveyed["margin"]]
    worst = (" the fitted light's σ is up to %.1f %% at that height (the calibration's report.md)" % (100 * max(sigma))
             if sigma else "")
    fmt = lambda a: "(%s)" % ", ".join("%.4g" % x for x in a)    # noqa: E731
    return ("the plant %s..%s %s reaches beyond the region the calibration's survey constrains, %s..%s with a "
            "margin of %.4g:%s" % (fmt(lower), fmt(upper), unit, fmt(surveyed["lower"]), fmt(surveyed["upper"]),
                                   surveyed["margin"], worst or " its light there is as described, not as measured"))
