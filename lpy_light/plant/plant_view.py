"""Organs coloured by their light: in the L-Py viewer (:func:`par_colour`) and as a PNG (:func:`plant_picture`).

Both use one fixed scale, viridis from 0 (dark blue) to ``top`` µmol m⁻² s⁻¹ (yellow), so that
steps and runs compare; organs whose light is not estimated (shading only) are grey-brown.
"""
from __future__ import annotations

import math

import numpy as np

#: viridis at 0, 1/4, 1/2, 3/4, 1 (RGB 0-255): enough stops for a smooth scale without matplotlib
VIRIDIS = np.array([(68, 1, 84), (59, 82, 139), (33, 145, 140), (94, 201, 98), (253, 231, 37)], dtype=float)
#: colour of an organ whose light is not known (not a target, or no light model yet)
UNKNOWN = (150, 130, 100)


def scale_colour(value: float, top: float) -> tuple:
    """RGB (0-255 ints) of ``value`` on the fixed scale 0 → ``top``; beyond ``top`` stays yellow."""
    if value is None or not math.isfinite(value) or not top > 0:
        return UNKNOWN
    t = min(max(value / top, 0.0), 1.0) * (len(VIRIDIS) - 1)
    i = min(int(t), len(VIRIDIS) - 2)
    rgb = VIRIDIS[i] + (t - i) * (VIRIDIS[i + 1] - VIRIDIS[i])
    return tuple(int(round(c)) for c in rgb)


def par_colour(light, top: float = 120.0) -> tuple:
    """``(r, g, b)`` for L-Py's ``SetColor``: the organ's PAR (µmol m⁻² s⁻¹) on the scale 0 → ``top``.

    ``light`` is an :class:`~lpy_light.plant.light.OrganLight` or None (before the first step).  In an
    interpretation rule: ``produce SetColor(*par_colour(light, 120)) ~l(size)``."""
    if light is None:
        return UNKNOWN
    par = getattr(light, "par", math.nan)
    if not math.isfinite(par):
        ppfd = getattr(light, "ppfd", None)
        par = float(ppfd[0]) if ppfd is not None and len(ppfd) == 1 else math.nan
    return scale_colour(par, top)


def organ_values(organs, lights, quantity: str = "par"):
    """Per organ, the value shown: ``par`` when defined, else the first band's ppfd (µmol m⁻² s⁻¹)."""
    values = []
    for organ in organs:
        light = lights.get(organ.key)
        if light is None:
            values.append(np.nan)
            continue
        v = getattr(light, quantity, np.nan)
        values.append(float(v) if np.isfinite(v) or len(light.ppfd) != 1 else float(light.ppfd[0]))
    return np.array(values)


def plant_picture(path, organs, lights, title: str = "", quantity: str = "par", top: float | None = None):
    """Write ``path`` (PNG): the organs' triangles (chamber units) coloured by ``quantity`` on the fixed scale
    0 → ``top`` µmol m⁻² s⁻¹ (the L-Py viewer's, :func:`par_colour`; default: the largest value shown).

    Drawn on a figure of its own, outside pyplot: it renders headless and leaves the caller's backend as it was
    (a notebook's inline figures keep showing)."""
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import LinearSegmentedColormap, Normalize
    from matplotlib.figure import Figure
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    values = organ_values(organs, lights, quantity)
    finite = values[np.isfinite(values)]
    if top is None or not top > 0:
        top = float(finite.max()) if len(finite) and finite.max() > 0 else 1.0
    fig = Figure(figsize=(7, 7))
    ax = fig.add_subplot(projection="3d")
    tris, colours = [], []
    for organ, v in zip(organs, values):
        tris.extend(organ.triangles)
        colours.extend([tuple(c / 255.0 for c in scale_colour(v, top))] * len(organ.triangles))
    if tris:
        pts = np.concatenate([o.triangles.reshape(-1, 3) for o in organs])
        ax.add_collection3d(Poly3DCollection(tris, facecolors=colours, edgecolors="none"))
        lo3, hi3 = pts.min(axis=0), pts.max(axis=0)
        centre, half = (lo3 + hi3) / 2, max((hi3 - lo3).max() / 2, 1e-9)
        ax.set_xlim(centre[0] - half, centre[0] + half)
        ax.set_ylim(centre[1] - half, centre[1] + half)
        ax.set_zlim(centre[2] - half, centre[2] + half)
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("y (mm)")
    ax.set_zlabel("z (mm)")
    label = "PAR" if quantity == "par" else quantity
    cmap = LinearSegmentedColormap.from_list("lpy_light", VIRIDIS / 255.0)
    fig.colorbar(ScalarMappable(norm=Normalize(0, top), cmap=cmap), ax=ax, shrink=0.6,
                 label="%s incident (µmol m⁻² s⁻¹; grey-brown: not estimated)" % label)
    ax.set_title(title)
    fig.savefig(path, dpi=110)
