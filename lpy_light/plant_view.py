"""A false-colour picture of the plant: each organ coloured by its light (PNG, matplotlib)."""
from __future__ import annotations

import numpy as np


def organ_values(organs, lights, quantity: str = "par"):
    """Per organ, the value shown: ``par`` when defined, else the first band's ppfd (µmol m⁻² s⁻¹)."""
    values = []
    for organ in organs:
        light = lights.get(organ.key)
        if light is None:
            values.append(np.nan)
            continue
        v = getattr(light, quantity, np.nan)
        values.append(float(v) if np.isfinite(v) else float(light.ppfd[0]))
    return np.array(values)


def plant_picture(path, organs, lights, title: str = "", quantity: str = "par"):
    """Write ``path`` (PNG): the organs' triangles (chamber units) coloured by ``quantity``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    values = organ_values(organs, lights, quantity)
    fig = plt.figure(figsize=(7, 7))
    ax = fig.add_subplot(projection="3d")
    finite = values[np.isfinite(values)]
    lo, hi = (finite.min(), finite.max()) if len(finite) else (0.0, 1.0)
    norm = matplotlib.colors.Normalize(lo, hi if hi > lo else lo + 1)
    cmap = matplotlib.colormaps["viridis"]
    tris, colours = [], []
    for organ, v in zip(organs, values):
        tris.extend(organ.triangles)
        colours.extend([cmap(norm(v)) if np.isfinite(v) else (0.6, 0.6, 0.6, 1)] * len(organ.triangles))
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
    fig.colorbar(plt.cm.ScalarMappable(norm=norm, cmap=cmap), ax=ax, shrink=0.6,
                 label="%s incident (µmol m⁻² s⁻¹)" % label)
    ax.set_title(title)
    fig.savefig(path, dpi=110)
    plt.close(fig)
