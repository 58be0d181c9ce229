"""What a growth step's precision goal asks of the target organs, and how far the photons so far are from it.

A goal is given (``LightModel(precision=...)``, ``lpy-light grow --precision``) as

* a number p in (0, 1): the relative σ of every target organ's PAR and R:FR (each band's ppfd when the
  bands give neither), as before;
* a mapping of the quantities the model's rules read to their σ: ``{"par": 0.03, "rfr": 0.02}`` --
  ``par``: relative σ of PAR; ``rfr``: **absolute** σ of R:FR (a ratio: 0.02 is ±0.02 on R:FR ≈ 1);
  a band label ``"655-665"``: relative σ of that band's ppfd;
* on the command line, the same as text: ``0.04`` or ``par=0.03,rfr=0.02``.

Parsed (:func:`parse_goal`), a goal is a :class:`Goal`: ``{quantity: (σ, relative)}``.  A step runs until
:func:`sigma_over_goal` -- the largest σ / goal over the target organs and the asked quantities -- is ≤ 1,
or its photon cap.  Organs without light in a quantity's bands are not waited for; an organ whose R:FR is
not reported yet (its far red's relative σ above :data:`lpy_light.chamber.ratios.MAX_DENOMINATOR_CV`) counts as
``far red's CV / MAX_DENOMINATOR_CV`` (> 1: not reached; the photons it needs scale as that squared).
The σ waited for is the step's own: the lamps' normalisation σ, fixed for the whole growth, is left out.
"""
from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from ..chamber import units
from ..errors import InputError
from ..chamber.ratios import MAX_DENOMINATOR_CV

#: the quantities a mapping may name besides band labels, and whether their σ is relative
QUANTITIES = {"par": True, "rfr": False}


class Goal(dict):
    """A parsed precision goal: ``{quantity: (sigma, relative)}``; ``given`` is what the user wrote
    (a number or a mapping), which ``summary.json`` and a step's ``extra`` report."""

    def __init__(self, items, given):
        super().__init__(items)
        self.given = given


def _number(text, key) -> float:
    try:
        value = float(text)
    except (TypeError, ValueError):
        value = math.nan
    if isinstance(text, bool) or not math.isfinite(value) or value <= 0:
        raise InputError("precision %s: expected a σ > 0, got %r" % (key, text))
    return value


def _band_label(key) -> bool:
    lo, dash, hi = str(key).partition("-")
    try:
        return bool(dash) and float(lo) < float(hi)
    except ValueError:
        return False


def parse_goal(value, bands=None, labels=None) -> Goal | None:
    """A :class:`Goal` from a number, a mapping or the command line's text (see the module), or None for None.

    ``bands`` (nm pairs) and ``labels`` (``"655-665"``, ...): the scene's, when known -- a mapping may name
    its bands, and may ask for PAR and R:FR only where the bands give them; without them (the command line,
    before the model's scene is read) any ``LO-HI`` key is let through, to be checked with the scene.  A bad
    key or value raises :class:`~lpy_light.errors.InputError` naming it."""
    if value is None:
        return None
    if isinstance(value, Goal):
        value = value.given
    if isinstance(value, str):
        text = value.strip()
        if "=" not in text:
            value = text
        else:
            items = {}
            for part in (p for p in text.split(",") if p.strip()):
                key, eq, number = part.partition("=")
                if not eq or not key.strip():
                    raise InputError("precision: expected KEY=σ pairs separated by commas (par=0.03,rfr=0.02), "
                                     "got %r" % part.strip())
                items[key.strip()] = number.strip()
            value = items
    if isinstance(value, Mapping):
        return _parse_mapping(value, bands, labels)
    try:
        p = float(value)
    except (TypeError, ValueError):
        p = math.nan
    if isinstance(value, bool) or not 0 < p < 1:
        raise InputError("precision must be a relative standard error in (0, 1), e.g. 0.04, or a mapping like "
                         "{'par': 0.03, 'rfr': 0.02}; got %r" % (value,))
    return Goal({"par": (p, True), "rfr": (p, True)}, p)


def _parse_mapping(value, bands, labels) -> Goal:
    if not value:
        raise InputError("precision: an empty mapping asks for nothing (give par=..., rfr=... or a number)")
    known = list(QUANTITIES) + list(labels or [])
    goal = {}
    for key, sigma in value.items():
        name = str(key).strip()
        if name.lower() in QUANTITIES:
            name = name.lower()
            relative = QUANTITIES[name]
        elif name in (labels or []) or (labels is None and _band_label(name)):
            relative = True
        else:
            what = "a band of the scene" if _band_label(name) else "a quantity"
            raise InputError("precision: unknown key %r (not %s; known: %s)" % (key, what, ", ".join(known)))
        s = _number(sigma, name)
        if relative and not s < 1:
            raise InputError("precision %s: expected a relative σ in (0, 1), got %r" % (name, sigma))
        if labels is not None and name == "par" and units.par_columns(bands) is None:
            raise InputError("precision par: the scene's bands do not tile 400-700 nm, so it has no PAR")
        if labels is not None and name == "rfr" and (units.band_index(bands, units.RED) is None
                                                     or units.band_index(bands, units.FAR_RED) is None):
            raise InputError("precision rfr: the scene has no bands %g-%g and %g-%g nm, so no R:FR"
                             % (units.RED + units.FAR_RED))
        goal[name] = (s, relative)
    return Goal(goal, {k: v[0] for k, v in goal.items()})


def sigma_over_goal(goal: Goal, x, cov, flux, bands, labels) -> float:
    """The largest σ / goal over organs and asked quantities (≤ 1: the goal is reached), or inf before any
    light (:func:`organs_sigma_over_goal`'s arguments)."""
    if len(x) == 0:
        return math.inf
    rel = organs_sigma_over_goal(goal, x, cov, flux, bands, labels)
    rel = rel[np.isfinite(rel)]
    return float(rel.max()) if rel.size else math.inf


def organs_sigma_over_goal(goal: Goal, x, cov, flux, bands, labels) -> np.ndarray:
    """(S,) per organ, the largest σ / goal over the asked quantities (≤ 1: reached; NaN: none defined yet).

    ``x`` (S, B) the target organs' incident tallies so far, ``cov`` (S, B, B) their covariance between
    bands, ``flux`` (B,) the lamps' photon flux per band (PAR's weights; R:FR's factor), ``bands`` the
    scene's bands in nm (None: one band), ``labels`` their labels.  A goal that asks for PAR or R:FR where
    the bands give neither asks for every band's relative σ instead (a number's goal, as before; a mapping
    cannot ask for them there: :func:`parse_goal`)."""
    flux = np.broadcast_to(np.asarray(flux, float), x.shape[1:])
    scale = np.broadcast_to(flux, x.shape)
    par, par_std, rfr, rfr_std = units.par_and_rfr(x, cov, scale, np.zeros_like(x), bands)
    f = units.band_index(bands, units.FAR_RED)
    worst = []
    with np.errstate(divide="ignore", invalid="ignore"):
        band_sigma = np.sqrt(np.maximum(np.diagonal(cov, axis1=1, axis2=2), 0.0))
        for name, (sigma, relative) in goal.items():
            if name == "par" and par is not None:
                worst.append(np.where(par > 0, par_std / par, np.nan) / sigma)
            elif name == "rfr" and rfr is not None:
                lit = x[:, f] > 0
                ratio = rfr_std / np.abs(rfr) if relative else rfr_std
                den_cv = np.where(lit, band_sigma[:, f] / np.where(lit, x[:, f], 1.0), np.nan)
                missing = lit & ~np.isfinite(rfr)                   # lit, but no R:FR reported yet
                worst.append(np.where(missing, den_cv / MAX_DENOMINATOR_CV, ratio / sigma))
            elif name in labels:
                b = labels.index(name)
                worst.append(np.where(x[:, b] > 0, band_sigma[:, b] / x[:, b], np.nan) / sigma)
        if not worst and not isinstance(goal.given, Mapping):   # a number, and bands without PAR or R:FR:
            sigma = min(s for s, _ in goal.values())                # every band's relative σ
            worst.append(np.where(x > 0, band_sigma / x, np.nan) / sigma)
    if not worst:
        return np.full(len(x), np.nan)
    return _row_max(np.column_stack([np.asarray(w).reshape(len(x), -1) for w in worst]))


def _row_max(rel) -> np.ndarray:
    """(S,) the largest finite value of each row of ``rel`` (S, K), NaN where none is finite."""
    finite = np.isfinite(rel)
    out = np.where(finite, rel, -np.inf).max(axis=1)
    return np.where(finite.any(axis=1), out, np.nan)
